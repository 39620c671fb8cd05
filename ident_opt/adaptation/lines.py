"""How the stream reads its input: one sample per line, CSV with a header or JSON lines, by the problem's column mapping
and conversions (`Mapping`, `LineParser`); a line that cannot be a sample is a `BadLine`, reported and skipped, never a
crash."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

from ident_opt.columns import channel_names, data_columns, locate
from ident_opt.data.checks import PLAUSIBLE
from ident_opt.errors import InputError

#: The UTF-8 byte-order mark some writers put before a file's first line.
BOM = "\ufeff"


class BadLine(ValueError):
    """A line that is not a valid sample (reported on the error stream, then skipped); `kind` says why."""

    def __init__(self, message: str, kind: str = "parse"):
        super().__init__(message)
        self.kind = kind


@dataclass
class Mapping:
    """How stream columns become standard names, by the batch loader's rules (`columns.locate`): `columns`
    {standard name: column name or 0-based index}, `conversions` {standard name: (scale, offset)} (value = scale ×
    raw + offset), `header`: whether a CSV stream is expected to start with a header line (the problem's `[data]
    header`), `to_tool`: after the conversions, name → (scale, offset) to ident-opt's angle convention (a URDF
    arm's samples come in the URDF's: `Robot.column_map`), `ignored`: standard names never read (`[data.columns]`
    name = false), `standard_by_name`: a header with the standard names is read by name, `n_joints`: the arm's."""

    columns: dict[str, str | int] = field(default_factory=dict)
    conversions: dict[str, tuple[float, float]] = field(default_factory=dict)
    header: bool = True
    to_tool: dict[str, tuple[float, float]] = field(default_factory=dict)
    ignored: frozenset[str] = frozenset()
    standard_by_name: bool = True
    n_joints: int = 2

    @classmethod
    def from_spec(cls, spec, robot=None) -> Mapping:
        """From a problem's `DataSpec` and its robot (its number of joints, its map from the data's angle
        convention to the tool's)."""
        n = robot.n_joints if robot is not None else 2
        to_tool = dict(robot.column_map) if robot is not None else {}
        return cls(
            dict(spec.columns),
            dict(spec.conversions),
            bool(spec.header),
            to_tool,
            frozenset(spec.ignored),
            bool(spec.standard_by_name),
            n,
        )

    @property
    def names(self) -> dict[str, tuple[str, ...]]:
        """The standard names per signal for this arm (`columns.channel_names`)."""
        return channel_names(self.n_joints)

    def resolve_header(self, header: list[str]) -> tuple[dict[str, int], dict[str, tuple[float, float]]]:
        """{standard name: position} for a CSV header, and the conversions that apply (`columns.locate`);
        `InputError` when a name repeats or the header lacks an angle."""
        names = [c.strip() for c in header]
        if len(set(names)) != len(names):
            twice = next(n for n in names if names.count(n) > 1)
            raise InputError(f"stream: column '{twice}' appears twice in the CSV header")
        found, conversions = locate(names, len(names), self, self.n_joints, "stream")
        missing = self._missing_angles(found)
        if missing:
            raise InputError(
                f"stream: the CSV header ({', '.join(names[:20])}) lacks {missing}; name them so, or map them with "
                "[data.columns] in the problem file"
            )
        return found, conversions

    def by_index(self, width: int) -> tuple[dict[str, int], dict[str, tuple[float, float]]]:
        """{standard name: position} for a header-less CSV stream from the mapping's column indices."""
        found, conversions = locate(None, width, self, self.n_joints, "stream")
        missing = self._missing_angles(found)
        if missing:
            raise InputError(
                "stream: the first line is data, not a header, and [data.columns] maps no column index for "
                f"{missing}; start the stream with a header line"
            )
        return found, conversions

    def _missing_angles(self, found: dict[str, int]) -> str:
        """The joint angles `found` lacks, comma-separated ("" when none)."""
        return ", ".join(n for n in self.names["q"] if n not in found)


def _number(text: str) -> float:
    """A JSON number token as a float: huge integers become ±inf (caught as not finite), never OverflowError."""
    try:
        return float(text)
    except (OverflowError, ValueError):
        return math.inf


def _no_constant(name: str) -> float:
    raise ValueError(f"{name} is not a number JSON allows")


@dataclass
class LineParser:
    """Turns lines into {standard name: float} (SI, conversions applied, currents as torques); learns the
    format, and the CSV header, from the first non-empty line."""

    format: str | None = None  # "csv" or "json", decided by the first non-empty line
    header: list[str] = field(default_factory=list)
    current_to_torque: tuple[float, ...] | None = None  # N m / A per joint, for samples of currents
    mapping: Mapping = field(default_factory=Mapping)
    currents_refused: str = ""  # why samples of currents cannot be read (no torque constant), for their error
    positions: dict[str, int] = field(default_factory=dict)
    conversions: dict[str, tuple[float, float]] = field(default_factory=dict)
    width: int = 0

    def parse(self, line: str) -> dict[str, float] | None:
        """The sample on `line`, or None for a blank line or the CSV header; raises BadLine (a bad sample) or
        InputError (a header or mapping the stream cannot be read with)."""
        text = line.strip()
        if self.format is None:
            text = text.removeprefix(BOM).strip()  # a byte-order mark before the first line, as the batch loader reads
        if not text:
            return None
        if self.format is None:
            self.format = "json" if text.startswith("{") else "csv"
            if self.format == "csv":
                cells = [c.strip() for c in text.split(",")]
                if not self.mapping.header and all(_is_number(c) for c in cells):
                    self.positions, self.conversions = self.mapping.by_index(len(cells))
                    self.width = len(cells)
                    self._check_time_column()
                else:
                    self.header = cells
                    self.positions, self.conversions = self.mapping.resolve_header(cells)
                    self.width = len(cells)
                    self._check_time_column()
                    return None
        if self.format == "json":
            raw = self._json(text)
        else:
            cells = [c.strip() for c in text.split(",")]
            if len(cells) != self.width:
                raise BadLine(f"{len(cells)} fields, the {'header' if self.header else 'first line'} has {self.width}")
            raw = {name: cells[i] for name, i in self.positions.items()}
        sample = _sample(raw, self.mapping.names, self.current_to_torque, self.conversions, self.currents_refused)
        for name, (scale, offset) in self.mapping.to_tool.items():  # currents are torques by now: tau's sign
            if name in sample:
                sample[name] = scale * sample[name] + offset
        return sample

    def _check_time_column(self) -> None:
        """Without dq and ddq columns the derivatives are estimated, which needs t: else an `InputError`."""
        names = self.mapping.names
        derivatives = all(n in self.positions for n in (*names["dq"], *names["ddq"]))
        if not derivatives and "t" not in self.positions:
            raise InputError(
                f"stream: the CSV columns give neither {' '.join((*names['dq'], *names['ddq']))} nor t; the "
                "derivatives are estimated from q and t, so t [s] is needed"
            )

    def _json(self, text: str) -> dict:
        try:
            raw = json.loads(text, parse_int=_number, parse_float=_number, parse_constant=_no_constant)
        except json.JSONDecodeError as exc:
            raise BadLine(f"not JSON ({exc.msg})") from None
        except (ValueError, RecursionError) as exc:
            raise BadLine(f"not a valid JSON sample ({type(exc).__name__})") from None
        if not isinstance(raw, dict):
            raise BadLine("a JSON line must be an object")
        out = {}
        for name in data_columns(self.mapping.n_joints):  # a mapped key first (with its conversion), else the name
            if name in self.mapping.ignored:
                continue
            source = self.mapping.columns.get(name)
            if isinstance(source, str) and source in raw:
                out[name] = raw[source]
                if name in self.mapping.conversions:
                    self.conversions[name] = self.mapping.conversions[name]
            elif name in raw:
                out[name] = raw[name]
                self.conversions.pop(name, None)
        return out


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _sample(
    raw: dict,
    names: dict[str, tuple[str, ...]],
    current_to_torque: tuple[float, ...] | None = None,
    conversions: dict | None = None,
    currents_refused: str = "",
) -> dict[str, float]:
    """The numeric fields of a sample, checked: every angle present, each other signal for every joint or none,
    torques or currents, every used value a finite number within `data.PLAUSIBLE`; conversions applied; currents
    become torques [N m]. `names`: the standard names per signal (`columns.channel_names`); `currents_refused`: why
    the problem cannot turn currents into torques (the joints' tables that lack a torque constant)."""

    def present(name):
        return name in raw and raw[name] not in ("", None)

    missing = [c for c in names["q"] if not present(c)]
    if missing:
        raise BadLine(f"missing field(s) {', '.join(missing)}")
    groups = {g: [c for c in names[g] if present(c)] for g in ("dq", "ddq", "tau", "i")}
    if any(0 < len(v) < len(names["q"]) for v in groups.values()):
        raise BadLine("a joint signal comes for every joint or none (tau1 … taun, dq1 … dqn, …)")
    if groups["tau"] and groups["i"]:
        raise BadLine(f"give torques {' '.join(names['tau'])} or currents {' '.join(names['i'])}, not both")
    if groups["i"] and current_to_torque is None:
        why = currents_refused or "the problem gives no torque constants and gear ratios"
        raise BadLine(f"currents {' '.join(names['i'])} cannot become torques: {why}")
    used = [*names["q"], *(c for g in ("dq", "ddq", "tau", "i") for c in groups[g]), *(["t"] if present("t") else [])]
    out = {name: _value(name, raw[name], conversions) for name in used}
    for current, torque, k in zip(groups["i"], names["tau"], current_to_torque or ()):
        out[torque] = out.pop(current) * k
    return out


def _value(name: str, value, conversions: dict | None) -> float:
    """One field as a finite, plausible float in SI units (its conversion applied); raises BadLine."""
    if isinstance(value, bool):
        raise BadLine(f"{name} is not a number")
    try:
        number = float(value)
    except (TypeError, ValueError, OverflowError):
        raise BadLine(f"{name} is not a number: {str(value)[:40]!r}") from None
    if conversions and name in conversions:
        scale, offset = conversions[name]
        number = scale * number + offset
    if not math.isfinite(number):
        raise BadLine(f"{name} is not finite: {str(value)[:40]!r}")
    kind = name.rstrip("0123456789")
    if kind in PLAUSIBLE and abs(number) > PLAUSIBLE[kind]:
        limit = PLAUSIBLE[kind]
        raise BadLine(f"{name} = {number:.6g} is implausible: |{kind}| > {limit:g} in SI units", "implausible")
    return number
