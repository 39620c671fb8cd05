"""Two runs' fits side by side (package doc): the parameters with their standard errors, their difference and its
z, and the held-out errors per protocol (or test trial) and joint.

Two runs are independent estimates, so a parameter's difference d = π_this − π_other has the standard error
√(se_this² + se_other²) and z = d / that; it moved "beyond its errors" when |z| > `Z_BEYOND` (3: about one false
flag in 370 parameters that did not move, under Gaussian errors). A parameter without a standard error in either run
(a datasheet value, a parameter the data did not determine) gets no z and is never flagged.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ident_opt.errors import InputError
from ident_opt.outputs import shown

#: |z| beyond which a parameter moved beyond its errors (module doc).
Z_BEYOND = 3.0
#: The held-out protocols whose errors are compared, in this order (those both runs have).
PROTOCOLS = ("cross_trial", "chronological", "paper")


@dataclass(frozen=True)
class RunSummary:
    """One run's fit as a `compare --json` (or `identify --json`) gives it: where it was read, the fit's name, the
    joints, π and its standard errors by parameter name, and the held-out nMSE per joint {protocol or trial: [n]}."""

    source: str
    estimator: str
    joints: tuple[str, ...]
    pi: dict[str, float]
    se: dict[str, float]
    nmse: dict[str, list[float]] = field(default_factory=dict)
    recommended: str | None = None


@dataclass(frozen=True)
class SideBySide:
    """This run against the other: `parameters` (one row per parameter of either run: this, this_se, other,
    other_se, difference, z, beyond), `errors` (one row per protocol or test trial and joint: this, other, ratio
    this/other), the names of the parameters beyond their errors, `threshold` (|z|) and notes (what was compared
    with what, what could not be)."""

    this: RunSummary
    other: RunSummary
    parameters: pd.DataFrame
    errors: pd.DataFrame
    beyond: list[str]
    threshold: float
    notes: list[str]

    def as_json(self) -> dict:
        """The `against` object of `compare --json` (non-finite numbers become null on writing)."""
        return {
            "file": self.other.source,
            "estimator": self.this.estimator,
            "other_estimator": self.other.estimator,
            "z_threshold": self.threshold,
            "beyond": self.beyond,
            "parameters": self.parameters.reset_index().to_dict(orient="records"),
            "errors": self.errors.to_dict(orient="records"),
            "notes": self.notes,
        }


def read_run(path: str | Path, estimator: str | None = None, prefer: str | None = None) -> RunSummary:
    """The fit of a `compare --json` or `identify --json` at `path`: `estimator`, else `prefer` when the run has it
    (like with like: this run's fit), else the run's recommended; InputError naming the file when it cannot be read
    or holds no such fit."""
    return summarize(read_payload(path), shown(path), estimator, prefer)


def read_payload(path: str | Path) -> dict:
    """The JSON at `path`, as written (`summarize` checks it); InputError naming the file when it cannot be read."""
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"--against {shown(path)}: cannot read the other run ({exc})") from None


def summarize(payload: dict, source: str, estimator: str | None = None, prefer: str | None = None) -> RunSummary:
    """A run's summary from its JSON payload (`read_run`: which fit); `source` names it in messages and reports."""
    if not isinstance(payload, dict) or not isinstance(payload.get("parameters"), dict):
        raise InputError(
            f"--against {source}: not a run of ident-opt (expected a `compare --json` or `identify --json`: an object "
            "with a 'parameters' object)"
        )
    fits = {k: v for k, v in payload["parameters"].items() if isinstance(v, dict)}
    name = estimator or (prefer if prefer in fits else payload.get("recommended"))
    if not isinstance(name, str) or name not in fits:
        raise InputError(f"--against {source}: no fit {name!r} in it; it has {', '.join(sorted(fits)) or 'none'}")
    se = (payload.get("standard_errors") or {}).get(name) or {}
    joints = payload.get("joints") or []
    return RunSummary(
        source=source,
        estimator=name,
        joints=tuple(str(j) for j in joints) if isinstance(joints, list) else (),
        pi=_numbers(fits[name], source, name),
        se=_numbers(se if isinstance(se, dict) else {}, source, f"{name}'s standard errors", allow_none=True),
        nmse=_errors(payload, name),
        recommended=payload.get("recommended") if isinstance(payload.get("recommended"), str) else None,
    )


def _numbers(values: dict, source: str, what: str, allow_none: bool = False) -> dict[str, float]:
    """`values` as floats; a value that is not a number is an InputError naming it (None and non-finite standard
    errors, the JSON's null for "not determined", become NaN when `allow_none`)."""
    out = {}
    for k, v in values.items():
        if allow_none and (v is None or (isinstance(v, float) and not math.isfinite(v))):
            out[str(k)] = math.nan
            continue
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise InputError(f"--against {source}: {what}: {k} = {v!r} is not a finite number")
        out[str(k)] = float(v)
    return out


def _errors(payload: dict, estimator: str) -> dict[str, list[float]]:
    """Held-out nMSE per joint of `estimator`: per protocol of `metrics`, then per test trial (`trial <name>`)."""
    out: dict[str, list[float]] = {}
    sources = [(p, (payload.get("metrics") or {}).get(p)) for p in PROTOCOLS]
    sources += [(f"trial {t}", m) for t, m in (payload.get("metrics_by_test_trial") or {}).items()]
    for where, metrics in sources:
        values = ((metrics or {}).get("nmse") or {}).get(estimator) if isinstance(metrics, dict) else None
        if isinstance(values, list) and all(isinstance(v, int | float) or v is None for v in values):
            out[where] = [math.nan if v is None else float(v) for v in values]
    return out


def side_by_side(this: RunSummary, other: RunSummary, threshold: float = Z_BEYOND) -> SideBySide:
    """This run's fit against the other's (module doc): parameters of either run, each with its z; the held-out
    errors both runs report (same protocol or trial, same number of joints)."""
    names = list(dict.fromkeys([*this.pi, *other.pi]))
    a = np.array([this.pi.get(n, np.nan) for n in names])
    b = np.array([other.pi.get(n, np.nan) for n in names])
    sa = np.array([this.se.get(n, np.nan) for n in names])
    sb = np.array([other.se.get(n, np.nan) for n in names])
    with np.errstate(invalid="ignore", divide="ignore"):
        z = (a - b) / np.sqrt(sa**2 + sb**2)
    z[~np.isfinite(z)] = np.nan
    beyond = np.abs(z) > threshold  # NaN compares False: never flagged
    table = pd.DataFrame(
        {"this": a, "this_se": sa, "other": b, "other_se": sb, "difference": a - b, "z": z, "beyond": beyond},
        index=pd.Index(names, name="parameter"),
    )
    notes = _notes(this, other, names)
    return SideBySide(this, other, table, _error_rows(this, other, notes), list(table.index[beyond]), threshold, notes)


def _error_rows(this: RunSummary, other: RunSummary, notes: list[str]) -> pd.DataFrame:
    """One row per protocol or trial both runs report and joint: this, other, ratio this/other."""
    rows = []
    for where in [w for w in this.nmse if w in other.nmse]:
        mine, theirs = this.nmse[where], other.nmse[where]
        if len(mine) != len(theirs):
            notes.append(f"{where}: {len(mine)} joints here, {len(theirs)} there: errors not compared")
            continue
        for j, (x, y) in enumerate(zip(mine, theirs)):
            joint = this.joints[j] if j < len(this.joints) else f"joint{j + 1}"
            ratio = x / y if y > 0 else math.nan
            rows.append({"held_out": where, "joint": joint, "this": x, "other": y, "ratio": ratio})
    if not rows:
        notes.append("no held-out error reported by both runs on the same protocol or trial")
    return pd.DataFrame(rows, columns=["held_out", "joint", "this", "other", "ratio"])


def _notes(this: RunSummary, other: RunSummary, names: list[str]) -> list[str]:
    """What was compared with what, and what could not be."""
    notes = [f"this run's {this.estimator} fit against {other.source}'s {other.estimator} fit"]
    if this.estimator != other.estimator:
        notes.append(f"the fits differ ({this.estimator} here, {other.estimator} there): a difference may be the fit's")
    only = [n for n in names if n not in this.pi or n not in other.pi]
    if only:
        notes.append(f"{len(only)} parameter(s) in one run only (different models): {', '.join(only[:8])}")
    if this.joints and other.joints and this.joints != other.joints:
        notes.append(f"the joints differ: {', '.join(this.joints)} here, {', '.join(other.joints)} there")
    return notes
