"""The Python API's own pieces: trials from a problem's files or from arrays, and the recommended fit
(`docs/api.md`). Every other stage function lives in the package of its feature and is re-exported by
`ident_opt` (`ident_opt.compare`, `ident_opt.diagnose`, …); the commands call the same functions.

    import ident_opt as iopt

    problem = iopt.load_problem("problems/kuka_lwr4.toml")
    training, testing = iopt.load_trials(problem)          # the problem's [data] (or paths)
    fit = iopt.fit(problem, training)                       # the recommended fit (or estimator="ols", …)
    tau = fit.predict(testing[0])                           # τ̂ (N, n) [N m]

Every stage function takes the parsed problem first, then trials (`ident_opt.data.Dataset`: t, q, dq, ddq, tau as
arrays (N, n) in SI units), and returns the data object the matching command reports: nothing here prints.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ident_opt import outputs
from ident_opt.data.dataset import Dataset, fittable
from ident_opt.data.loader import from_arrays, held_out_overlap, load_dataset
from ident_opt.errors import InputError
from ident_opt.fitting.base import base_parameters
from ident_opt.fitting.recommend import ArmFit, choose
from ident_opt.outputs import shown
from ident_opt.problem import Problem
from ident_opt.warnings import ResultWarning


def load_trials(
    problem: Problem,
    data: Sequence[str | Path] | None = None,
    test: Sequence[str | Path] | None = None,
    *,
    allow_implausible: bool = False,
    drop_invalid: bool = False,
    min_samples: int | None = None,
    fit: bool = True,
) -> tuple[list[Dataset], list[Dataset]]:
    """(training, held-out) trials: every file of `data` trains and every file of `test` is held out; without `data`
    the problem's `[data]` decides (`train`/`test`, or `trials`: the first trains, the second is held out), and a
    problem with only a `[simulate]` section gets its simulated trials (generated on first use, cached). `fit`: the
    trials will be fitted, so a joint whose torque never varies is an error. Bad input raises `InputError` naming the
    file, column and row."""
    train = [Path(p) for p in data or []]
    held = [Path(p) for p in test or []]
    if not train:
        train, held = list(problem.data.training), held or list(problem.data.testing)
    paths, n_train = train + held, len(train) or 1
    if not paths and problem.simulate is not None:
        from ident_opt.simulator import problem_trials  # deferred: the simulator's integrator side

        paths = problem_trials(problem)
    if not paths:
        raise InputError(f"{problem.path}: no data: give --data D or list trials under [data] in the problem file")
    options = {"allow_implausible": allow_implausible, "drop_invalid": drop_invalid}
    if min_samples is not None:
        options["min_samples"] = min_samples
    outputs.declare_inputs(paths)
    trials = [load_dataset(p, problem.data, problem.robot, **options) for p in paths]
    for trial in trials:
        fittable(trial, fit)
    return trials[:n_train], trials[n_train:]


def trial(
    problem: Problem,
    t: np.ndarray,
    q: np.ndarray,
    tau: np.ndarray | None = None,
    *,
    current: np.ndarray | None = None,
    dq: np.ndarray | None = None,
    ddq: np.ndarray | None = None,
    source: str = "arrays",
    allow_implausible: bool = False,
) -> Dataset:
    """A trial of the problem's arm from arrays: `t` (N,) [s], `q` (N, n) [rad], the torques `tau` (N, n) [N m] or
    the motor currents `current` (N, n) [A], optionally `dq` and `ddq`; missing derivatives are estimated by the
    same pipeline as a file's, at the problem's `derivative_cutoff_hz` (`ident_opt.data.loader.from_arrays`)."""
    return from_arrays(
        t,
        q,
        tau,
        problem.data,
        problem.robot,
        current=current,
        dq=dq,
        ddq=ddq,
        source=source,
        allow_implausible=allow_implausible,
    )


def fit(problem: Problem, trials: Sequence[Dataset], estimator: str | None = None, **options) -> ArmFit:
    """π of the problem's arm (`problem.robot.model()`) on all `trials` (their statistics add up), by `estimator`
    (default: the recommended fit, chosen from the trials' own evidence, `ident_opt.fitting.recommend.choose`), with
    standard errors: the fit `compare` reports as recommended, `export` and `codegen` write. `fit.predict(trial)` is
    τ̂; `options` go to the estimator (e.g. `weights="wls"`)."""
    choice = choose(problem, trials, estimator=estimator, command="fit")
    try:
        return choice.fit(problem.robot, problem.robot.model(), trials, **options)
    except RuntimeError as exc:  # the solver failed: nothing to stand behind
        raise InputError(f"the {choice.estimator} fit failed ({exc}); try another estimator") from None


@dataclass
class Checked:
    """What `check` found: the robot's summary (`Robot.summary` with its identifiable base parameters) and the lines
    that describe it, each trial's summary (samples, rate, derivatives, ranges), and the warnings."""

    problem: str
    robot: dict
    lines: list[str]
    trials: list[dict]
    warnings: list[ResultWarning] = field(default_factory=list)

    def as_json(self) -> dict:
        """The `check --json` payload."""
        return {
            "problem": self.problem,
            "robot": self.robot,
            "trials": self.trials,
            "warnings": [w.as_dict() for w in self.warnings],
        }


def check(problem: Problem, training: Sequence[Dataset], testing: Sequence[Dataset] = ()) -> Checked:
    """`ident-opt check`: the problem's robot and every trial summarised, nothing fitted; a held-out trial that is a
    training trial is a warning."""
    robot = problem.robot
    arm = robot.model()
    info = {**robot.summary(), "base_parameters": base_parameters(arm).rank}
    if "urdf" in info:  # as people read it: relative to the working folder when inside it
        info["urdf"] = shown(info["urdf"])
    lines = [f"problem {problem.name!r} ({problem.path}): {robot.headline}", *robot.describe()]
    lines.append(f"  identifiable: {info['base_parameters']} base parameters of the {arm.n_params} of its model")
    trials = [_summary(d) for d in [*training, *testing]]
    return Checked(problem.name, info, lines, trials, held_out_overlap(list(training), list(testing)))


def _summary(trial: Dataset) -> dict:
    """A JSON-able description of one loaded trial."""
    return {
        "source": shown(trial.source),
        "samples": trial.n,
        "duration_s": float(trial.t[-1] - trial.t[0]),
        "rate_hz": trial.rate_hz,
        "derivatives": trial.derivatives,
        "dropped_rows": trial.dropped_rows,
        "extra_columns": list(trial.extra.columns),
        "ranges": {
            name: [[float(arr[:, j].min()), float(arr[:, j].max())] for j in range(arr.shape[1])]
            for name, arr in (("q", trial.q), ("dq", trial.dq), ("ddq", trial.ddq), ("tau", trial.tau))
        },
    }
