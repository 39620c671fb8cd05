"""Reading a trial: a file (CSV, Excel, Parquet, a ROS 2 bag) or arrays, validated and with its missing derivatives
estimated, into a `Dataset`.

The file format is `docs/data-format.md`: one row per sample, SI units, columns t, q1 … qn, optional dq/ddq, and
either joint torques tau1 … taun or motor currents i1 … in. Every fault is reported as an `InputError` naming the
file (or the array), the column and the first offending row; input files are only read. Arrays (`from_arrays`) go
through the same checks and the same derivative pipeline as a file's columns.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from ident_opt import outputs
from ident_opt.arm.base import Robot
from ident_opt.arm.planar import PI_NAMES
from ident_opt.columns import channel_names, locate
from ident_opt.data import rosbag
from ident_opt.data.checks import (
    _check_columns,
    _check_plausible,
    _check_rate,
    _check_time,
    _check_unique_header,
    _non_increasing,
    _row_label,
)
from ident_opt.data.dataset import Dataset, at_rest, convert, holds_rests, rest_note
from ident_opt.data.validate import checked_array
from ident_opt.errors import InputError, excerpt
from ident_opt.numerics.derivatives import (
    choose_cutoff,
    estimate_derivatives,
    instrument_derivatives,
    lowpass,
    resolve_cutoff,
    settled,
)
from ident_opt.problem.spec import DataSpec
from ident_opt.warnings import ResultWarning


def _read(path: Path, spec: DataSpec) -> pd.DataFrame:
    """The raw table of a data file, or of a ROS 2 bag (`ident_opt.data.rosbag`: already in the data format's names)."""
    outputs.declare_inputs([path])
    outputs.check_length(path, reading=True)  # a name no file system holds: "cannot be read", not an OSError
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
            with open(path, "rb") as fh:  # pyarrow cannot encode a file name that is not UTF-8; a handle has none
                frame = pd.read_parquet(fh)
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


def _locate(
    frame: pd.DataFrame, spec: DataSpec, path: Path, n_joints: int
) -> tuple[dict[str, object], dict[str, tuple[float, float]]]:
    """({data-format name: its column label in `frame`}, the conversions that apply) by the rules every reader of
    the problem's data shares (`columns.locate`)."""
    header = [str(c) for c in frame.columns] if spec.header else None
    found, conversions = locate(header, frame.shape[1], spec, n_joints, str(path))
    return {name: frame.columns[i] for name, i in found.items()}, conversions


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
    return _complete(_read(path, spec), path, spec, robot, allow_implausible, drop_invalid, min_samples)


def from_arrays(
    t: np.ndarray,
    q: np.ndarray,
    tau: np.ndarray | None = None,
    spec: DataSpec | None = None,
    robot: Robot | None = None,
    *,
    current: np.ndarray | None = None,
    dq: np.ndarray | None = None,
    ddq: np.ndarray | None = None,
    source: str = "arrays",
    allow_implausible: bool = False,
    min_samples: int = len(PI_NAMES),
) -> Dataset:
    """A trial from arrays: `t` (N,) [s], `q` (N, n) [rad] and either `tau` (N, n) [N m] or `current` (N, n) [A],
    optionally `dq` [rad/s] and `ddq` [rad/s²], in SI units and in the convention of the problem's data files
    (`Robot.column_map` applies; `[data.columns]` does not: arrays come by role, not by column). Each array is
    checked at the door (`checked_array`: real numbers, its shape, every value finite; an InputError naming it),
    then they go through the loader's own checks and derivative pipeline (`spec.derivative_cutoff_hz`: the same
    cut-off rule, filters and edge trimming as a file); `source` names them in messages and reports."""
    n = robot.n_joints
    times = checked_array(f"{source}: t", t, (None,), " (the sample times [s])")
    columns = {"t": times}
    given = {"q": q, "dq": dq, "ddq": ddq, "tau": tau, "i": current}
    named = {"i": "current"}  # the argument's name where it is not the data format's
    why = f" (one row per sample of t, one column per joint of {robot.described_as})"
    for kind, values in given.items():
        if values is None:
            continue
        a = checked_array(f"{source}: {named.get(kind, kind)}", values, (len(times), n), why)
        columns.update({f"{kind}{j + 1}": a[:, j] for j in range(n)})
    if (tau is None) == (current is None):
        raise InputError(f"{source}: give the joint torques (tau) or the motor currents (current), one of the two")
    frame = pd.DataFrame(columns)
    given = spec or DataSpec()
    by_role = DataSpec(derivative_cutoff_hz=given.derivative_cutoff_hz, rest_velocity=given.rest_velocity)
    return _complete(frame, Path(source), by_role, robot, allow_implausible, False, min_samples)


def _complete(
    frame: pd.DataFrame,
    path: Path,
    spec: DataSpec,
    robot: Robot,
    allow_implausible: bool,
    drop_invalid: bool,
    min_samples: int,
) -> Dataset:
    """The columns of `frame` (read from `path`) located, validated, converted, with derivatives estimated where
    missing: the one pipeline of files and arrays."""
    n_joints = len(robot.joints)
    names = channel_names(n_joints)
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

    dq, ddq, how, cutoff_hz = _derivatives(signals, t, q, keep, path, spec, allow_implausible)
    notes: list[str] = [] if cutoff_hz is None else [f"derivatives {how}"]
    dropped = int(bad.sum())
    if dropped:
        notes.append(f"dropped {dropped} invalid row(s)")
    extra = _extra_columns(frame, cols, keep)
    tau_filtered = None if cutoff_hz is None else lowpass(t, tau, cutoff_hz)
    # Logged derivatives carry the logger's own filters; the instruments come from q at the cut-off the data support.
    instruments = instrument_derivatives(t, q, cutoff_hz if cutoff_hz is not None else choose_cutoff(t, q))
    trial = Dataset(str(path), t, q, dq, ddq, tau, extra, how, dropped, notes, cutoff_hz, tau_filtered, instruments)
    trial = trial if cutoff_hz is None else _settled(trial, path, min_samples)
    if not holds_rests(spec.rest_velocity, trial):
        return trial
    held = at_rest(trial)
    held.notes.append(rest_note(spec.rest_velocity, np.mean((held.dq == 0) & (trial.dq != 0), axis=0)))
    return held


def _derivatives(
    signals: dict[str, np.ndarray],
    t: np.ndarray,
    q: np.ndarray,
    keep: np.ndarray,
    path: Path,
    spec: DataSpec,
    allow_implausible: bool,
) -> tuple[np.ndarray, np.ndarray, str, float | None]:
    """(dq, ddq, how, cut-off [Hz] or None when given): the logged derivatives when both are there, else estimated
    from q and t at the data's cut-off (logged accelerations kept) and checked, since a wrong time unit shows there."""
    if "dq" in signals and "ddq" in signals:
        return signals["dq"], signals["ddq"], "given", None
    cutoff, rule = resolve_cutoff(spec.derivative_cutoff_hz, t, q)
    dq, ddq, how = estimate_derivatives(t, q, cutoff, signals.get("dq"))
    how += rule
    if "ddq" in signals:  # logged accelerations are kept: only the velocities were missing
        ddq, how = signals["ddq"], how + " (accelerations as logged)"
    if not allow_implausible:  # estimated from q and t: a wrong time unit shows here first
        _check_plausible({"dq": dq, "ddq": ddq}, keep, path, spec, estimated=True)
    return dq, ddq, how, cutoff


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


def held_out_overlap(training: Sequence[Dataset], testing: Sequence[Dataset]) -> list[ResultWarning]:
    """A warning per held-out trial that is also a training trial (the same file, or a copy of the same bytes): its
    scores then measure the fit on its own data. Every command that scores held-out trials makes them part of its
    result (terminal, report, JSON `warnings`)."""
    found = []
    for held in testing:
        same = next((t for t in training if _same_trial(Path(t.source), Path(held.source))), None)
        if same is not None:
            found.append(
                ResultWarning(
                    "held_out_is_training",
                    f"{held.source} (held out) is the training trial {same.source}: its scores measure the fit on "
                    "its own data, not on unseen data; hold out another trial",
                )
            )
    return found


def _same_trial(a: Path, b: Path) -> bool:
    """Whether two trial paths are one file (also through links) or two files with the same bytes."""
    try:
        if os.path.samefile(a, b):
            return True
        if a.is_file() and b.is_file() and a.stat().st_size == b.stat().st_size:
            return a.read_bytes() == b.read_bytes()
    except OSError:
        pass
    return False
