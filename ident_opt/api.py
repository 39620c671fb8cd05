"""The Python API: what the commands do, as functions a notebook calls (`docs/api.md`).

    import ident_opt as io

    problem = io.load_problem("problems/kuka_lwr4.toml")
    training, testing = io.load_trials(problem)            # the problem's [data] (or paths)
    fit = io.fit(problem, training)                         # the recommended fit (or estimator="ols", …)
    tau = problem.robot.model().predict(fit.pi, q, dq, ddq)  # τ (N, n) [N m]
    comparison = io.compare(problem, training, testing)     # every fit side by side, held-out errors, warnings
    io.export(problem, fit, "arm.urdf")                     # or "arm.xml": MuJoCo MJCF

Each function takes the parsed problem (`load_problem`) and trials (`load_trials`, `ident_opt.data.Dataset`: t, q,
dq, ddq, tau as arrays (N, n) in SI units) and returns the data object the matching command reports: nothing here
prints or writes, except `export`, whose job is the file.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from ident_opt.data.dataset import Dataset, load_dataset
from ident_opt.errors import InputError
from ident_opt.evaluation.compare import Comparison, compare_estimators
from ident_opt.fitting import estimators
from ident_opt.fitting.fit import LinearFit
from ident_opt.fitting.recommend import recommended_fit
from ident_opt.problem import Problem
from ident_opt.shipping import identified, write_mjcf, write_urdf


def load_trials(
    problem: Problem,
    data: Sequence[str | Path] | None = None,
    test: Sequence[str | Path] | None = None,
    **options,
) -> tuple[list[Dataset], list[Dataset]]:
    """(training, held-out) trials: `data` and `test` when given, else the problem's `[data]` (`train`/`test`, or
    `trials`: the first trains, the second is held out). `options` go to `ident_opt.data.dataset.load_dataset`
    (`allow_implausible`, `drop_invalid`); bad input raises `InputError` naming the file, column and row."""
    train_paths = list(data) if data else list(problem.data.training)
    test_paths = list(test) if test is not None else ([] if data else list(problem.data.testing))
    if not train_paths:
        raise InputError(f"{problem.path}: no data: give data=[...] or list trials under [data] in the problem file")

    def read(paths):
        return [load_dataset(path, problem.data, problem.robot, **options) for path in paths]

    return read(train_paths), read(test_paths)


def fit(problem: Problem, trials: Sequence[Dataset], estimator: str | None = None, **options) -> LinearFit:
    """π of the problem's arm (`problem.robot.model()`) fitted by `estimator` (default: the recommended fit, chosen
    from the trials' own evidence, `ident_opt.fitting.recommend`) on all `trials` (their statistics add up), with
    standard errors; `options` go to the estimator (e.g. `weights="wls"`, `margin=1e-6`)."""
    robot = problem.robot
    model = robot.model()
    if estimator is None and not options:
        return recommended_fit(robot, model, list(trials), problem)[0]
    name = estimator or recommended_fit(robot, model, list(trials), problem)[1].recommendation.estimator
    if name not in robot.estimators:
        raise InputError(f"estimator {name!r} is not a fit of this arm; its fits: {', '.join(robot.estimators)}")
    stats = estimators.statistics(model, list(trials), name, probes=True)
    return estimators.fit_for(robot, name, stats, model, **options)


def compare(problem: Problem, training: Sequence[Dataset], testing: Sequence[Dataset] = (), **options) -> Comparison:
    """Every fit of the arm beside its nominal model, scored on held-out data (`ident-opt compare`'s study,
    `ident_opt.evaluation.compare.compare_estimators`); `options` as there (`margin`, `weights`, `progress`)."""
    options.setdefault("progress", False)
    return compare_estimators(
        list(training),
        problem.robot,
        problem.split,
        list(testing) or None,
        reference=problem.reference,
        conversions=problem.data.conversions,
        cutoff_setting=problem.data.derivative_cutoff_hz,
        **options,
    )


def export(problem: Problem, fitted: LinearFit, path: str | Path) -> list[Path]:
    """Write the arm with the parameters of `fitted` (a fit of `problem.robot.model()`) as a robot description:
    a URDF with its JSON sidecar (path ending in .urdf) or a MuJoCo MJCF (.xml, .mjcf); returns the files written.
    A π no physical robot has (e.g. an OLS fit's) raises `InputError` naming the link."""
    model = problem.robot.model()
    undetermined = fitted.details.get("not_determined", [])
    description = problem.robot.bodies(model, fitted.pi, undetermined=undetermined)
    path = Path(path)
    if path.suffix.lower() == ".urdf":
        record = {**identified(model.names, fitted.pi, fitted.se, fitted.method), "not_determined": undetermined}
        return list(write_urdf(description, path, record))
    if path.suffix.lower() in (".xml", ".mjcf"):
        return [write_mjcf(description, path)]
    raise InputError(f"{path}: name it *.urdf (URDF) or *.xml / *.mjcf (MuJoCo MJCF)")
