"""A simulated fleet: robots of one model around its nominal arm, a day's logs each, with hidden changes and
day-to-day scatter, written in the fleet layout (`docs/data-format.md`), for the tests and the benchmark.

    python benchmarks/simulate_fleet.py --problem P --out ROOT [--robots 30] [--days 20] [--seed 0] ...

Every option is checked before any work, against `BOUNDS` and the size limits (`MAX_FILE_SAMPLES` per file,
`MAX_SAMPLES` and `MAX_FILES` in all): a value outside is an InputError naming the option (the script: exit 2 naming the
flag). The fleet is written into a temporary folder beside ROOT and renamed onto it when complete: on an error or Ctrl-C
nothing is left.

The plant is the problem's own identification model, τ = Y(q, dq, ddq) π (rigid inverse dynamics plus the
joint terms), evaluated on the exact motion; the files hold what a logger gives: t, the angles with encoder noise
and the torques with noise, so the reader estimates dq and ddq as it does on real logs. Per robot and day:

- **the robot**: the nominal π (the problem's datasheet or URDF; a friction term it lacks gets
  `NOMINAL_FRICTION` of its joint's rigid torque, at least `WRIST_FRICTION` of the largest), every rigid-body
  parameter × one factor 1 + N(0, `spread`)
  (a consistent arm stays consistent), each friction term × 1 + N(0, 3 `spread`), offsets N(0, 2 %) of the
  joint's torque;
- **scatter**: friction × 1 + N(0, `temperature`) (one factor for the day plus a half as large per joint), a new
  excitation each day (a random Fourier series, `ident_opt.simulator.fourier`) of a random length (±30 %), torque
  noise of `noise` × each joint's RMS torque in the file;
- **hidden changes** (`Hidden`, written to ROOT/_truth.json, a name the fleet's reader skips), on a fraction
  `changed` of the robots, starting on a day after the baseline: `wear` (a joint's friction terms grow linearly,
  by 40–80 % at the last day), `payload` (from that day a point mass on the last link, `Robot.payload`, whose
  torque is 10–25 % of the most affected joint's), `drive` (a joint's logged torque × a factor 0.85–0.92 or
  1.08–1.15: a torque constant or gain that moved; only on a joint whose torque is not mostly friction,
  `RIGID_SHARE`: elsewhere it could not be told from a change of that joint's friction); on request `other` (a
  constant offset of 5–10 % of a joint's RMS torque on its logged torque: no cause the fleet names).
"""

from __future__ import annotations

import datetime
import json
import os
import shutil
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ident_opt.arguments import MAX_SEED
from ident_opt.columns import columns_of
from ident_opt.data.dataset import in_source_convention
from ident_opt.errors import InputError, excerpt
from ident_opt.problem import load_problem
from ident_opt.simulator.fourier import Fourier

#: The causes a simulated fleet can hide, one per changed robot, in turn (`FleetSpec.causes`): the three the fleet
#: names, and `other`, a constant torque offset on one joint from one day (a torque sensor's zero that moved).
CAUSES = ("wear", "payload", "drive", "other")
#: A friction term the nominal model lacks gets this fraction of its joint's rigid RMS torque, and at least
#: `WRIST_FRICTION` of the largest joint's (a wrist's drive has friction, however light its links).
NOMINAL_FRICTION, WRIST_FRICTION = 0.1, 0.02
#: A drive change is hidden only on a joint whose rigid torque is at least this share of its torque (RMS): on a
#: joint whose torque is nearly all friction (a light wrist), one factor on it is a change of its friction.
RIGID_SHARE = 0.5
#: The file the ground truth goes to, in ROOT (a leading underscore: the fleet's reader skips it).
TRUTH = "_truth.json"
#: The excitation: harmonics of the Fourier series and its base frequency [Hz].
HARMONICS, BASE_HZ = 4, 0.2
#: Each numeric option's accepted range, both ends included (`check_spec`, and the script's flags).
BOUNDS: dict[str, tuple[float, float]] = {
    "robots": (1, 10_000),
    "days": (1, 3650),
    "files_per_day": (1, 100),
    "seconds": (1.0, 3600.0),  # s, a file's length before its ±30 %
    "rate_hz": (1.0, 5000.0),  # Hz, as `ident-opt simulate --rate`
    "spread": (0.0, 0.5),
    "temperature": (0.0, 0.5),
    "noise": (0.0, 1.0),
    "angle_noise": (0.0, 0.1),  # rad
    "changed": (0.0, 1.0),
    "baseline_days": (2, 3650),  # as `ident-opt fleet --baseline-days`
    "seed": (0, MAX_SEED),
}
#: At most this many samples in one file (its longest, 1.3 × seconds × rate: the regressor a file's torques come
#: from holds joints × parameters numbers per sample), this many in the whole fleet, and this many files.
MAX_FILE_SAMPLES, MAX_SAMPLES, MAX_FILES = 200_000, 100_000_000, 200_000


@dataclass(frozen=True)
class FleetSpec:
    """What to simulate: `robots` × `days` (from `start`, ISO date), `files_per_day` files of about `seconds` [s]
    at `rate_hz` [Hz] each; the scatter (`spread`, `temperature`, `noise` as fractions, `angle_noise` [rad]);
    the share of robots with a hidden change (`changed`), none starting before day `baseline_days` + 2, their
    `causes` (comma-separated names of `CAUSES`, taken in turn)."""

    robots: int = 30
    days: int = 20
    start: str = "2026-03-01"
    files_per_day: int = 1
    seconds: float = 30.0
    rate_hz: float = 200.0
    spread: float = 0.03
    temperature: float = 0.03
    noise: float = 0.02
    angle_noise: float = 1e-4
    changed: float = 0.5
    baseline_days: int = 5
    causes: str = "wear,payload,drive"
    seed: int = 0


@dataclass(frozen=True)
class Hidden:
    """A hidden change: its robot, cause (`CAUSES`), joint (1-based; None for a payload), the first day it acts
    on (ISO date) and its size (wear: the friction's relative growth by the last day; payload: the mass [kg];
    drive: the factor on the logged torque; other: the torque offset [N m])."""

    robot: str
    cause: str
    joint: int | None
    first_day: str
    size: float


@dataclass(frozen=True)
class _Plant:
    """What the generator knows of the model: the arm, its nominal π with friction, each joint's RMS torque on a
    reference motion [N m], and the index sets of the parameters by role."""

    arm: object
    pi: np.ndarray
    rms: np.ndarray  # each joint's RMS torque on the reference motion, friction included [N m]
    rigid: np.ndarray  # bool (P,): inertial, coupling and gravity parameters
    friction: np.ndarray  # int (P,): the joint (1-based) of a friction term, 0 otherwise
    offset: np.ndarray  # int (P,): the joint of an offset-like term (kind "other" with a joint), 0 otherwise
    drives: np.ndarray  # the joints (1-based) a drive change may be hidden on (`RIGID_SHARE`)


def check_spec(spec: FleetSpec) -> None:
    """Every field of `spec` in its `BOUNDS` (an integer where the default is one), the start a date that the last
    day still is, the causes known, and the fleet within the size limits; an InputError naming the flag."""
    for key, (low, high) in BOUNDS.items():
        value, integer = getattr(spec, key), isinstance(getattr(FleetSpec, key), int)
        kinds = (int, np.integer) if integer else (int, float, np.integer, np.floating)
        flag = "--" + key.replace("_", "-")
        if isinstance(value, bool) or not isinstance(value, kinds) or not (np.isfinite(value) and low <= value <= high):
            what = "an integer" if integer else "a number"
            raise InputError(f"{flag} must be {what} in [{low:g}, {high:g}], got {excerpt(value)}")
    try:
        datetime.date.fromisoformat(spec.start) + datetime.timedelta(days=spec.days - 1)
    except (TypeError, ValueError, OverflowError):
        raise InputError(
            f"--start must be a date (YYYY-MM-DD) whose {spec.days} days end by 9999-12-31, got {excerpt(spec.start)}"
        ) from None
    causes = [c.strip() for c in str(spec.causes).split(",") if c.strip()]
    if not causes or any(c not in CAUSES for c in causes):
        raise InputError(f"--causes must be names of {', '.join(CAUSES)}, comma-separated, got {excerpt(spec.causes)}")
    per_file = 1.3 * spec.seconds * spec.rate_hz
    files = spec.robots * spec.days * spec.files_per_day
    if per_file > MAX_FILE_SAMPLES:
        raise InputError(
            f"--seconds {spec.seconds:g} at --rate-hz {spec.rate_hz:g}: up to {per_file:,.0f} samples in a file, "
            f"more than {MAX_FILE_SAMPLES:,}; give fewer seconds or a lower rate"
        )
    if files > MAX_FILES:
        raise InputError(
            f"--robots {spec.robots} × --days {spec.days} × --files-per-day {spec.files_per_day}: {files:,} files, "
            f"more than {MAX_FILES:,}"
        )
    if files * spec.seconds * spec.rate_hz > MAX_SAMPLES:
        raise InputError(
            f"--robots × --days × --files-per-day × --seconds × --rate-hz: about "
            f"{files * spec.seconds * spec.rate_hz:,.0f} samples, more than {MAX_SAMPLES:,}; simulate a smaller fleet"
        )


def robot_names(count: int) -> list[str]:
    """R01, R02, … (zero-padded to the width of `count`)."""
    width = max(2, len(str(count)))
    return [f"R{i + 1:0{width}d}" for i in range(count)]


def motion(problem, seconds: float, rate_hz: float, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """(t, q, dq, ddq): a random Fourier excitation of `seconds` [s] at `rate_hz` [Hz] around the middle of the
    problem's position limits (0 without), at about 40 % of its velocity limits (0.8 rad/s without)."""
    n = problem.robot.n_joints
    limits = problem.limits
    centre = np.zeros(n) if limits is None else 0.5 * (np.array(limits.position_min) + np.array(limits.position_max))
    speed = np.full(n, 0.8) if limits is None else np.minimum(0.4 * np.array(limits.velocity), 0.8)
    series = Fourier(n, HARMONICS, BASE_HZ)
    t = np.arange(round(seconds * rate_hz)) / rate_hz
    Bq, Bv, Ba = series.basis(t)
    q, dq, ddq = (np.empty((len(t), n)) for _ in range(3))
    for j in range(n):
        x = np.concatenate([[centre[j]], rng.normal(0.0, speed[j] / np.sqrt(HARMONICS), 2 * HARMONICS)])
        q[:, j], dq[:, j], ddq[:, j] = Bq @ x, Bv @ x, Ba @ x
    return t, q, dq, ddq


def long_trial(problem_path: str | Path, samples: int, rate_hz: float, seed: int = 0) -> pd.DataFrame:
    """One logged trial of the problem's nominal arm of `samples` rows at `rate_hz` [Hz] (the fleet's motion and
    noise, `FleetSpec`'s defaults), in the data format: for measuring how a task's cost grows with a file's length."""
    problem, rng, spec = load_problem(problem_path), np.random.default_rng(seed), FleetSpec()
    plant = _plant(problem)
    t, q, dq, ddq = motion(problem, samples / rate_hz, rate_hz, rng)
    tau = plant.arm.predict(plant.pi, q, dq, ddq)
    tau += rng.normal(0.0, 1.0, tau.shape) * spec.noise * np.sqrt(np.mean(tau**2, axis=0))
    q_logged = q + rng.normal(0.0, spec.angle_noise, q.shape)
    frame = pd.DataFrame({"t": t, **columns_of({"q": q_logged, "tau": tau})})
    return in_source_convention(frame, problem.robot.column_map)


def _plant(problem) -> _Plant:
    """The model, its nominal π (friction where the nominal has none: `NOMINAL_FRICTION`) and the roles."""
    robot = problem.robot
    arm = robot.model()
    source, values = robot.datasheets()[robot.datasheet]
    pi = arm.vector(source.as_dict(values))
    _, q, dq, ddq = motion(problem, 20.0, 100.0, np.random.default_rng(12345))
    Y = arm.regressor(q, dq, ddq)
    kinds = [p.kind for p in arm.parameters]
    rigid = np.array([k in ("inertia", "coupling", "gravity") for k in kinds])
    rms = np.sqrt(np.mean((Y[:, :, rigid] @ pi[rigid]) ** 2, axis=0))
    joint = np.array([p.joint or 0 for p in arm.parameters])
    friction = np.where(np.array(kinds) == "friction", joint, 0)
    offset = np.where(np.array(kinds) == "other", joint, 0)
    floor = np.maximum(NOMINAL_FRICTION * rms, WRIST_FRICTION * rms.max())
    for i in np.flatnonzero((friction > 0) & (pi == 0)):
        column = Y[:, friction[i] - 1, i]
        pi[i] = floor[friction[i] - 1] / max(np.sqrt(np.mean(column**2)), 1e-12)
    total = np.sqrt(np.mean((Y @ pi) ** 2, axis=0))
    shown = np.flatnonzero(rms >= RIGID_SHARE * total) + 1
    drives = shown if shown.size else np.arange(1, len(rms) + 1)
    return _Plant(arm, pi, total, rigid, friction, offset, drives)


def _robot_pi(plant: _Plant, spec: FleetSpec, rng: np.random.Generator) -> np.ndarray:
    """One robot's π around the nominal (module doc)."""
    pi = plant.pi.copy()
    pi[plant.rigid] *= 1.0 + rng.normal(0.0, spec.spread)
    f = plant.friction > 0
    pi[f] *= np.clip(1.0 + rng.normal(0.0, 3 * spec.spread, f.sum()), 0.5, None)
    o = np.flatnonzero(plant.offset)
    pi[o] += rng.normal(0.0, 0.02, o.size) * plant.rms[plant.offset[o] - 1]
    return pi


def _hidden(
    names: list[str], spec: FleetSpec, n_joints: int, drives: np.ndarray, rng: np.random.Generator
) -> dict[str, dict]:
    """robot → its hidden change (cause, joint, first day index, size); robots with none are absent. A drive change
    goes to one of `drives` (1-based), any other to any joint."""
    count = round(spec.changed * len(names))
    chosen = rng.permutation(len(names))[:count]
    first, last = spec.baseline_days + 2, spec.days - 4
    if count and first > last:
        raise InputError(
            f"a simulated fleet of {spec.days} days cannot hide a change after {spec.baseline_days} baseline days "
            f"and before the last 4: give at least {spec.baseline_days + 6} days"
        )
    causes = [c.strip() for c in spec.causes.split(",") if c.strip()]
    unknown = [c for c in causes if c not in CAUSES]
    if unknown or not causes:
        raise InputError(f"unknown cause(s) {unknown or causes}; a simulated fleet hides {', '.join(CAUSES)}")
    out = {}
    for k, index in enumerate(sorted(chosen)):
        cause = causes[k % len(causes)]
        joints = drives if cause == "drive" else np.arange(1, n_joints + 1)
        joint = None if cause == "payload" else int(rng.choice(joints))
        size = {
            "wear": rng.uniform(0.4, 0.8),
            "payload": rng.uniform(0.10, 0.25),  # the payload's torque, relative to the joint's (below)
            "drive": 1.0 + rng.choice([-1.0, 1.0]) * rng.uniform(0.08, 0.15),
            "other": rng.choice([-1.0, 1.0]) * rng.uniform(0.05, 0.10),  # the offset, relative to the joint's torque
        }[cause]
        out[names[index]] = {"cause": cause, "joint": joint, "day": int(rng.integers(first, last + 1)), "size": size}
    return out


def _payload_mass(problem, plant: _Plant, share: float) -> float:
    """The mass [kg] whose torque on the reference motion is `share` of the most affected joint's torque (RMS)."""
    _, q, dq, ddq = motion(problem, 20.0, 100.0, np.random.default_rng(12345))
    unit = plant.arm.regressor(q, dq, ddq) @ problem.robot.payload(plant.arm, 1.0)
    ratio = np.sqrt(np.mean(unit**2, axis=0)) / plant.rms
    return float(share / ratio.max())


def simulate_fleet(problem_path: str | Path, root: str | Path, spec: FleetSpec = FleetSpec()) -> list[Hidden]:
    """Write a simulated fleet of `spec` for the problem at `problem_path` into `root` (which must be missing or
    empty) in the fleet layout, and its ground truth into root/_truth.json; return the hidden changes. `spec` is
    checked first (`check_spec`); the fleet is written into a temporary folder renamed onto `root` when complete
    (module doc)."""
    root = Path(root).absolute()
    if root.exists() and not (root.is_dir() and not any(root.iterdir())):
        raise InputError(f"--out {root}: exists and is not an empty folder; a simulated fleet goes into a new folder")
    check_spec(spec)
    problem = load_problem(problem_path)
    rng = np.random.default_rng(spec.seed)
    plant = _plant(problem)
    names = robot_names(spec.robots)
    hidden = _hidden(names, spec, problem.robot.n_joints, plant.drives, rng)
    start = datetime.date.fromisoformat(spec.start)
    days = [(start + datetime.timedelta(days=d)).isoformat() for d in range(spec.days)]
    parent = next(p for p in root.parents if p.exists())  # the temporary folder must be on root's filesystem
    staging = Path(tempfile.mkdtemp(prefix=f".{root.name}.", suffix=".partial", dir=parent))
    try:
        truth = _write_fleet(problem, plant, spec, names, days, hidden, rng, staging)
        record = {"problem": str(problem_path), "spec": asdict(spec), "hidden": [asdict(h) for h in truth]}
        (staging / TRUTH).write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")
        os.chmod(staging, 0o777 & ~_umask())  # mkdtemp's folder is private; the fleet is a folder like any other
        root.parent.mkdir(parents=True, exist_ok=True)
        if root.exists():
            root.rmdir()  # empty (checked above)
        staging.rename(root)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return truth


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _write_fleet(problem, plant: _Plant, spec: FleetSpec, names, days, hidden, rng, root: Path) -> list[Hidden]:
    """Every robot's days' files into `root`; the hidden changes."""
    truth = []
    for name in names:
        pi = _robot_pi(plant, spec, rng)
        change = hidden.get(name)
        if change is not None:
            if change["cause"] == "payload":
                change["size"] = _payload_mass(problem, plant, change["size"])
            elif change["cause"] == "other":
                change["size"] *= float(plant.rms[change["joint"] - 1])
            truth.append(Hidden(name, change["cause"], change["joint"], days[change["day"]], float(change["size"])))
        for d, day in enumerate(days):
            folder = root / f"robot={name}" / f"day={day}"
            folder.mkdir(parents=True, exist_ok=True)
            for f in range(spec.files_per_day):
                _write(_day_file(problem, plant, pi, spec, d, change, rng), folder, f, d)
    return truth


def _day_file(problem, plant: _Plant, pi: np.ndarray, spec: FleetSpec, d: int, change, rng) -> pd.DataFrame:
    """One logged trial of a robot on day index `d`: its π with the day's scatter and its hidden `change` (a dict
    of `_hidden`, the payload's size a mass [kg]) from its first day on."""
    n = problem.robot.n_joints
    pi = pi.copy()
    f = plant.friction > 0
    pi[f] *= 1.0 + rng.normal(0.0, spec.temperature) + rng.normal(0.0, spec.temperature / 2, f.sum())
    scale = np.ones(n)
    if change is not None and d >= change["day"]:
        if change["cause"] == "wear":
            grown = (d - change["day"] + 1) / (spec.days - change["day"])
            pi[plant.friction == change["joint"]] *= 1.0 + change["size"] * grown
        elif change["cause"] == "payload":
            pi += problem.robot.payload(plant.arm, change["size"])
        elif change["cause"] == "drive":
            scale[change["joint"] - 1] = change["size"]
    seconds = spec.seconds * rng.uniform(0.7, 1.3)
    t, q, dq, ddq = motion(problem, seconds, spec.rate_hz, rng)
    tau = plant.arm.predict(pi, q, dq, ddq) * scale
    if change is not None and change["cause"] == "other" and d >= change["day"]:
        tau[:, change["joint"] - 1] += change["size"]
    tau += rng.normal(0.0, 1.0, tau.shape) * spec.noise * np.sqrt(np.mean(tau**2, axis=0))
    q_logged = q + rng.normal(0.0, spec.angle_noise, q.shape)
    frame = pd.DataFrame({"t": t, **columns_of({"q": q_logged, "tau": tau})})
    return in_source_convention(frame, problem.robot.column_map)


def _write(frame: pd.DataFrame, folder: Path, index: int, day: int) -> Path:
    """A day's file `index`: Parquet, except every third day's first file, a CSV (gzip-compressed on even days)."""
    if index == 0 and day % 3 == 2:
        path = folder / ("log.csv.gz" if day % 2 == 0 else "log.csv")
        frame.to_csv(path, index=False)
    else:
        path = folder / f"log{index}.parquet"
        frame.to_parquet(path, index=False)
    return path


def read_truth(root: str | Path) -> list[Hidden]:
    """The hidden changes a simulated fleet in `root` was written with."""
    record = json.loads((Path(root) / TRUTH).read_text(encoding="utf-8"))
    return [Hidden(**h) for h in record["hidden"]]
