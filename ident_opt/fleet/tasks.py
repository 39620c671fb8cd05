"""What runs on a Dask worker (`baseline`, `scales`, `evidence`: on the client, from statistics): each function
takes and returns small picklable objects; samples never leave the worker.

- `choose`: a robot's first days' files → `RobotChoice`, the fit its days get: the recommended fit
  (`fitting.recommend.evidence` on the first day that has a readable trial, its trials read together on the worker),
  or the one `--estimator` names;
- `file_stats`: a `FleetFile` and its robot's `RobotChoice` → `FileStats`, the trial's `Stats` (a few kB whatever its
  length; with its `InstrumentStats` when the chosen fit is the robust one; derivatives at the choice's cut-off
  factor) or why it was skipped;
- `day_stats`: files' `FileStats` → `DayStats`, their sum with the files read and skipped (a robot-day, or the days
  of a baseline or of a change pooled);
- `fit_day`: a robot-day's `DayStats` and `RobotChoice` → `DayFit`, its fit (π with standard errors) and the tested
  parameters;
- `baseline`: a robot's first days → `Baseline`, π0 (OLS on the first K with statistics, pooled) and each joint's
  weight 1/σ²;
- `scales`: a robot-day and its `Baseline` → `Scales`, the factor on each joint's torque against π0;
- `evidence`: the days of a change pooled and the `Baseline` → `Evidence`, how much of the misfit to π0 each named
  cause explains.

A file is read by the loader every command uses (`data.load_dataset`: the problem's column mapping, units,
derivative filter, checks) and judged fittable as every command does (`data.fittable`); its `InputError` becomes
the skip reason. The problem is loaded once per worker process (`setup`, by its path: a worker on another machine
needs the same path, as it needs the logs).

Evidence, from the statistics alone (`Stats`: per joint G_j = Σ Y_jᵀY_j, b_j = Σ Y_jᵀτ_j, s_j = Σ τ_j²), with the
baseline π0 and joint weights w_j: the misfit RSS0 = Σ_j w_j (s_j − 2 b_j·π0 + π0ᵀG_jπ0). A cause is a few columns,
each a direction a in π acting on some joints (Y_j a on joint j): `wear` of joint j, its friction terms on every
joint; `payload`, the directions a body on the last link moves π along (`Robot.tool_directions`); `drive` of joint j,
π0 itself on joint j only (τ_j = k Y_jπ0); `offset` of joint j, its constant torque offset where the model has one
(a cause the contract calls `other`); `full`, every parameter. A cause explains δᵀh of RSS0, with
H_cd = Σ_j w_j a_cᵀG_ja_d (over the joints both columns act on), h_c = Σ_j w_j a_cᵀ(b_j − G_jπ0), δ = H⁺h.
"""

from __future__ import annotations

import contextlib
import functools
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ident_opt.arm.base import Arm, Robot
from ident_opt.data.dataset import Dataset, fittable
from ident_opt.data.loader import load_dataset
from ident_opt.errors import InputError
from ident_opt.fitting import estimators, recommend
from ident_opt.fitting.base import BaseParameters, base_parameters, fit_base_ols, fit_least_squares
from ident_opt.fitting.iv import InstrumentStats
from ident_opt.fitting.stats import Stats
from ident_opt.fleet import streamed
from ident_opt.fleet.causes import Block, cause_gains
from ident_opt.fleet.layout import LINK, FleetFile, linked, local_copy
from ident_opt.problem import load_problem
from ident_opt.warnings import ResultWarning

#: A robot-day is fitted when its samples × joints reach this many times the base parameters.
MIN_ROWS_PER_PARAMETER = 5
#: What one file's reading or reduction may raise beyond the loader's InputError (a NaN where a spline takes none,
#: a singular matrix, an overflow): the file's task turns it into its skip reason, as an InputError, so that one
#: odd file never ends the run.
UNREADABLE = (ValueError, ArithmeticError, np.linalg.LinAlgError, IndexError)
#: A skipped file's reason, in every report, is the first line of the loader's message, cut to this many
#: characters: a bad file's contents (a header, a cell) are shown only as far as they say what is wrong with it.
REASON_CHARS = 300


@dataclass(frozen=True)
class Job:
    """What every task of a run shares: the problem file (absolute path), the loader's switches and the fit asked
    for with `--estimator` (None: each robot's recommended fit, `choose`)."""

    problem: str
    allow_implausible: bool = False
    drop_invalid: bool = False
    estimator: str | None = None


@dataclass(frozen=True, eq=False)
class Setup:
    """A worker's view of the problem, built once per process: the robot, its model, the fit, the base parameters
    (the quantities tested for changes) and the causes as blocks of columns (`causes`: "wear:j", "drive:j",
    "payload"; "offset:j" where the model has a joint's torque offset; "full": every parameter)."""

    problem: object
    robot: Robot
    model: Arm
    base: BaseParameters
    causes: dict[str, list[Block]]

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
    P, n = model.n_params, model.n_joints
    every = np.ones(n, dtype=bool)
    causes: dict[str, list[Block]] = {}
    for j in range(1, n + 1):
        for cause, kind in (("wear", "friction"), ("offset", "other")):
            own = [i for i, p in enumerate(model.parameters) if p.kind == kind and p.joint == j]
            if own:
                causes[f"{cause}:{j}"] = [(np.eye(P)[:, own], every)]
        causes[f"drive:{j}"] = [("pi0", np.arange(n) == j - 1)]
    causes["payload"] = [(robot.tool_directions(model), every)]
    causes["full"] = [(np.eye(P), every)]
    return Setup(problem, robot, model, base_parameters(model), causes)


# ---------------------------------------------------------------------------------------------- files
def ready(problem_path: str) -> int:
    """Load the problem on this worker (`setup`) and return its number of parameters: a run's first task."""
    return setup(problem_path).model.n_params


@dataclass
class RobotChoice:
    """The fit a robot's days get (`fitting.recommend.Choice`: estimator, why, the cut-off factor its files'
    derivatives take; without its evidence, which stays on the worker), the warnings of that evidence
    (`fitting.trust`), the day it was judged on (None: `--estimator`, or no readable day: the arm's consistent fit)
    and the task's CPU time [s]."""

    robot: str
    choice: recommend.Choice
    warnings: list[ResultWarning] = field(default_factory=list)
    day: str | None = None
    cpu: float = 0.0


def _read(job: Job, s: Setup, file: FleetFile) -> Dataset:
    """One trial read, checked and differentiated by the loader every command uses; refused, an InputError whose
    message names the file as the layout does (not the path of a temporary copy), on one line of at most
    `REASON_CHARS`. A file that is a symbolic link now, or lies in a linked folder, is not opened (`layout.linked`:
    the fleet reads only what lies inside its root)."""
    if linked(file):
        raise InputError(LINK)
    with local_copy(file.url) as local:
        try:
            trial = load_dataset(
                local, s.problem.data, s.robot, allow_implausible=job.allow_implausible, drop_invalid=job.drop_invalid
            )
            fittable(trial)
        except InputError as exc:
            raise InputError(_reason(str(exc).replace(f"{local}: ", "", 1).replace(str(local), file.name))) from None
        except UNREADABLE as exc:  # data the loader did not foresee: this file is skipped, not the run
            raise InputError(_unreadable(exc, str(local), file.name)) from None
    return trial


def _finite(stats: Stats) -> bool:
    """Whether every number of `stats` is finite."""
    return all(np.isfinite(a).all() for a in (stats.G, stats.b, stats.s))


def _unreadable(exc: BaseException, local: str, name: str) -> str:
    """The skip reason of a file whose reading or reduction failed with `exc` (not a loader's InputError)."""
    text = str(exc).replace(local, name)
    return _reason(f"cannot be processed ({type(exc).__name__}: {text or 'no message'})")


def _reason(message: str) -> str:
    """A loader's message as a skip reason: its first line, cut to `REASON_CHARS` characters."""
    lines = message.strip().splitlines()
    first = lines[0] if lines else ""
    return first if len(first) <= REASON_CHARS else first[: REASON_CHARS - 1] + "…"


def choose(job: Job, robot: str, *days: list[FleetFile]) -> RobotChoice:
    """The fit of `robot`'s days: `job.estimator` if asked (checked as every command checks it), else the
    recommended fit (`fitting.recommend.choose`) from the first of `days` (each a day's files) with a readable
    trial, its trials read together; the arm's consistent fit, said so, when no day has one. One choice for all the
    robot's days, so that its series compare like with like."""
    start = time.thread_time()
    s = setup(job.problem)
    if job.estimator is not None:
        asked = recommend.choose(s.problem, [], model=s.model, estimator=job.estimator, command="fleet")
        return RobotChoice(robot, asked, cpu=time.thread_time() - start)
    for files in days:
        trials = []
        for file in files:
            with contextlib.suppress(InputError):  # the file's own task says why it is skipped
                trials.append(_read(job, s, file))
        if trials:
            try:
                found = recommend.choose(s.problem, trials, model=s.model, command="fleet")
            except UNREADABLE:  # trials nothing can be judged on: the next day's (each file's task says more)
                continue
            chosen = replace(found, evidence=None)  # the evidence (fits, trials) stays on the worker
            return RobotChoice(robot, chosen, found.warnings, files[0].day, time.thread_time() - start)
    consistent = s.robot.default_estimator
    why = f"no readable trial in its first days to judge the data by: the physically consistent fit ({consistent})"
    return RobotChoice(robot, recommend.Choice(consistent, why), cpu=time.thread_time() - start)


@dataclass
class FileStats:
    """One file's statistics (None when skipped, with the `reason`; `instruments` too when the robot's fit takes
    them), its number of samples, the task's CPU time [s] (`time.thread_time`: what it costs, whatever else the
    machine runs) and the loader's notes (kept in the fleet's store)."""

    file: FleetFile
    stats: Stats | None
    samples: int = 0
    reason: str = ""
    cpu: float = 0.0
    instruments: InstrumentStats | None = None
    notes: list[str] = field(default_factory=list)


def file_stats(job: Job, file: FleetFile, choice: RobotChoice) -> FileStats:
    """Read, check, differentiate (at the robot's `choice` of cut-off factor) and reduce one trial to the statistics
    its robot's fit takes, with the torque the fits use (`Dataset.tau_fit`, `estimators.statistics`); a file the
    loader refuses is returned as skipped, with the loader's reason (the file named as in the layout). A long, plain
    log is read in pieces (`fleet.streamed`: the same statistics, memory flat in its length)."""
    start = time.thread_time()
    s = setup(job.problem)
    streamed_stats = _streamed(job, s, file, choice.choice)
    if streamed_stats is not None:
        stats, n, notes = streamed_stats
        plain = stats.stats if isinstance(stats, InstrumentStats) else stats
        instruments = stats if isinstance(stats, InstrumentStats) else None
        return FileStats(file, plain, n, cpu=time.thread_time() - start, instruments=instruments, notes=notes)
    try:
        trial = _read(job, s, file)
        rec = choice.choice
        try:
            (trial,) = rec.at_cutoff([trial])
            stats = estimators.statistics(s.model, [trial], rec.estimator)
            if not _finite(stats.stats if isinstance(stats, InstrumentStats) else stats):
                raise ValueError("its statistics are not finite")  # it would poison its day's sum
        except UNREADABLE as exc:
            raise InputError(_unreadable(exc, file.url, file.name)) from None
    except InputError as exc:
        return FileStats(file, None, 0, str(exc), time.thread_time() - start)
    cpu, notes = time.thread_time() - start, list(trial.notes)
    if isinstance(stats, InstrumentStats):
        return FileStats(file, stats.stats, trial.n, cpu=cpu, instruments=stats, notes=notes)
    return FileStats(file, stats, trial.n, cpu=cpu, notes=notes)


def _streamed(job: Job, s: Setup, file: FleetFile, choice: recommend.Choice) -> tuple | None:
    """`streamed.statistics` of the file, or None when the loader must read it whole: not a long plain log, or
    anything odd in it (the loader then says what, as for every command)."""
    if linked(file):
        return None  # `_read` refuses it, saying why
    try:
        with local_copy(file.url) as local:
            return streamed.statistics(local, s, job, choice)
    except Exception:
        return None


# ---------------------------------------------------------------------------------------------- days
@dataclass
class DayStats:
    """A robot-day's statistics (the sum over its readable files; None if none was; `instruments` their instrument
    statistics when the robot's fit takes them), the files read and the ones skipped (`{"file", "reason"}`), the
    samples, and the CPU time [s] of its files' tasks and its own."""

    robot: str
    day: str
    stats: Stats | None
    files: list[str]
    skipped: list[dict]
    samples: int
    cpu: float = 0.0
    instruments: InstrumentStats | None = None


def day_stats(*files: FileStats, day: str | None = None) -> DayStats:
    """The sum of the files' statistics, labelled with the first file's robot and day (or `day`)."""
    start = time.thread_time()
    read = [f for f in files if f.stats is not None]
    total = instruments = None
    for f in read:
        total = f.stats.copy() if total is None else total + f.stats
        if f.instruments is not None:
            instruments = f.instruments if instruments is None else instruments + f.instruments
    first = files[0].file
    skipped = [{"file": f.file.name, "reason": f.reason} for f in files if f.stats is None]
    samples = sum(f.samples for f in read)
    cpu = sum(f.cpu for f in files) + time.thread_time() - start
    names = [f.file.name for f in read]
    return DayStats(first.robot, day or first.day, total, names, skipped, samples, cpu, instruments)


@dataclass
class DayFit:
    """A robot-day's fit by `estimator`: π and its standard errors (NaN where the data do not determine a
    parameter) by the model's names, the tested quantities (`Setup.tested`) with their OLS standard errors, notes,
    and the CPU time [s] of the day's tasks (files, sum, fit). `pi` is None when the day could not be fitted (`notes`
    say why)."""

    robot: str
    day: str
    files: list[str]
    skipped: list[dict]
    samples: int
    estimator: str = ""
    pi: np.ndarray | None = None
    se: np.ndarray | None = None
    tested: np.ndarray | None = None
    tested_se: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    cpu: float = 0.0


def fit_day(job: Job, day: DayStats, choice: RobotChoice) -> DayFit:
    """The robot-day's fit by its robot's `choice` (the recommended fit) with standard errors (OLS's where the fit
    gives none at all), and the tested parameters: the base parameters by least squares
    (`fitting.base.fit_base_ols`), what the data determine with no prior or bound in them, with their standard
    errors (a change test compares like with like: the same estimator, free of any prior, on every day)."""
    start = time.thread_time()
    out = _fit_day(job, day, choice.choice.estimator)
    out.cpu = day.cpu + time.thread_time() - start
    return out


def _fit_day(job: Job, day: DayStats, name: str) -> DayFit:
    """`fit_day` by estimator `name`, without its clock."""
    s = setup(job.problem)
    out = DayFit(day.robot, day.day, day.files, day.skipped, day.samples, name)
    stats = day.stats
    if stats is None:
        out.notes.append("no readable trial")
        return out
    if stats.n * s.model.n_joints < MIN_ROWS_PER_PARAMETER * s.base.rank:
        out.notes.append(f"{stats.n} samples: too few for the {s.base.rank} identifiable parameters")
        return out
    taken = day.instruments if name in estimators.INSTRUMENTED else stats
    try:
        fit = estimators.fit_for(s.robot, name, taken, s.model)
    except RuntimeError as exc:  # a solver failure: the day has no fit
        out.notes.append(f"the {name} fit failed ({exc})")
        return out
    se = fit.se
    if not np.isfinite(se).any():
        se = fit_least_squares(stats, s.model).se
    ols = fit_base_ols(stats, s.model)
    out.pi, out.se = fit.pi, se
    out.tested, out.tested_se = ols.fit.pi, ols.fit.se
    out.notes += fit.warnings
    return out


# ---------------------------------------------------------------------------------------------- changes
@dataclass
class Baseline:
    """A robot's baseline model: π0 (P,) fitted by OLS on its first days' statistics together; each joint's weight
    w_j = 1/v_j, v_j its out-of-sample residual variance [N² m²] (each baseline day predicted by the fit on the
    others: noise and day-to-day scatter); per sample, what each cause gains on a baseline day so predicted
    (`null`: the scatter's share of any gain); the days it used."""

    robot: str
    pi: np.ndarray
    weights: np.ndarray
    null: dict[str, float]
    days: list[str]


def _without(total: Stats, part: Stats) -> Stats:
    """The statistics of `total` without those of `part` (a subset of its samples)."""
    return Stats(total.G - part.G, total.b - part.b, total.s - part.s, total.n - part.n)


def baseline(job: Job, *days: DayStats, count: int | None = None) -> Baseline | None:
    """The baseline model of a robot from the first `count` (default: all) of `days` that have statistics, with its
    out-of-sample weights and null gains from leaving each day out in turn (one day alone: its in-sample residual,
    no null); None when no day has statistics."""
    s = setup(job.problem)
    read = [d.stats for d in days if d.stats is not None][:count]
    if not read:
        return None
    total = read[0].copy()
    for stats in read[1:]:
        total += stats
    fit = fit_least_squares(total, s.model)
    floor = 1e-12 * max(float(fit.sigma2.max()), 1e-300)
    if len(read) < 2:
        return Baseline(days[0].robot, fit.pi, 1.0 / np.maximum(fit.sigma2, floor), {}, [days[0].day])
    others = [fit_least_squares(_without(total, stats), s.model).pi for stats in read]
    n = sum(stats.n for stats in read)
    variance = sum(stats.rss(pi) for stats, pi in zip(read, others)) / n
    weights = 1.0 / np.maximum(variance, floor)
    null: dict[str, float] = {}
    for stats, pi in zip(read, others):
        for key, gain in cause_gains(s.causes, stats, pi, weights)[0].items():
            null[key] = null.get(key, 0.0) + gain / n
    used = [d.day for d in days if d.stats is not None][: len(read)]
    return Baseline(days[0].robot, fit.pi, weights, null, used)


@dataclass
class Scales:
    """A robot-day's torque scale per joint against the baseline, k_j (n,) with its standard error: the factor on
    joint j's torque that best fits the day with π0 (1 for an unchanged robot; a drive's gain moves it)."""

    robot: str
    day: str
    scale: np.ndarray
    se: np.ndarray


def scales(job: Job, day: DayStats, base: Baseline | None) -> Scales | None:
    """The day's `Scales` against the robot's baseline: per joint k = u/v with u = b_j·π0, v = π0ᵀG_jπ0, and its
    standard error √(RSS_j(k)/(n−1)/v); None without statistics or baseline."""
    if day.stats is None or base is None:
        return None
    S, pi0 = day.stats, base.pi
    u = S.b @ pi0
    v = np.maximum(np.einsum("p,jpr,r->j", pi0, S.G, pi0), 1e-300)
    rss = np.maximum(S.s - u**2 / v, 0.0)
    return Scales(day.robot, day.day, u / v, np.sqrt(rss / max(S.n - 1, 1) / v))


@dataclass
class Evidence:
    """Pooled days against the baseline: the weighted misfit RSS0 of π0, how much of it each cause explains
    (`gains`: the keys of `Setup.causes`) and how much it would on as many unchanged days (`null`: the baseline's
    rates × the samples), each drive's torque factor k_j (1 + its coefficient on Y_jπ0) and each joint's friction
    growth (δ·f_j / f_j·f_j, f_j its baseline friction terms)."""

    robot: str
    day: str
    rss0: float
    gains: dict[str, float]
    null: dict[str, float]
    scale: np.ndarray
    growth: dict[str, float]
    cpu: float = 0.0  # the pooled files' tasks and its own [s]


def evidence(job: Job, day: DayStats, base: Baseline | None) -> Evidence | None:
    """The pooled days' `Evidence` against the robot's baseline (module doc); None without statistics or baseline."""
    if day.stats is None or base is None:
        return None
    start = time.thread_time()
    s = setup(job.problem)
    S = day.stats
    gains, scale, growth = cause_gains(s.causes, S, base.pi, base.weights)
    null = {key: rate * S.n for key, rate in base.null.items()}
    cpu = day.cpu + time.thread_time() - start
    return Evidence(day.robot, day.day, float(base.weights @ S.rss(base.pi)), gains, null, scale, growth, cpu)
