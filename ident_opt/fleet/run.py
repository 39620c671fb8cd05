"""What `ident-opt fleet` computes: every robot of a fleet identified every day on Dask, and what changed, named.

1. The layout under `--logs` is found and checked (`fleet.layout`), before any work.
2. Phase 1 (`fleet.incremental`), on the cluster (`fleet.engine`) for what the store (`fleet.store`) does not
   hold: per robot the fit its days get (`tasks.choose`: the recommended fit, judged on its first readable day as
   `identify` judges its training trials; or `--estimator`), per file its statistics, per robot-day their sum and
   that fit; on the client, from every file's statistics, per robot a baseline model from its first days and
   against it each day's torque scale per joint (`fleet.tasks`). The client holds statistics only.
3. On the client (`fleet.changes`): the fleet's scatter of each tested parameter, each robot's test against its
   first `baseline_days` fitted days, and for a robot with a moved parameter the day its change began.
4. Phase 2, on the client, for the robots with a change only: the statistics of the change's files pooled, and the
   evidence against the robot's baseline model that names the cause (`tasks.evidence`, `changes.name_cause`).
5. What phase 1 computed is written to the store, in one transaction.

A robot with fewer fitted days than the baseline plus `changes.RUN_DAYS` gets its series but no test (a warning).
"""

from __future__ import annotations

import datetime
import time
from pathlib import Path

import numpy as np

from ident_opt.arguments import range_of
from ident_opt.errors import InputError, excerpt
from ident_opt.fitting.recommend import choose
from ident_opt.fleet import changes, incremental, layout, tasks
from ident_opt.fleet import store as fleet_store
from ident_opt.fleet.engine import CONNECT_TIMEOUT_S, Engine
from ident_opt.fleet.result import FleetResult, RobotResult
from ident_opt.problem.spec import Problem
from ident_opt.warnings import ResultWarning

#: The engine every run names in its JSON.
ENGINE = "dask.distributed"
#: The arguments of `run_fleet` that are counts (the others are numbers).
INTEGERS = ("baseline_days", "workers")


def run_fleet(
    problem: Problem | str | Path,
    logs: str,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    baseline_days: int = 5,
    allow_implausible: bool = False,
    drop_invalid: bool = False,
    progress: bool = True,
    processes: bool = True,
    connect_timeout: float = CONNECT_TIMEOUT_S,
    estimator: str | None = None,
    store: str | Path | fleet_store.StoreLocation | None = None,
) -> FleetResult:
    """`ident-opt fleet`: identify every robot-day under `logs` for `problem` (a parsed problem, or its file: the
    workers read it again from its file), test each robot against its first `baseline_days` days and name what
    changed (module doc). `scheduler`: an existing Dask scheduler's address
    (None: a local cluster of `workers` processes, or threads with `processes` False), which must answer within
    `connect_timeout` [s]. `estimator`: the fit every robot-day gets (None: each robot's recommended fit).
    `store`: what earlier runs gave per file (`fleet.store`: a path, `sqlite:///path`, or None: none kept); only
    files it does not hold are read."""
    start = time.perf_counter()
    _check_numbers(baseline_days=baseline_days, workers=workers, connect_timeout=connect_timeout)
    problem_path, setup = _load(problem, estimator)
    found = layout.discover(logs)
    job = tasks.Job(problem_path, allow_implausible, drop_invalid, estimator)
    where = fleet_store.location(store)
    key = fleet_store.model_key(setup, job)
    stored = fleet_store.read(where, key)  # a store of another model is refused here, before any work

    def open_engine(small: bool) -> Engine:  # a small run's local workers are threads (`incremental.SMALL_RUN`)
        return Engine(scheduler, workers, processes and not small, connect_timeout)

    phase = incremental.phase1(open_engine, job, found, stored, baseline_days, progress)
    robots, skipped, warnings, units, evidence, found_changes = _analyse(job, setup, found, phase, baseline_days)
    fleet_store.write(where, key, phase.update)  # one transaction, once everything is computed
    seconds = time.perf_counter() - start
    choices = {name: r.choice for name, r in robots.items() if r.choice is not None}
    fit_name, why = _one_choice(choices)
    fleet = _numbers(robots, found, units, phase.gathered + evidence, seconds, phase, fit_name)
    fleet["baseline_days"], fleet["estimator"] = baseline_days, fleet.pop("estimator")  # the contract's order
    return FleetResult(
        problem=str(setup.problem.path),
        logs=str(logs),
        arm=setup.problem.robot.headline,
        estimator=fit_name,
        why=why,
        baseline_days=baseline_days,
        names=setup.model.names,
        tested_names=tested_names(setup),
        definitions=setup.base.definitions() if setup.base.rank < setup.model.n_params else {},
        robots=robots,
        changes=found_changes,
        skipped=found.skipped + skipped,
        fleet=fleet,
        warnings=found.warnings + phase.warnings + warnings,
    )


def _analyse(job: tasks.Job, setup: tasks.Setup, found: layout.Layout, phase: incremental.Phase1, K: int) -> tuple:
    """From phase 1's results: the robots' series (each with its fit's choice), the files skipped, the warnings, the
    test with each change's onset, phase 2's units and evidence, and the changes named."""
    gathered = phase.gathered
    baselines = {b.robot: b for b in gathered if isinstance(b, tasks.Baseline)}
    choices = {c.robot: c for c in gathered if isinstance(c, tasks.RobotChoice)}
    robots, skipped, warnings = _series(gathered, setup, found)
    choices = {name: c for name, c in choices.items() if name in robots}  # a robot left out has no fit to name
    warnings += _choice_warnings(choices)
    onsets = _test(robots, K, warnings)
    units = _change_units(found, robots, onsets, baselines, choices)
    evidence = _phase2(job, units, phase.files)
    found_changes = _named_changes(robots, onsets, evidence, setup, K)
    for name, r in robots.items():
        r.choice = choices.get(name)
    return robots, skipped, warnings, units, evidence, found_changes


def _check_numbers(**values: float | None) -> None:
    """At the door: each number in the range its command-line flag accepts (`arguments.RANGES`: the API takes no
    value the command would refuse), an integer where the flag's is; None passes (the default). An InputError
    naming the argument otherwise."""
    for name, value in values.items():
        if value is None and name == "workers":
            continue
        low, high = range_of("fleet", name)
        integer = name in INTEGERS
        kinds = (int, np.integer) if integer else (int, float, np.integer, np.floating)
        if (
            isinstance(value, bool)
            or not isinstance(value, kinds)
            or not (integer or np.isfinite(value))
            or not low <= value <= high
        ):
            what = "an integer" if integer else "a number"
            raise InputError(f"run_fleet: {name} must be {what} in [{low:g}, {high:g}], got {excerpt(value)}")


def _load(problem: Problem | str | Path, estimator: str | None) -> tuple[str, tasks.Setup]:
    """The problem file's absolute path (the workers load it again) and its setup, checked before any work."""
    problem_path = str(Path(problem.path if isinstance(problem, Problem) else problem).resolve())
    setup = tasks.setup(problem_path)
    setup.problem.require("fleet")
    if estimator is not None:  # an unknown fit is refused here, before any work
        choose(setup.problem, [], model=setup.model, estimator=estimator, command="fleet")
    return problem_path, setup


def _numbers(
    robots: dict[str, RobotResult],
    found: layout.Layout,
    units: list,
    results: list,
    seconds: float,
    phase: incremental.Phase1,
    estimator: str,
) -> dict:
    """The run's numbers (`FleetResult.fleet`): its size, its time and the cluster's throughput on the files it
    read, what the store gave (`files_new`, `files_cached`, `files_changed`, `files_gone`), and the fit."""
    samples = sum(sum(r.samples) for r in robots.values())
    cpu = sum(item.cpu for item in results if isinstance(item, tasks.DayFit | tasks.Evidence | tasks.RobotChoice))
    engine_seconds = phase.engine_seconds
    return {
        "robots": len(robots),
        "robot_days": sum(len(r.days) for r in robots.values()),
        "files": len(found.files),
        "samples": samples,
        "seconds": seconds,
        "workers": phase.cluster[0],
        "engine": ENGINE,
        "scheduler": phase.cluster[1],
        "engine_seconds": engine_seconds,
        "samples_per_second": phase.samples_read / engine_seconds if engine_seconds > 0 else None,
        "files_read_again": 0,  # the changes' evidence pools phase 1's statistics: no file is read twice
        "files_pooled": sum(len(unit[1]) for unit in units),
        **phase.counts,
        "cpu_seconds": cpu,
        "cpu_seconds_per_file": cpu / max(len(found.files), 1),
        "estimator": estimator,
    }


# ---------------------------------------------------------------------------------------------- series
def _day_number(day: str) -> int:
    return datetime.date.fromisoformat(day).toordinal()


def _series(
    gathered: list, setup: tasks.Setup, found: layout.Layout
) -> tuple[dict[str, RobotResult], list[dict], list[ResultWarning]]:
    """Phase 1's results gathered into each robot's series (fitted days only): the fit, and the tested parameters
    (the base parameters, then each joint's torque scale); the files skipped; a warning per robot with days that
    have no fit, and per robot left out because none of its days has one (every file unreadable)."""
    fits: dict[str, list[tasks.DayFit]] = {}
    scales: dict[tuple[str, str], tasks.Scales] = {}
    for item in gathered:
        if isinstance(item, tasks.DayFit):
            fits.setdefault(item.robot, []).append(item)
        elif isinstance(item, tasks.Scales):
            scales[item.robot, item.day] = item
    robots, skipped, warnings = {}, [], []
    P, n = setup.model.n_params, setup.model.n_joints
    missing = (np.full(n, np.nan), np.full(n, np.nan))
    for robot in found.robots:
        days = sorted(fits.get(robot, []), key=lambda f: f.day)
        for fit in days:
            skipped += fit.skipped
        good = [f for f in days if f.pi is not None]
        bad = [f for f in days if f.pi is None]
        listed = "; ".join(f"{f.day}: {', '.join(f.notes)}" for f in bad[:5]) + (" …" if len(bad) > 5 else "")
        if not good:  # not one readable, fittable day: the robot is left out, the others answered as without it
            sentence = f"robot {robot}: no day with a fit ({listed or 'no day'}); the robot is left out"
            warnings.append(ResultWarning("robot_skipped", sentence))
            continue
        if bad:
            sentence = f"robot {robot}: {len(bad)} day(s) without a fit ({listed})"
            warnings.append(ResultWarning("unfitted_days", sentence))
        k = [(s.scale, s.se) if (s := scales.get((robot, f.day))) else missing for f in good]
        tested = changes.Tested(
            robot,
            [f.day for f in good],
            np.array([_day_number(f.day) for f in good], dtype=float),
            np.hstack([np.array([f.tested for f in good]), np.array([a for a, _ in k])]).reshape(len(good), -1),
            np.hstack([np.array([f.tested_se for f in good]), np.array([b for _, b in k])]).reshape(len(good), -1),
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


def _choice_warnings(choices: dict[str, tasks.RobotChoice]) -> list[ResultWarning]:
    """The warnings of the evidence behind the robots' fits (`fitting.trust`), one per code with the robots it
    concerns (the first robot's message as the example)."""
    by_code: dict[str, list[tuple[str, ResultWarning]]] = {}
    for name in sorted(choices):
        for w in choices[name].warnings:
            by_code.setdefault(w.code, []).append((name, w))
    out = []
    for code, found in by_code.items():
        names = ", ".join(n for n, _ in found[:10]) + (" …" if len(found) > 10 else "")
        first_robot, first = found[0]
        day = choices[first_robot].day
        out.append(
            ResultWarning(
                code,
                f"{len(found)} robot(s) ({names}), judged on their first readable day; "
                f"{first_robot} on {day}: {first.message}",
            )
        )
    return out


def _one_choice(choices: dict[str, tasks.RobotChoice]) -> tuple[str, str]:
    """(estimator, why) of the robots' fits: the name when every robot got the same fit ("per robot" otherwise), the
    reason when they share one, else how many robots got each fit (each robot's reason is in its entry)."""
    recs = [c.choice for c in choices.values()]
    if not recs:
        return "none", "no robot to fit"
    names = sorted({r.estimator for r in recs})
    whys = {r.why for r in recs}
    name = names[0] if len(names) == 1 else "per robot"
    if len(whys) == 1:
        return name, whys.pop()
    counts = ", ".join(f"{n} on {sum(r.estimator == n for r in recs)} robot(s)" for n in names)
    return (
        name,
        f"each robot's recommended fit, judged on its own first readable day ({counts}; each robot's reason in its "
        "entry)",
    )


def tested_names(setup: tasks.Setup) -> tuple[str, ...]:
    """The tested parameters' names: the base parameters, then `scale_<joint>` per joint (its torque's factor
    against the baseline model)."""
    return (*setup.tested, *(f"scale_{name}" for name in setup.robot.joint_names))


# ---------------------------------------------------------------------------------------------- the test
def _test(
    robots: dict[str, RobotResult], baseline_days: int, warnings: list[ResultWarning]
) -> dict[str, dict[str, tuple[int, float]]]:
    """Test each robot with enough days (stored on it); for those with a change, the onset of each pattern
    (`changes.onsets`)."""
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
    onsets = {}
    if not testable:
        return onsets
    fleet = changes.scatter([r.tested for r in testable], K)
    for r in testable:
        r.test = changes.test(r.tested, fleet, K)
        if r.test.moved:
            onsets[r.robot] = changes.onsets(r.test, r.tested.day_numbers, K, sorted(r.test.moved))
    return onsets


# ---------------------------------------------------------------------------------------------- phase 2
def _change_files(found: layout.Layout, robot: RobotResult, tau: int) -> list:
    """The files of a robot's fitted days from its change (day index `tau`) on."""
    return [f for day in robot.days[tau:] for f in found.files_of(robot.robot, day)]


def _change_units(
    found: layout.Layout,
    robots: dict[str, RobotResult],
    onsets: dict[str, dict[str, tuple[int, float]]],
    baselines: dict[str, tasks.Baseline],
    choices: dict[str, tasks.RobotChoice],
) -> list[tuple]:
    """Phase 2's units, per changed robot with a baseline: (robot, files from its latest onset, baseline, choice)."""
    return [
        (r, _change_files(found, robots[r], max(t for t, _ in onsets[r].values())), baselines[r], choices[r])
        for r in onsets
        if r in baselines
    ]


def _phase2(job: tasks.Job, units: list[tuple], files: incremental.Files) -> list:
    """Phase 2 on the client: each unit's files' statistics (phase 1's, no file read again) pooled in the files'
    order, and the evidence against the robot's baseline model."""
    out = []
    for _, unit_files, base, _ in units:
        pooled = files.day(unit_files, day="change")
        out.append(tasks.evidence(job, pooled, base))
    return out


def _named_changes(
    robots: dict[str, RobotResult],
    onsets: dict[str, dict[str, tuple[int, float]]],
    evidence: list,
    setup: tasks.Setup,
    K: int,
) -> list[changes.Change]:
    """Each changed robot's change (`_change`), its cause named by its phase-2 evidence (none: neutral, "other")."""
    named = {e.robot: e for e in evidence if e is not None}
    unnamed = tasks.Evidence("", "change", 0.0, {}, {}, np.ones(setup.model.n_joints), {})  # no evidence: other
    return [_change(robots[r], onsets[r], named.get(r, unnamed), setup, K) for r in sorted(onsets)]


def _roles(setup: tasks.Setup) -> tuple[dict[int, list[int]], list[int], dict[int, int]]:
    """Which tested parameters are each joint's friction ({joint: indices}), which a body on the last link moves,
    and each joint's torque scale ({joint: index})."""
    names = tested_names(setup)
    friction: dict[int, list[int]] = {}
    for p in setup.model.parameters:
        if p.kind == "friction" and p.joint and p.name in setup.tested:
            friction.setdefault(p.joint, []).append(names.index(p.name))
    moved_by_tool = np.abs(setup.base.K @ setup.robot.tool_directions(setup.model)).max(axis=1) > 0
    B = len(setup.tested)
    return friction, [int(i) for i in np.flatnonzero(moved_by_tool)], {j + 1: B + j for j in range(len(names) - B)}


def _change(
    robot: RobotResult, onsets: dict[str, tuple[int, float]], found: tasks.Evidence, setup: tasks.Setup, K: int
) -> changes.Change:
    """The contract's change entry of a robot from its test, its onset and the pooled evidence: the parameters it
    concerns are the moved ones of its cause (a joint's friction for wear, what a body on the last link moves for a
    payload, the joint's torque scale and the rest for a drive, every moved one for other)."""
    test, tested = robot.test, robot.tested
    cause, joint, explained = changes.name_cause(found.gains, found.null, found.growth)
    moved = sorted(test.moved)
    friction, tool, scale_of = _roles(setup)
    own = {"wear": friction.get(joint, []), "payload": tool, "drive": moved}.get(cause, moved)
    concerned = [q for q in moved if q in own] or moved
    if cause == "drive":
        concerned = [scale_of[joint]] + [q for q in concerned if q != scale_of[joint]]
    last = len(robot.days) - 1
    lead = scale_of[joint] if cause == "drive" else max(concerned, key=lambda q: abs(test.z[last, q]))
    names = tested_names(setup)
    baseline = {names[q]: float(test.mean[q]) for q in concerned}
    latest = {names[q]: float(tested.values[last, q]) for q in concerned}
    scale = float(found.scale[joint - 1]) if cause == "drive" else None
    size = scale - 1.0 if scale is not None else latest[names[lead]] / baseline[names[lead]] - 1.0
    pattern = changes.pattern_of(cause, onsets)
    tau = onsets[pattern][0]
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
        lead=names[lead],
    )
