"""What runs on a Dask worker: each function takes and returns small picklable objects; samples never leave it.

- `file_stats`: a `FleetFile` → `FileStats`, the trial's `Stats` (a few kB whatever its length) or why it was
  skipped;
- `day_stats`: files' `FileStats` → `DayStats`, their sum with the files read and skipped (a robot-day, or the days
  of a baseline or of a change pooled);
- `fit_day`: a robot-day's `DayStats` → `DayFit`, its fit (π with standard errors) and the tested parameters;
- `baseline`: a robot's first days pooled → `Baseline`, π0 (OLS) and each joint's weight 1/σ²;
- `evidence`: the days of a change pooled and the `Baseline` → `Evidence`, how much of the misfit to π0 each named
  cause explains.

A file is read by the loader every command uses (`data.load_dataset`: the problem's column mapping, units,
derivative filter, checks) and judged fittable as every command does (`data.fittable`); its `InputError` becomes
the skip reason. The problem is loaded once per worker process (`setup`, by its path: a worker on another machine
needs the same path, as it needs the logs).

Evidence, from the statistics alone (`Stats`: per joint G_j = Σ Y_jᵀY_j, b_j = Σ Y_jᵀτ_j, s_j = Σ τ_j²), with the
baseline π0 and joint weights w_j: the misfit RSS0 = Σ_j w_j (s_j − 2 b_j·π0 + π0ᵀG_jπ0). A cause that moves π
along directions A (P, m) — `wear` of joint j: its friction terms; `payload`: the last link's (`Robot.tool_directions`);
`full`: every parameter — explains δᵀh of it, with H = Σ_j w_j AᵀG_jA, h = Σ_j w_j Aᵀ(b_j − G_jπ0), δ = H⁺h. A
`drive` of joint j scales that joint's torque, τ_j = k Y_jπ0: k = u/v with u = b_j·π0, v = π0ᵀG_jπ0, explaining
w_j (u − v)²/v.
"""

from __future__ import annotations

import contextlib
import functools
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import fsspec
import numpy as np
from fsspec.implementations.local import LocalFileSystem

from ident_opt.arm.base import Arm, Robot
from ident_opt.data import fittable, load_dataset
from ident_opt.errors import InputError
from ident_opt.fleet.layout import FleetFile
from ident_opt.identify import estimators
from ident_opt.identify.base import BaseParameters, base_parameters, fit_base_ols, fit_least_squares
from ident_opt.identify.fit import solve_normal
from ident_opt.identify.stats import Stats
from ident_opt.problem import load_problem

#: A robot-day is fitted when its samples × joints reach this many times the base parameters.
MIN_ROWS_PER_PARAMETER = 5


def fleet_estimator(robot: Robot) -> str:
    """The fit each robot-day gets: the one the tool stands behind for this arm (the one place to choose it)."""
    return robot.default_estimator


@dataclass(frozen=True)
class Job:
    """What every task of a run shares: the problem file (absolute path) and the loader's switches."""

    problem: str
    allow_implausible: bool = False
    drop_invalid: bool = False


@dataclass(frozen=True, eq=False)
class Setup:
    """A worker's view of the problem, built once per process: the robot, its model, the fit, the base parameters
    (the quantities tested for changes) and the causes' directions."""

    problem: object
    robot: Robot
    model: Arm
    estimator: str
    base: BaseParameters
    causes: dict[str, np.ndarray]  # "wear:j" / "payload" / "full" -> A (P, m)

    @property
    def tested(self) -> tuple[str, ...]:
        """The identifiable parameters each day is tested on: the base parameters (every parameter of an arm whose
        data determine them all), named after their independent standard parameter."""
        return self.base.names


@functools.lru_cache(maxsize=4)
def setup(problem_path: str) -> Setup:
    """The `Setup` of the problem at `problem_path` (cached per process)."""
    problem = load_problem(problem_path)
    robot = problem.robot
    model = robot.model()
    P = model.n_params
    causes = {}
    for j in range(1, model.n_joints + 1):
        friction = [i for i, p in enumerate(model.parameters) if p.kind == "friction" and p.joint == j]
        if friction:
            causes[f"wear:{j}"] = np.eye(P)[:, friction]
    causes["payload"] = robot.tool_directions(model)
    causes["full"] = np.eye(P)
    return Setup(problem, robot, model, fleet_estimator(robot), base_parameters(model), causes)


# ---------------------------------------------------------------------------------------------- files
def ready(problem_path: str) -> int:
    """Load the problem on this worker (`setup`) and return its number of parameters: a run's first task."""
    return setup(problem_path).model.n_params


@dataclass
class FileStats:
    """One file's statistics (None when skipped, with the `reason`) and its number of samples."""

    file: FleetFile
    stats: Stats | None
    samples: int = 0
    reason: str = ""


@contextlib.contextmanager
def local_copy(url: str) -> Iterator[Path]:
    """A local path to the file at `url`: itself when local, else a temporary copy with the same name (the loader
    reads by path and by file ending), removed afterwards."""
    fs, path = fsspec.core.url_to_fs(url)
    if isinstance(fs, LocalFileSystem):
        yield Path(path)
        return
    with tempfile.TemporaryDirectory(prefix="ident-opt-fleet-") as folder:
        local = Path(folder) / PurePosixPath(path).name
        try:
            fs.get_file(path, str(local))
        except (OSError, ValueError) as exc:
            raise InputError(f"{local}: cannot fetch {url} ({exc})") from None
        yield local


def file_stats(job: Job, file: FleetFile) -> FileStats:
    """Read, check, differentiate and reduce one trial to its statistics with the torque the fits use
    (`Dataset.tau_fit`); a file the loader refuses is returned as skipped, with the loader's reason."""
    s = setup(job.problem)
    local = file.url
    try:
        with local_copy(file.url) as local:
            trial = load_dataset(
                local,
                s.problem.data,
                s.robot,
                allow_implausible=job.allow_implausible,
                drop_invalid=job.drop_invalid,
            )
            fittable(trial)
    except InputError as exc:
        reason = str(exc).replace(f"{local}: ", "", 1).replace(str(local), file.name)
        return FileStats(file, None, 0, reason)
    stats = Stats.from_data(s.model, trial.q, trial.dq, trial.ddq, trial.tau_fit)
    return FileStats(file, stats, trial.n)


# ---------------------------------------------------------------------------------------------- days
@dataclass
class DayStats:
    """A robot-day's statistics (the sum over its readable files; None if none was), the files read and the ones
    skipped (`{"file", "reason"}`), and the samples."""

    robot: str
    day: str
    stats: Stats | None
    files: list[str]
    skipped: list[dict]
    samples: int


def day_stats(*files: FileStats, day: str | None = None) -> DayStats:
    """The sum of the files' statistics, labelled with the first file's robot and day (or `day`)."""
    read = [f for f in files if f.stats is not None]
    total = None
    for f in read:
        total = f.stats.copy() if total is None else total + f.stats
    first = files[0].file
    skipped = [{"file": f.file.name, "reason": f.reason} for f in files if f.stats is None]
    samples = sum(f.samples for f in read)
    return DayStats(first.robot, day or first.day, total, [f.file.name for f in read], skipped, samples)


@dataclass
class DayFit:
    """A robot-day's fit: π and its standard errors (NaN where the data do not determine a parameter) by the
    model's names, the tested quantities (`Setup.tested`) with their OLS standard errors, and notes. `pi` is None
    when the day could not be fitted (`notes` say why)."""

    robot: str
    day: str
    files: list[str]
    skipped: list[dict]
    samples: int
    pi: np.ndarray | None = None
    se: np.ndarray | None = None
    tested: np.ndarray | None = None
    tested_se: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)


def fit_day(job: Job, day: DayStats) -> DayFit:
    """The robot-day's fit by `fleet_estimator` with standard errors (OLS's where the fit gives none at all), and
    its base parameters: the fit's π projected on them (K π), with the OLS fit's standard errors on them."""
    s = setup(job.problem)
    out = DayFit(day.robot, day.day, day.files, day.skipped, day.samples)
    stats = day.stats
    if stats is None:
        out.notes.append("no readable trial")
        return out
    if stats.n * s.model.n_joints < MIN_ROWS_PER_PARAMETER * s.base.rank:
        out.notes.append(f"{stats.n} samples: too few for the {s.base.rank} identifiable parameters")
        return out
    try:
        fit = estimators.fit_for(s.robot, s.estimator, stats, s.model)
    except RuntimeError as exc:  # a solver failure: the day has no fit
        out.notes.append(f"the {s.estimator} fit failed ({exc})")
        return out
    se = fit.se
    if not np.isfinite(se).any():
        se = fit_least_squares(stats, s.model).se
    ols = fit_base_ols(stats, s.model)
    out.pi, out.se = fit.pi, se
    out.tested, out.tested_se = s.base.project(fit.pi), ols.fit.se
    out.notes += fit.warnings
    return out


# ---------------------------------------------------------------------------------------------- changes
@dataclass
class Baseline:
    """A robot's baseline model: π0 (P,) fitted by OLS on its first days' statistics together, the joint weights
    w_j = 1/σ_j² [1/(N² m²)] from that fit's residual, and the days it used."""

    robot: str
    pi: np.ndarray
    weights: np.ndarray
    days: list[str]


def baseline(job: Job, *days: DayStats) -> Baseline | None:
    """The baseline model of a robot from its first days (None when none of them was readable)."""
    s = setup(job.problem)
    read = [d for d in days if d.stats is not None]
    if not read:
        return None
    total = read[0].stats.copy()
    for d in read[1:]:
        total += d.stats
    fit = fit_least_squares(total, s.model)
    weights = 1.0 / np.maximum(fit.sigma2, 1e-12 * max(float(fit.sigma2.max()), 1e-300))
    return Baseline(read[0].robot, fit.pi, weights, [d.day for d in read])


@dataclass
class Evidence:
    """A robot-day against its baseline: the weighted misfit RSS0 of π0, how much of it each cause explains
    (`reductions`: "drive:j", "wear:j", "payload", "full"), each joint's torque scale k_j with its standard error,
    and each joint's friction growth (δ·π0_f / π0_f·π0_f, the relative change along its baseline friction)."""

    robot: str
    day: str
    rss0: float
    reductions: dict[str, float]
    scale: np.ndarray
    scale_se: np.ndarray
    growth: dict[str, float]


def evidence(job: Job, day: DayStats, base: Baseline | None) -> Evidence | None:
    """The day's `Evidence` against the robot's baseline (module doc); None without statistics or baseline."""
    if day.stats is None or base is None:
        return None
    s = setup(job.problem)
    S, pi0, w = day.stats, base.pi, base.weights
    r0 = S.rss(pi0)
    u = S.b @ pi0
    v = np.maximum(np.einsum("p,jpr,r->j", pi0, S.G, pi0), 1e-300)
    scale = u / v
    rss_scaled = np.maximum(S.s - u**2 / v, 0.0)
    scale_se = np.sqrt(rss_scaled / max(S.n - 1, 1) / v)
    reductions = {f"drive:{j + 1}": float(w[j] * (u[j] - v[j]) ** 2 / v[j]) for j in range(S.n_joints)}
    growth = {}
    for key, A in s.causes.items():
        H = np.einsum("j,pa,jpr,rb->ab", w, A, S.G, A)
        h = np.einsum("j,pa,jp->a", w, A, S.b - np.einsum("jpr,r->jp", S.G, pi0))
        delta = solve_normal(H, h)
        reductions[key] = float(delta @ h)
        if key.startswith("wear:"):
            f0 = A.T @ pi0
            growth[key] = float(delta @ f0 / max(f0 @ f0, 1e-300))
    return Evidence(day.robot, day.day, float(w @ r0), reductions, scale, scale_se, growth)
