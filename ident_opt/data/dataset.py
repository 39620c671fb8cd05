"""Measured trials: reading, validating, estimating missing derivatives, and splitting.

The file format is `docs/data-format.md`: one row per sample, SI units, columns t, q1 … qn, optional
dq/ddq, and either joint torques tau1 … taun or motor currents i1 … in. Every fault is reported as an
`InputError` naming the file, the column and the first offending row; input files are only read.
"""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd
from sklearn.model_selection import train_test_split

from ident_opt import outputs
from ident_opt.arm.base import Robot
from ident_opt.arm.planar import PI_NAMES
from ident_opt.columns import channel_names, locate
from ident_opt.data import rosbag
from ident_opt.data.derivatives import (
    choose_cutoff,
    estimate_derivatives,
    instrument_derivatives,
    lowpass,
    resolve_cutoff,
    settled,
)
from ident_opt.errors import InputError, excerpt
from ident_opt.problem.spec import DataSpec

#: A standard joint column's name: its signal and its joint number (1-based).
JOINT_COLUMN = re.compile(r"(q|dq|ddq|tau|i)(\d+)")
#: Limits beyond which a value is almost surely in the wrong unit (degrees, encoder counts, mA ...).
PLAUSIBLE = {"q": 100.0, "dq": 1e3, "ddq": 1e5, "tau": 1e5, "i": 1e3}
#: Sampling rates [Hz] a robot log can have: outside, t is almost surely not in seconds.
PLAUSIBLE_RATE_HZ = (0.1, 1e5)


@dataclass
class Dataset:
    """One trial: time [s], joint angles [rad], velocities [rad/s], accelerations [rad/s²], torques [N m]."""

    source: str
    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    tau: np.ndarray
    extra: pd.DataFrame = field(default_factory=pd.DataFrame)
    derivatives: str = "given"
    dropped_rows: int = 0
    notes: list[str] = field(default_factory=list)
    cutoff_hz: float | None = None  # the derivative filter's cut-off actually used (None: derivatives given)
    #: τ through the same zero-phase low-pass as the angles (parallel filtering), for fits; None: τ as logged
    tau_filtered: np.ndarray | None = None
    #: (dq, ddq) of the instruments of IV, estimated at a lower cut-off than the regressor's
    #: (`derivatives.instrument_derivatives`); None when not estimated
    instruments: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def tau_fit(self) -> np.ndarray:
        """The torque fits use [N m]: filtered like the regressor's inputs when derivatives were estimated, so
        a fit compares like with like. Scores always use the measured `tau`."""
        return self.tau if self.tau_filtered is None else self.tau_filtered

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def rate_hz(self) -> float:
        """Median sampling rate [Hz]."""
        return float(1.0 / np.median(np.diff(self.t))) if self.n > 1 else float("nan")

    def subset(self, index: np.ndarray) -> Dataset:
        """The samples at `index` (an index array or boolean mask), in that order."""
        return replace(
            self,
            t=self.t[index],
            q=self.q[index],
            dq=self.dq[index],
            ddq=self.ddq[index],
            tau=self.tau[index],
            tau_filtered=None if self.tau_filtered is None else self.tau_filtered[index],
            instruments=None if self.instruments is None else tuple(x[index] for x in self.instruments),
            # a trial built in code may have no extra columns at all (an empty frame with no rows)
            extra=self.extra.iloc[np.arange(self.n)[index]].reset_index(drop=True) if len(self.extra) else self.extra,
        )

    def to_frame(self) -> pd.DataFrame:
        """The trial in the data format's column names (torques, not currents)."""
        cols = {"t": self.t}
        for name, arr in (("q", self.q), ("dq", self.dq), ("ddq", self.ddq), ("tau", self.tau)):
            cols.update({f"{name}{j + 1}": arr[:, j] for j in range(arr.shape[1])})
        return pd.concat([pd.DataFrame(cols), self.extra.reset_index(drop=True)], axis=1)


# ---------------------------------------------------------------------------------------------- reading
def _read(path: Path, spec: DataSpec) -> pd.DataFrame:
    """The raw table of a data file, or of a ROS 2 bag (`ident_opt.data.rosbag`: already in the data format's names)."""
    outputs.declare_inputs([path])
    if path.exists() and rosbag.is_bag(path):
        return rosbag.read_bag(path, spec.ros_topic, spec.ros_joints)
    return _read_table(path, spec)


def _read_table(path: Path, spec: DataSpec) -> pd.DataFrame:
    """The raw table of a CSV / Parquet / Excel file, every cell as read (no conversion yet)."""
    if not path.exists():
        raise InputError(f"{path}: data file not found")
    if not path.is_file():
        raise InputError(f"{path}: not a file")
    name = path.name.lower()
    header = 0 if spec.header else None
    try:
        if name.endswith(".csv") or name.endswith(".csv.gz"):
            frame = pd.read_csv(path, header=header, sep=",", dtype=str, keep_default_na=False, skipinitialspace=True)
        elif name.endswith(".parquet"):
            frame = pd.read_parquet(path)
            if not spec.header and not _standard_names(frame.columns, spec):
                frame.columns = range(frame.shape[1])
        elif name.endswith(".xlsx"):
            frame = pd.read_excel(path, sheet_name=spec.sheet or 0, header=header)
        else:
            raise InputError(
                f"{path}: unsupported file type; ident-opt reads .csv, .csv.gz, .parquet, .xlsx and ROS 2 bags"
            )
    except InputError:
        raise
    except pd.errors.EmptyDataError:
        raise InputError(f"{path}: the file is empty") from None
    except (ValueError, OSError, EOFError, UnicodeDecodeError, KeyError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{path}: cannot read the file ({first})") from None
    except Exception as exc:  # pyarrow and openpyxl raise their own types for corrupt files
        raise InputError(f"{path}: cannot read the file ({type(exc).__name__}: {exc})") from None
    if frame.shape[0] == 0:
        raise InputError(f"{path}: the file has no data rows")
    return frame


def _standard_names(labels, spec: DataSpec) -> bool:
    """Whether a table's own column names are the data format's (t and q1 among them) and may be read so
    (`[data] standard_by_name`, the default)."""
    return spec.standard_by_name and {"t", "q1"} <= {str(c).strip() for c in labels}


def _header_row(frame: pd.DataFrame, spec: DataSpec) -> tuple[pd.DataFrame, DataSpec]:
    """A file read without a header row (`[data] header = false`) whose first row has the standard names (t, q1) is
    a file with a header after all (unless `[data] standard_by_name = false`): that row becomes the header. A
    Parquet file always names its columns: standard names there are read as such too."""
    if spec.header or not spec.standard_by_name:
        return frame, spec
    if _standard_names(frame.columns, spec):
        return frame, replace(spec, header=True)
    first = [str(v).strip() for v in frame.iloc[0]]
    if not _standard_names(first, spec):
        return frame, spec
    body = frame.iloc[1:].reset_index(drop=True)
    body.columns = first
    return body, replace(spec, header=True)


def _check_unique_header(frame: pd.DataFrame, path: Path, spec: DataSpec) -> None:
    """A column name twice in the header is ambiguous (pandas would silently rename the second 'q1.1')."""
    if not spec.header or not path.name.lower().endswith((".csv", ".csv.gz")):
        return
    try:
        names = [str(c).strip() for c in pd.read_csv(path, header=None, nrows=1, dtype=str).iloc[0]]
    except (ValueError, OSError, UnicodeDecodeError, pd.errors.ParserError):
        return  # the full read succeeded; a header this odd is judged by the columns found
    seen: dict[str, int] = {}
    for index, name in enumerate(names):
        if name in seen:
            raise InputError(
                f"{path}: column '{name}' appears twice in the header (columns {seen[name]} and {index}, "
                "0-based); rename one of them"
            )
        seen[name] = index


def _locate(
    frame: pd.DataFrame, spec: DataSpec, path: Path, n_joints: int
) -> tuple[dict[str, object], dict[str, tuple[float, float]]]:
    """({data-format name: its column label in `frame`}, the conversions that apply) by the rules every reader of
    the problem's data shares (`columns.locate`)."""
    header = [str(c) for c in frame.columns] if spec.header else None
    found, conversions = locate(header, frame.shape[1], spec, n_joints, str(path))
    return {name: frame.columns[i] for name, i in found.items()}, conversions


def _row_label(path: Path, row: int, spec: DataSpec) -> str:
    """Where 0-based data row `row` is, as the user finds it: a CSV's line, a ROS 2 bag's message index."""
    if path.name.lower().endswith((".csv", ".csv.gz")):
        return f"data row {row + 1} (line {row + 1 + int(spec.header)} of the file)"
    if path.exists() and rosbag.is_bag(path):
        return rosbag.message_label(row, spec.ros_topic)
    return f"data row {row + 1}"


def _numeric(
    frame: pd.DataFrame, label: object, name: str, path: Path, spec: DataSpec, drop_invalid: bool, bad: np.ndarray
) -> np.ndarray:
    """Column `label` as floats; non-numeric or non-finite cells are an error or (drop_invalid) marked."""
    raw = frame[label]
    values = pd.to_numeric(raw, errors="coerce").to_numpy(dtype=float)
    invalid = ~np.isfinite(values)
    if invalid.any():
        if drop_invalid:
            bad |= invalid
        else:
            row = int(np.argmax(invalid))
            cell = raw.iloc[row]
            empty = cell is None or (isinstance(cell, str) and not cell.strip())  # a NaN read as a number is a value
            what = "an empty cell" if empty else f"the value {excerpt(cell)}"
            raise InputError(
                f"{path}: column '{name}' has {what} at {_row_label(path, row, spec)}; "
                "every used cell must be a finite number (use --drop-invalid to skip such rows)"
            )
    return values


def _beyond(name: str, n_joints: int) -> bool:
    """Whether `name` is a standard joint column (q7, tau8, …) of a joint beyond the arm's `n_joints`."""
    match = JOINT_COLUMN.fullmatch(name)
    return match is not None and int(match.group(2)) > n_joints


def _unread(name: str, spec: DataSpec) -> str:
    """Why column `name` is missing when the problem leaves it unread on purpose ("" otherwise), for messages."""
    return f" (the problem leaves it unread: [data.columns] {name} = false)" if name in spec.ignored else ""


def _check_columns(cols: dict[str, object], frame: pd.DataFrame, path: Path, n_joints: int, spec: DataSpec) -> str:
    """Required columns present, signals complete per joint, exactly one of torques/currents: its kind."""
    have = ", ".join(map(str, frame.columns[:30]))
    names = channel_names(n_joints)
    used = {str(label) for label in cols.values()}
    extra = [str(c) for c in frame.columns if str(c) not in used and _beyond(str(c), n_joints)]
    if extra:
        raise InputError(
            f"{path}: the file has columns of joints the arm does not have ({', '.join(extra[:8])}): the problem's "
            f"arm has {n_joints} joints; check the problem file's [robot] joints, or drop those columns"
        )
    missing = [c for c in ("t", *names["q"]) if c not in cols]
    if missing:
        which = f"column '{missing[0]}' is" if len(missing) == 1 else f"columns {', '.join(map(repr, missing))} are"
        raise InputError(
            f"{path}: required {which} missing; the file has: {have}. "
            "Map foreign names with [data.columns] in the problem file."
        )
    together = "come in pairs" if n_joints == 2 else f"come for all {n_joints} joints or none"
    present = {kind: [c for c in names[kind] if c in cols] for kind in ("tau", "i")}
    for kind, group in present.items():
        if 0 < len(group) < n_joints:
            missing = next(c for c in names[kind] if c not in group)
            raise InputError(
                f"{path}: column '{missing}' is missing{_unread(missing, spec)}; torques ({', '.join(names['tau'])}) "
                f"or currents ({', '.join(names['i'])}) {together}; the file has: {have}"
            )
    if present["tau"] and present["i"]:
        raise InputError(
            f"{path}: the file has both torques ({', '.join(names['tau'])}) and currents ({', '.join(names['i'])}); "
            "keep one set, or leave the other unread in [data.columns] (e.g. "
            f"{', '.join(f'{c} = false' for c in names['i'])} to read the torques)"
        )
    if not present["tau"] and not present["i"]:
        raise InputError(
            f"{path}: neither torques ({', '.join(names['tau'])}) nor currents ({', '.join(names['i'])}) found; "
            f"the file has: {have}. Map foreign names with [data.columns] in the problem file."
        )
    for kind in ("dq", "ddq"):
        group = [c for c in names[kind] if c in cols]
        if 0 < len(group) < n_joints:
            missing = next(c for c in names[kind] if c not in group)
            raise InputError(
                f"{path}: column '{missing}' is missing{_unread(missing, spec)}; {' and '.join(names[kind])} {together}"
            )
    return "tau" if present["tau"] else "i"


def _non_increasing(t: np.ndarray, bad: np.ndarray) -> np.ndarray:
    """Rows (not already `bad`) that break the strict increase of t: every sample not after the last kept."""
    breaks = np.zeros(len(t), dtype=bool)
    last = -np.inf
    for k, tk in enumerate(t):
        if bad[k]:
            continue
        if tk > last:
            last = tk
        else:
            breaks[k] = True
    return breaks


def _check_time(t: np.ndarray, path: Path, spec: DataSpec) -> None:
    """t strictly increasing, else an error naming the first row where it repeats or goes back."""
    steps = np.diff(t)
    if (steps <= 0).any():
        row = int(np.argmax(steps <= 0)) + 1
        kind = "repeats" if steps[row - 1] == 0 else "goes back"
        raise InputError(
            f"{path}: column 't' is not strictly increasing: it {kind} at "
            f"{_row_label(path, row, spec)} ({excerpt(float(t[row - 1]))} then {excerpt(float(t[row]))})"
        )


def in_source_convention(frame: pd.DataFrame, column_map: dict[str, tuple[float, float]]) -> pd.DataFrame:
    """A trial in the tool's convention written back in the data's own (the inverse of a robot's `column_map`:
    value = (value_tool − offset) / scale), so that reading it again maps it to what it was."""
    out = frame.copy()
    for name, (scale, offset) in column_map.items():
        if name in out:
            out[name] = (out[name] - offset) / scale
    return out


def convert(values: np.ndarray, scale: float, offset: float) -> np.ndarray:
    """A mapped column's conversion on the way in: scale × raw + offset (`[data.columns]`)."""
    return values if (scale, offset) == (1.0, 0.0) else scale * values + offset


def _check_rate(t: np.ndarray, path: Path) -> None:
    """A sampling rate outside `PLAUSIBLE_RATE_HZ` means t is not in seconds (ms, µs, sample counts)."""
    rate = 1.0 / float(np.median(np.diff(t)))
    low, high = PLAUSIBLE_RATE_HZ
    if not low <= rate <= high:
        raise InputError(
            f"{path}: column 't' gives a sampling rate of {rate:.3g} Hz, outside [{low:g}, {high:g}] Hz: "
            "is t in seconds? Use --allow-implausible to proceed anyway."
        )


def _check_plausible(
    signals: dict[str, np.ndarray], keep: np.ndarray, path: Path, spec: DataSpec, estimated: bool = False
) -> None:
    """Every signal within `PLAUSIBLE` for its unit, else an error naming column and row."""
    for kind, arr in signals.items():
        over = np.abs(arr) > PLAUSIBLE[kind]
        if over.any():
            row, joint = np.unravel_index(int(np.argmax(over)), over.shape)
            original_row = int(np.flatnonzero(keep)[row])
            hint = " (degrees or encoder counts?)" if kind == "q" else " (wrong unit?)"
            if estimated:
                hint = " (estimated from q and t: is t in seconds, q in radians?)"
            raise InputError(
                f"{path}: column '{kind}{joint + 1}' has the implausible value {excerpt(float(arr[row, joint]))} at "
                f"{_row_label(path, original_row, spec)}: |{kind}| > {PLAUSIBLE[kind]:g} in SI units"
                f"{hint}. Use --allow-implausible to proceed anyway."
            )


def _current_to_torque(robot: Robot, path: Path) -> np.ndarray:
    """Joint-side torque per ampere per joint [N m/A] (torque constant × gear ratio); an error naming every
    joint's table that lacks one of the two."""
    k = [j.current_to_torque for j in robot.joints]
    lacking = [
        f"[robot.{table}] gives no "
        + " and no ".join(key for key in ("torque_constant", "gear_ratio") if getattr(joint, key, None) is None)
        for table, joint, v in zip(robot.joint_tables, robot.joints, k)
        if v is None
    ]
    if lacking:
        torques = ", ".join(channel_names(robot.n_joints)["tau"])
        raise InputError(
            f"{path}: the file logs motor currents, but {'; '.join(lacking)}: a current becomes a joint torque as "
            f"current × torque_constant × gear_ratio, so every joint needs both; add them, or log joint torques "
            f"({torques})"
        )
    return np.array(k, dtype=float)


def _extra_columns(frame: pd.DataFrame, cols: dict[str, object], keep: np.ndarray) -> pd.DataFrame:
    """The columns the models do not use (strain, temperature, ...), numeric, on the kept rows."""
    used = set(cols.values())
    extra = frame[[c for c in frame.columns if c not in used]][keep].reset_index(drop=True)
    extra.columns = [f"col{c}" if isinstance(c, int) else str(c) for c in extra.columns]
    return extra.apply(pd.to_numeric, errors="coerce") if len(extra.columns) else extra


def load_dataset(
    path: str | Path,
    spec: DataSpec,
    robot: Robot,
    *,
    allow_implausible: bool = False,
    drop_invalid: bool = False,
    min_samples: int = len(PI_NAMES),
) -> Dataset:
    """Read, validate and complete one trial (see the module docstring); never modifies the file.

    Joint signals are (N, n) arrays with n = the robot's number of joints; torque [N m] is the logged
    torque, or current [A] × torque constant × gear ratio per joint.
    """
    path = Path(path)
    n_joints = len(robot.joints)
    names = channel_names(n_joints)
    frame = _read(path, spec)
    frame, spec = _header_row(frame, spec)
    _check_unique_header(frame, path, spec)
    cols, conversions = _locate(frame, spec, path, n_joints)
    load_kind = _check_columns(cols, frame, path, n_joints, spec)

    bad = np.zeros(len(frame), dtype=bool)
    values = {name: _numeric(frame, label, name, path, spec, drop_invalid, bad) for name, label in cols.items()}
    # Converted first (a mapped t may be scaled by -1): every check below sees what the models will see.
    # A URDF's angle zero and axis sign are the file's, not ident-opt's: the robot maps them (urdf_planar).
    to_tool = robot.column_map
    for name, v in values.items():
        values[name] = convert(convert(v, *conversions.get(name, (1.0, 0.0))), *to_tool.get(name, (1.0, 0.0)))
    if drop_invalid:  # rows that break strict increase of t are dropped too (the first of a run is kept)
        bad |= _non_increasing(values["t"], bad)
    keep = ~bad
    values = {name: v[keep] for name, v in values.items()}
    t = values["t"]
    _check_time(t, path, spec)
    n = len(t)
    if n < max(min_samples, 2):
        raise InputError(f"{path}: only {n} valid samples, fewer than the {max(min_samples, 2)} this command needs")

    signals = {kind: np.column_stack([values[c] for c in group]) for kind, group in names.items() if group[0] in values}
    if not allow_implausible:
        _check_rate(t, path)
        _check_plausible(signals, keep, path, spec)
    q = signals["q"]
    tau = signals["tau"] if load_kind == "tau" else signals["i"] * _current_to_torque(robot, path)

    notes: list[str] = []
    if "dq" in signals and "ddq" in signals:
        dq, ddq, how = signals["dq"], signals["ddq"], "given"
    else:
        cutoff, rule = resolve_cutoff(spec.derivative_cutoff_hz, t, q)
        dq, ddq, how = estimate_derivatives(t, q, cutoff, signals.get("dq"))
        how += rule
        if "ddq" in signals:  # logged accelerations are kept: only the velocities were missing
            ddq, how = signals["ddq"], how + " (accelerations as logged)"
        notes.append(f"derivatives {how}")
        if not allow_implausible:  # estimated from q and t: a wrong time unit shows here first
            _check_plausible({"dq": dq, "ddq": ddq}, keep, path, spec, estimated=True)
    dropped = int(bad.sum())
    if dropped:
        notes.append(f"dropped {dropped} invalid row(s)")
    extra = _extra_columns(frame, cols, keep)
    cutoff_hz = None if how == "given" else cutoff
    tau_filtered = None if cutoff_hz is None else lowpass(t, tau, cutoff_hz)
    # Logged derivatives carry the logger's own filters; the instruments come from q at the cut-off the data support.
    instruments = instrument_derivatives(t, q, cutoff_hz if cutoff_hz is not None else choose_cutoff(t, q))
    trial = Dataset(str(path), t, q, dq, ddq, tau, extra, how, dropped, notes, cutoff_hz, tau_filtered, instruments)
    return trial if cutoff_hz is None else _settled(trial, path, min_samples)


def _settled(trial: Dataset, path: Path, min_samples: int) -> Dataset:
    """The trial without the samples near its ends (and near gaps) whose estimated derivatives still carry the
    zero-phase filter's edge error (`derivatives.settled`), with a note saying how many went."""
    keep = settled(trial.t, trial.cutoff_hz)
    if keep.sum() < max(min_samples, 2):
        raise InputError(
            f"{path}: only {int(keep.sum())} samples lie a filter period (1/{trial.cutoff_hz:.3g} Hz) away from the "
            "trial's ends and gaps, where derivatives can be estimated; this command needs "
            f"{max(min_samples, 2)}: record a longer trial, or log dq and ddq"
        )
    if keep.all():
        return trial
    cut = trial.subset(keep)
    cut.notes.append(
        f"{int((~keep).sum())} sample(s) within {1 / trial.cutoff_hz:.3g} s of the trial's ends or gaps left out: "
        "the zero-phase filter's edge error is still in their derivatives there"
    )
    return cut


def refiltered(d: Dataset, cutoff_hz: float) -> Dataset:
    """The trial with its derivatives (and the fit's filtered torque) estimated again at `cutoff_hz` [Hz], from
    its angles (and its logged velocities, if the file had them); logged accelerations stay as they are."""
    logged_dq = d.dq if "velocities as logged" in d.derivatives else None
    dq, ddq, how = estimate_derivatives(d.t, d.q, cutoff_hz, logged_dq)
    if "accelerations as logged" in d.derivatives:
        ddq = d.ddq
    return replace(
        d,
        dq=dq,
        ddq=ddq,
        derivatives=how,
        cutoff_hz=cutoff_hz,
        tau_filtered=lowpass(d.t, d.tau, cutoff_hz),
        instruments=instrument_derivatives(d.t, d.q, cutoff_hz),
    )


def concat(trials: list[Dataset]) -> Dataset:
    """Several trials as one sample set (a pool): their samples one after the other, each with the derivatives
    estimated in its own file (no filter ran across a join). t is shifted to keep increasing [s]; statistics of
    the pool equal the sum of each trial's."""
    if len(trials) == 1:
        return trials[0]
    shifted, offset = [], 0.0
    for d in trials:
        shifted.append(d.t - d.t[0] + offset)
        offset = shifted[-1][-1] + float(np.median(np.diff(d.t)))
    filtered = [d.tau_fit for d in trials]
    cutoffs = {d.cutoff_hz for d in trials}
    return Dataset(
        " + ".join([trials[0].source, *(Path(d.source).name for d in trials[1:])]),  # the first in full
        np.concatenate(shifted),
        *(np.concatenate([getattr(d, k) for d in trials]) for k in ("q", "dq", "ddq", "tau")),
        extra=pd.concat([d.extra for d in trials], ignore_index=True),
        derivatives="; ".join(dict.fromkeys(d.derivatives for d in trials)),
        dropped_rows=sum(d.dropped_rows for d in trials),
        cutoff_hz=cutoffs.pop() if len(cutoffs) == 1 else None,
        tau_filtered=np.concatenate(filtered),
        instruments=None
        if any(d.instruments is None for d in trials)
        else tuple(np.concatenate([d.instruments[i] for d in trials]) for i in (0, 1)),
    )


#: The largest |value| (SI units) of q, dq, ddq or τ that a fit can take: the regressor's products of four
#: such values stay far from overflow. Far beyond any arm (1e8 rad/s, 1e8 N·m), so --allow-implausible keeps it.
MAX_MAGNITUDE = 1e8


def fittable(trial, fit: bool = True) -> None:
    """InputError when `trial` cannot be fitted in double precision (a value beyond `MAX_MAGNITUDE`) or, with
    `fit`, when a joint's torque never varies (its NMSE would be 0/0); without `fit` the latter is a warning."""
    for name, values in (("q", trial.q), ("dq", trial.dq), ("ddq", trial.ddq), ("tau", trial.tau)):
        worst = float(abs(values).max()) if values.size else 0.0
        if not worst <= MAX_MAGNITUDE:
            raise InputError(
                f"{trial.source}: |{name}| reaches {worst:.3g} (SI units), beyond {MAX_MAGNITUDE:.0e}: no fit is "
                "possible in double precision; check the column's unit (--allow-implausible does not lift this)"
            )
    for j in range(trial.tau.shape[1]):
        column = trial.tau[:, j]
        if column.size and float(column.max() - column.min()) == 0.0:
            message = (
                f"{trial.source}: the torque of joint {j + 1} is constant ({float(column[0]):g} N·m in every row): "
                "nothing to identify on that joint, and its NMSE would be 0/0; check the column mapping"
            )
            if fit:
                raise InputError(message)
            print(f"warning: {message}", file=sys.stderr)


# ---------------------------------------------------------------------------------------------- splits
def shuffled_split(n: int, train_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The paper's protocol: shuffle the samples, then train on `train_fraction` of them."""
    _nonempty_parts(n, int(train_fraction * n))
    train, test = train_test_split(np.arange(n), train_size=train_fraction, random_state=seed, shuffle=True)
    return np.sort(train), np.sort(test)


def chronological_split(n: int, train_fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """The honest protocol within one trial: the first part in time trains, the rest tests."""
    cut = round(train_fraction * n)
    _nonempty_parts(n, cut)
    return np.arange(cut), np.arange(cut, n)


def _nonempty_parts(n: int, n_train: int) -> None:
    """InputError when a split of `n` samples with `n_train` training samples leaves a part empty."""
    if not 0 < n_train < n:
        raise InputError(
            f"a split of {n} samples into {n_train} training and {n - n_train} test samples leaves a part empty; "
            "give more samples or a [split] train_fraction nearer 0.5"
        )
