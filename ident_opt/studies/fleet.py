"""What `ident-opt fleet` computes: every robot of a fleet identified every day on Dask, and what changed, named.

1. The layout under `--logs` is found and checked (`fleet.layout`), before any work.
2. Phase 1, on the cluster (`fleet.engine`): per file its statistics, per robot-day their sum and the fit
   (`fleet.tasks`); the client gathers the fits only.
3. On the client (`fleet.changes`): the fleet's scatter of each tested parameter, each robot's test against its
   first `baseline_days` fitted days, and for a robot with a moved parameter the day its change began.
4. Phase 2, on the cluster, for the robots with a change only: the baseline days' and the change's files read again
   and pooled, and the evidence that names the cause (`tasks.evidence`, `changes.name_cause`).

A robot with fewer fitted days than the baseline plus `changes.RUN_DAYS` gets its series but no test (a warning).
"""

from __future__ import annotations

import datetime
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ident_opt.fleet import changes, layout, tasks
from ident_opt.fleet.engine import Engine
from ident_opt.problem import load_problem
from ident_opt.warnings import ResultWarning

#: The engine every run names in its JSON.
ENGINE = "dask.distributed"


@dataclass
class RobotResult:
    """One robot's series: its fitted days, their files and samples, the fit's π and standard errors (D, P), the
    tested parameters (`changes.Tested`) and their test (None with too few days)."""

    robot: str
    days: list[str]
    files: list[int]
    samples: list[int]
    pi: np.ndarray
    se: np.ndarray
    tested: changes.Tested
    test: changes.Test | None = None


@dataclass
class FleetResult:
    """A fleet run: the problem and logs, the arm in a line, the fit each robot-day got, the model's parameter names
    and the tested ones (with their definitions where they are base parameters), the robots' series, the changes,
    the skipped files, the run's numbers (`fleet`, the contract's keys and more) and the warnings."""

    problem: str
    logs: str
    arm: str
    estimator: str
    baseline_days: int
    names: tuple[str, ...]
    tested_names: tuple[str, ...]
    definitions: dict[str, str]
    robots: dict[str, RobotResult]
    changes: list[changes.Change]
    skipped: list[dict]
    fleet: dict
    warnings: list[ResultWarning] = field(default_factory=list)


def run_fleet(
    problem_path: str | Path,
    logs: str,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    baseline_days: int = 5,
    allow_implausible: bool = False,
    drop_invalid: bool = False,
    progress: bool = True,
    processes: bool = True,
) -> FleetResult:
    """Identify every robot-day under `logs` for the problem at `problem_path`, test each robot against its first
    `baseline_days` days and name what changed (module doc). `scheduler`: an existing Dask scheduler's address
    (None: a local cluster of `workers` processes, or threads with `processes` False)."""
    start = time.perf_counter()
    problem_path = str(Path(problem_path).resolve())
    problem = load_problem(problem_path)
    found = layout.discover(logs)
    job = tasks.Job(problem_path, allow_implausible, drop_invalid)
    setup = tasks.setup(problem_path)
    with Engine(scheduler, workers, processes) as engine:
        engine.check(tasks.ready, problem_path)
        phase1 = time.perf_counter()
        fits = engine.run(found.robots, _phase1(job, found), _count1(found), progress, "fleet: statistics and fits")
        engine_seconds = time.perf_counter() - phase1
        robots, skipped, warnings = _series(fits, setup, found)
        tests, onsets = _test(robots, baseline_days, warnings)
        units = [_change_files(found, robots[r], onsets[r][0], baseline_days) for r in onsets]
        total = sum(len(b) + len(c) + 4 for _, b, c in units)
        evidence = engine.run(units, _phase2(job), total, progress, "fleet: naming the changes")
        n_workers, address = engine.workers, engine.address
    found_changes = [
        _change(robots[e.robot], onsets[e.robot], e, setup, baseline_days)
        for e in sorted((e for e in evidence if e is not None), key=lambda e: e.robot)
    ]
    samples = sum(sum(r.samples) for r in robots.values())
    seconds = time.perf_counter() - start
    fleet = {
        "robots": len(robots),
        "robot_days": sum(len(r.days) for r in robots.values()),
        "files": len(found.files),
        "samples": samples,
        "seconds": seconds,
        "workers": n_workers,
        "engine": ENGINE,
        "scheduler": address,
        "engine_seconds": engine_seconds,
        "samples_per_second": samples / engine_seconds if engine_seconds > 0 else None,
        "files_read_again": sum(len(b) + len(c) for _, b, c in units),
        "baseline_days": baseline_days,
        "estimator": setup.estimator,
    }
    base = setup.base
    definitions = base.definitions() if base.rank < setup.model.n_params else {}
    return FleetResult(
        problem=str(problem.path),
        logs=str(logs),
        arm=problem.robot.headline,
        estimator=setup.estimator,
        baseline_days=baseline_days,
        names=setup.model.names,
        tested_names=setup.tested,
        definitions=definitions,
        robots=robots,
        changes=found_changes,
        skipped=found.skipped + skipped,
        fleet=fleet,
        warnings=found.warnings + warnings,
    )


# ---------------------------------------------------------------------------------------------- phase 1
def _count1(found: layout.Layout) -> int:
    """Phase 1's tasks: one per file, and a sum and a fit per robot-day."""
    return len(found.files) + 2 * sum(len(found.days(r)) for r in found.robots)


def _phase1(job: tasks.Job, found: layout.Layout):
    """A robot's phase-1 tasks: each file's statistics, each day's sum and fit (the fits are gathered)."""

    def submit(client, robot: str) -> tuple[list, list]:
        fits, others = [], []
        for day in found.days(robot):
            files = [client.submit(tasks.file_stats, job, f) for f in found.files_of(robot, day)]
            total = client.submit(tasks.day_stats, *files)
            fits.append(client.submit(tasks.fit_day, job, total))
            others += [*files, total]
        return fits, others

    return submit


def _day_number(day: str) -> int:
    return datetime.date.fromisoformat(day).toordinal()


def _series(
    fits: list[tasks.DayFit], setup: tasks.Setup, found: layout.Layout
) -> tuple[dict[str, RobotResult], list[dict], list[ResultWarning]]:
    """The fits gathered into each robot's series (fitted days only), the files skipped, and a warning per robot
    with days that have no fit."""
    by_robot: dict[str, list[tasks.DayFit]] = {}
    for fit in fits:
        by_robot.setdefault(fit.robot, []).append(fit)
    robots, skipped, warnings = {}, [], []
    P, Q = setup.model.n_params, len(setup.tested)
    for robot in found.robots:
        days = sorted(by_robot.get(robot, []), key=lambda f: f.day)
        for fit in days:
            skipped += fit.skipped
        good = [f for f in days if f.pi is not None]
        bad = [f for f in days if f.pi is None]
        if bad:
            listed = "; ".join(f"{f.day}: {', '.join(f.notes)}" for f in bad[:5]) + (" …" if len(bad) > 5 else "")
            warnings.append(ResultWarning("unfitted_days", f"robot {robot}: {len(bad)} day(s) without a fit ({listed})"))
        tested = changes.Tested(
            robot,
            [f.day for f in good],
            np.array([_day_number(f.day) for f in good], dtype=float),
            np.array([f.tested for f in good]).reshape(len(good), Q),
            np.array([f.tested_se for f in good]).reshape(len(good), Q),
        )
        robots[robot] = RobotResult(
            robot,
            tested.days,
            [len(f.files) for f in good],
            [f.samples for f in good],
            np.array([f.pi for f in good]).reshape(len(good), P),
            np.array([f.se for f in good]).reshape(len(good), P),
            tested,
        )
    return robots, skipped, warnings


# ---------------------------------------------------------------------------------------------- the test
def _test(
    robots: dict[str, RobotResult], baseline_days: int, warnings: list[ResultWarning]
) -> tuple[dict[str, changes.Test], dict[str, tuple[int, str]]]:
    """Each testable robot's test (stored on it), and the onset (day index, pattern) of those with a change."""
    K = baseline_days
    testable = [r for r in robots.values() if len(r.days) >= K + changes.RUN_DAYS]
    short = [r.robot for r in robots.values() if len(r.days) < K + changes.RUN_DAYS]
    if short:
        warnings.append(
            ResultWarning(
                "too_few_days",
                f"{len(short)} robot(s) with fewer than {K + changes.RUN_DAYS} fitted days ({K} baseline + "
                f"{changes.RUN_DAYS} to test) are reported but not tested: {', '.join(short[:10])}"
                + (" …" if len(short) > 10 else ""),
            )
        )
    tests, onsets = {}, {}
    if not testable:
        return tests, onsets
    fleet = changes.scatter([r.tested for r in testable], K)
    for r in testable:
        r.test = tests[r.robot] = changes.test(r.tested, fleet, K)
        if r.test.moved:
            onsets[r.robot] = changes.onset(r.test, r.tested.day_numbers, K, sorted(r.test.moved))
    return tests, onsets


# ---------------------------------------------------------------------------------------------- phase 2
def _change_files(found: layout.Layout, robot: RobotResult, tau: int, K: int) -> tuple[str, list, list]:
    """(robot, the files of its baseline days, the files of its days from the change on)."""
    files = [found.files_of(robot.robot, day) for day in robot.days]
    return robot.robot, [f for day in files[:K] for f in day], [f for day in files[tau:] for f in day]


def _phase2(job: tasks.Job):
    """A changed robot's phase-2 tasks: its baseline's and its change's files pooled, π0, the evidence (gathered)."""

    def submit(client, unit) -> tuple[list, list]:
        _, base_files, change_files = unit
        base_stats = [client.submit(tasks.file_stats, job, f) for f in base_files]
        change_stats = [client.submit(tasks.file_stats, job, f) for f in change_files]
        base = client.submit(tasks.day_stats, *base_stats, day="baseline")
        after = client.submit(tasks.day_stats, *change_stats, day="change")
        model = client.submit(tasks.baseline, job, base)
        found = client.submit(tasks.evidence, job, after, model)
        return [found], [*base_stats, *change_stats, base, after, model]

    return submit


def _roles(setup: tasks.Setup) -> tuple[dict[int, list[int]], list[int]]:
    """Which tested parameters each joint's friction is ({joint: indices}), and which a body on the last link moves."""
    tested = setup.tested
    friction: dict[int, list[int]] = {}
    for p in setup.model.parameters:
        if p.kind == "friction" and p.joint and p.name in tested:
            friction.setdefault(p.joint, []).append(tested.index(p.name))
    moved_by_tool = np.abs(setup.base.K @ setup.causes["payload"]).max(axis=1) > 0
    return friction, [int(i) for i in np.flatnonzero(moved_by_tool)]


def _change(
    robot: RobotResult, onset: tuple[int, str], found: tasks.Evidence, setup: tasks.Setup, K: int
) -> changes.Change:
    """The contract's change entry of a robot from its test, its onset and the pooled evidence."""
    test, tested = robot.test, robot.tested
    cause, joint, explained = changes.name_cause(found.reductions, found.growth)
    moved = sorted(test.moved)
    friction, tool = _roles(setup)
    own = {"wear": friction.get(joint, []), "payload": tool}.get(cause, moved)
    concerned = [q for q in moved if q in own] or moved
    last = len(robot.days) - 1
    lead = max(concerned, key=lambda q: abs(test.z[last, q]))
    names = setup.tested
    baseline = {names[q]: float(test.mean[q]) for q in concerned}
    latest = {names[q]: float(tested.values[last, q]) for q in concerned}
    scale = float(found.scale[joint - 1]) if cause == "drive" else None
    size = scale - 1.0 if scale is not None else latest[names[lead]] / baseline[names[lead]] - 1.0
    tau, pattern = onset
    return changes.Change(
        robot=robot.robot,
        cause=cause,
        joint=joint,
        parameters=[names[q] for q in concerned],
        first_day=robot.days[tau],
        pattern=pattern,
        baseline=baseline,
        latest=latest,
        z=float(test.z[last, lead]),
        detected=robot.days[min(test.moved[q][0] for q in moved)],
        explained=explained,
        scale=scale,
        size=float(size),
    )
