"""`ident-opt codegen`: the identified model as C for the controller, compiled and checked against Python.

The model shipped is the arm's (with its extensions) with π the chosen fit on the training trials (by default the
recommended fit: the π `compare` reports, `fitting.recommend.Choice.fit`) or loaded from an earlier run's
parameters.json, plus its GMR residual (`ship.prepare`). The C is generated and compiled (`build`: `tau_hat`,
`tau_hat_gmr`, `ddq_hat`, and with training trials `observer_step`: the contact observer with thresholds calibrated
on them, `ident_opt.contact.casadi_step`), compared with the Python model (`ship.check`, `casadi_step.check`), and
where the arm serves online identification the online update `pi_update` is generated and checked too
(`pi_update.verify`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ident_opt import outputs
from ident_opt.arm.base import Arm
from ident_opt.contact import casadi_step
from ident_opt.data.dataset import Dataset, concat
from ident_opt.errors import InputError
from ident_opt.fitting.recommend import Choice, choose
from ident_opt.problem.spec import Problem
from ident_opt.shipping import codegen, pi_update, ship
from ident_opt.shipping.ship import MEASURE, TOLERANCE, Shipped

#: What the online update adds to the output folder (`adaptation.c_update`, the check).
UPDATE_FILES = (
    "pi_update.c",
    "pi_update.h",
    "pi_update_casadi.c",
    "pi_update_casadi.h",
    "pi_update_main.c",
    "libpi_update.so",
    "pi_update_example",
    "pi_update_samples.csv",
)


@dataclass
class Built:
    """The generated CasADi functions and the files written for them."""

    functions: list
    files: list[Path]  # sources, header, library, example, README
    library: Path

    @property
    def names(self) -> list[str]:
        return [f.name() for f in self.functions]


@dataclass
class Generated:
    """What `codegen` made: the model shipped, the files built, the choice of fit (None: loaded from a file),
    parameters.json's content (`payload`), the check against Python per function (largest difference) and the
    files of the output folder this run owns."""

    shipped: Shipped
    built: Built
    choice: Choice | None
    payload: dict
    errors: dict[str, float]
    written: list[str] = field(default_factory=list)

    @property
    def disagreeing(self) -> dict[str, float]:
        """The functions whose compiled code disagrees with Python beyond `ship.TOLERANCE`."""
        return {name: err for name, err in self.errors.items() if not err <= TOLERANCE[name]}


def shipped_model(robot, extensions: Sequence[str] | None, saved: dict | None) -> Arm:
    """The model to ship: the arm with `extensions`, else the saved parameters' (with their parameters checked:
    every one present and numeric, before anything is written), else the robot's own model (`Robot.model()`, the one
    `compare` fits)."""
    names = extensions if extensions is not None else (saved or {}).get("extensions")
    try:
        model = robot.model(tuple(dict.fromkeys(names)) if names is not None else None)
    except ValueError as exc:
        raise InputError(f"codegen: {exc}") from None
    if saved is not None:
        ship.saved_vector(saved, model)
    return model


def with_update(problem: Problem, trials: Sequence[Dataset], update: bool = True) -> bool:
    """Whether `pi_update` (the online update in C) is generated: asked for, a trial to check it on, and an arm the
    online identifier serves."""
    return update and bool(trials) and "online" in problem.robot.serves


def written_files(problem: Problem, trials: Sequence[Dataset], update: bool = True) -> list[str]:
    """The files a run writes to its output folder."""
    written = [f"{codegen.NAME}.c", f"{codegen.NAME}.h", codegen.library_name(), "main.c", "README.md"]
    written.append("parameters.json")
    if with_update(problem, trials, update):
        written += UPDATE_FILES
    return written


def build(
    shipped: Shipped, robot, out: Path, compiler: list[str], forward: bool = True, update: bool = False, extra=()
) -> Built:
    """Generate the C code of `shipped` into `out` and compile it (`forward`: also ddq_hat; `extra`: more CasADi
    Functions, e.g. observer_step), with the example and the README written for `robot` (its joints and angle
    convention; `update`: the online update's files too)."""
    functions = [*codegen.build_functions(shipped.model, shipped.pi, shipped.gmr, forward=forward), *extra]
    source, header = codegen.generate_sources(functions, out)
    library = codegen.compile_library(source, out, compiler)
    example = codegen.copy_example(out, shipped.model.n_joints, gmr=shipped.gmr is not None)
    readme = codegen.write_readme(out, functions, robot, update=update)
    return Built(functions, [source, header, library, example, readme], library)


def payload(shipped: Shipped, built: Built, errors: dict[str, float], problem: Problem, sources: list[str]) -> dict:
    """parameters.json (and the --json payload): the parameters baked in, the model, the GMR, the checks."""
    model, gmr, robot = shipped.model, shipped.gmr, problem.robot
    n = model.n_joints
    out = {
        "estimator": shipped.estimator,
        "estimator_status": shipped.status,
        "model": {"extensions": list(model.extensions), **model.settings()},
        "arm": robot.summary(),
        "joints": list(robot.joint_names),
        "parameters": model.as_dict(shipped.pi),
        "units": {p.name: p.unit for p in model.parameters},
        "gmr": {
            "inputs": list(codegen.gmr_inputs(n)),
            "outputs": [f"r{j + 1}" for j in range(n)],
            "n_components": len(gmr.weights_),
            "weights": gmr.weights_,
            "means": gmr.means_,
            "covariances": gmr.covariances_,
        },
        "problem": problem.name,
        "data": sources,
        "functions": built.names,
        "library": built.library.name,
        "check": {name: {MEASURE[name]: err, "limit": TOLERANCE[name]} for name, err in errors.items()},
    }
    if robot.statement:  # e.g. a two-joint URDF arm: the offsets and signs from its angles to the C code's
        out["robot"] = list(robot.statement)
    return out


def _check_observer(built: Built, observer: tuple, trial: Dataset, data: dict) -> float:
    """The compiled observer_step against the Python watch along `trial` (`casadi_step.check`): its entry of
    parameters.json (`data["observer"]`, with the check) and the error (inf when an alarm differs)."""
    _, watch, data["observer"] = observer
    step = codegen.load_external(built.library, "observer_step")
    found = casadi_step.check(step, watch, trial.q, trial.dq, trial.tau)
    data["observer"]["check"] = found
    error = found["max_relative_difference"] if not found["alarm_mismatches"] else float("inf")
    data["check"]["observer_step"] = {MEASURE["observer_step"]: error, "limit": TOLERANCE["observer_step"]}
    return error


def generate(
    problem: Problem,
    training: Sequence[Dataset],
    out: str | Path,
    *,
    estimator: str | None = None,
    extensions: Sequence[str] | None = None,
    saved: dict | None = None,
    components: int | None = None,
    forward: bool = True,
    update: bool = True,
    force: bool = False,
    say: Callable[[str], None] = lambda line: None,
) -> Generated:
    """`ident-opt codegen` into the folder `out`: π by `estimator` (default: the recommended fit) on the `training`
    trials, or from `saved` (`ship.read_parameters`: an earlier run's parameters.json); the GMR residual with
    `components` (default: the problem's `[residual]`); `forward`: also ddq_hat; `update`: also pi_update where the
    arm serves online identification; `force`: overwrite files an earlier run did not write. `say(line)` hears what
    is about to happen (the slow steps)."""
    problem.require("codegen")
    robot = problem.robot
    compiler = codegen.find_compiler()  # fail before any fitting when there is none
    model = shipped_model(robot, extensions, saved)
    trials = list(training)
    choice = None
    if saved is None:
        choice = choose(problem, trials, model=model, estimator=estimator, command="codegen")
        say(f"the {choice.estimator} fit ({choice.why})")
    if not (saved and saved.get("gmr")):
        if components is not None and components < 1:
            raise InputError(f"codegen: --components must be >= 1, got {components}")
        k = components if components is not None else problem.residual.components
        candidates = "K chosen among " + str(list(problem.residual.candidates))
        say(f"fitting the GMR residual ({k or candidates} components) on {concat(trials).n} samples")
    out = Path(out)
    written = written_files(problem, trials, update)
    outputs.guard_owned(out, written, force=force)
    shipped = ship.prepare(robot, model, trials, problem.residual, choice, components, saved)
    say(
        f"{robot.headline}; {len(model.names)} parameters ({shipped.estimator}), GMR with "
        f"{len(shipped.gmr.weights_)} components; generating C in {out}"
    )
    observer = casadi_step.for_codegen(shipped.model, shipped.pi, trials) if trials else None
    extra = [observer[0]] if observer else []
    built = build(shipped, robot, out, compiler, forward, with_update(problem, trials, update), extra)
    train = concat(trials) if trials else None
    errors = ship.check(built.library, shipped, train, built.names, np.random.default_rng(0))
    data = payload(shipped, built, errors, problem, [t.source for t in trials])
    if observer:
        say("checking observer_step (the contact observer) against Python")
        errors["observer_step"] = _check_observer(built, observer, trials[0], data)
    if with_update(problem, trials, update):
        say("generating pi_update (the online update) and checking it against Python")
        found = pi_update.verify(problem, trials[0], out, compiler)
        data["pi_update"] = found
        errors["pi_update"] = found["max_difference_vs_size_or_se"] if not found["failures"] else float("inf")
    return Generated(shipped, built, choice, data, errors, written)
