"""What the loader checks of a trial before anything is fitted: one column per role and no role twice, every joint's
signals present, time strictly increasing at a rate a robot log can have, values in units that make sense (degrees,
encoder counts or mA are refused). Every fault is an InputError naming the file, the column and the first offending
row."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from ident_opt.columns import channel_names
from ident_opt.data import rosbag
from ident_opt.errors import InputError, excerpt
from ident_opt.problem.spec import DataSpec

#: A standard joint column's name: its signal and its joint number (1-based).
JOINT_COLUMN = re.compile(r"(q|dq|ddq|tau|i)(\d+)")

#: Limits beyond which a value is almost surely in the wrong unit (degrees, encoder counts, mA ...).
PLAUSIBLE = {"q": 100.0, "dq": 1e3, "ddq": 1e5, "tau": 1e5, "i": 1e3}


#: Sampling rates [Hz] a robot log can have: outside, t is almost surely not in seconds.
PLAUSIBLE_RATE_HZ = (0.1, 1e5)
#: The shortest step t may take, as a fraction of its median step: a shorter one is a repeated time stamp to
#: rounding (the fraction the derivative pipeline already treats as rounding, `derivatives._uniform`).
MIN_STEP_FRACTION = 1e-6


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
    """t strictly increasing, each step at least `MIN_STEP_FRACTION` of the median step; else an error naming the
    first row where it repeats, goes back or steps too little. Not lifted by --allow-implausible: the derivative
    pipeline divides by these steps (a step of 1e-300 s overflows its splines to inf)."""
    steps = np.diff(t)
    if (steps <= 0).any():
        row = int(np.argmax(steps <= 0)) + 1
        kind = "repeats" if steps[row - 1] == 0 else "goes back"
        raise InputError(
            f"{path}: column 't' is not strictly increasing: it {kind} at "
            f"{_row_label(path, row, spec)} ({excerpt(float(t[row - 1]))} then {excerpt(float(t[row]))})"
        )
    if not steps.size:
        return
    median = float(np.median(steps))
    short = steps < MIN_STEP_FRACTION * median
    if short.any():
        row = int(np.argmax(short)) + 1
        raise InputError(
            f"{path}: column 't' steps by only {float(steps[row - 1]):.3g} s at {_row_label(path, row, spec)} "
            f"({excerpt(float(t[row - 1]))} then {excerpt(float(t[row]))}), less than {MIN_STEP_FRACTION:g} of its "
            f"median step ({median:.3g} s): the two samples share one time stamp to rounding and no derivative can "
            "be taken between them; correct that time stamp or remove the row"
        )


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


def _row_label(path: Path, row: int, spec: DataSpec) -> str:
    """Where 0-based data row `row` is, as the user finds it: a CSV's line, a ROS 2 bag's message index."""
    if path.name.lower().endswith((".csv", ".csv.gz")):
        return f"data row {row + 1} (line {row + 1 + int(spec.header)} of the file)"
    if path.exists() and rosbag.is_bag(path):
        return rosbag.message_label(row, spec.ros_topic)
    return f"data row {row + 1}"
