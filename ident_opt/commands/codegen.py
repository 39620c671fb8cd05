"""`ident-opt codegen`: identify (or load) the model, write its C code, compile it, check it against Python.

DIR receives the CasADi-generated `ident_opt_model.c`/`.h`, the shared library `libident_opt_model.so`,
`parameters.json` (the parameters baked in, by name, the estimator, the GMR residual model), a README for
embedding and the example `main.c`. Exported functions: `tau_hat(q, dq, ddq) -> tau`, `tau_hat_gmr` (the same
plus the GMR residual's conditional mean) and `ddq_hat(q, dq, tau) -> ddq` (forward dynamics), each with the
standard CasADi entry points. The compiled library is loaded back and compared with the Python model on the
training states and on random states; a mismatch is an error.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from ident_opt import outputs
from ident_opt.commands.common import add_components, add_problem_arguments, add_switches, load, output_dir, require
from ident_opt.data.dataset import concat
from ident_opt.errors import InputError
from ident_opt.fitting.estimators import ESTIMATORS
from ident_opt.fitting.recommend import chosen
from ident_opt.problem import load_problem
from ident_opt.report import codegen as report
from ident_opt.shipping import codegen, ship
from ident_opt.shipping import pi_update as online_codegen


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The standard problem flags, --out (required) and the model/estimator/GMR choices."""
    add_problem_arguments(parser)
    parser.add_argument("--out", metavar="DIR", required=True, help="output folder for the C code and library")
    parser.add_argument(
        "--extension",
        metavar="NAME",
        action="append",
        default=None,
        help="model extension to include (repeatable): armature, asymmetric_coulomb, stribeck, offset",
    )
    parser.add_argument(
        "--estimator",
        choices=tuple(ESTIMATORS),
        default=None,
        help="how π is identified, among the arm's fits (default: its physically consistent one: constrained for "
        "the planar arm, consistent for an n-joint arm)",
    )
    parser.add_argument(
        "--parameters",
        metavar="FILE",
        help="use the parameters (and GMR, if present) of a parameters.json from an earlier run "
        "instead of identifying them",
    )
    add_components(parser)
    add_switches(
        parser,
        {
            "--no-forward": "do not generate ddq_hat (forward dynamics)",
            "--no-update": "do not generate pi_update (the online statistics update and bounded least-squares "
            "re-solve in C)",
            "--force": "overwrite files in --out that an earlier codegen run did not write",
        },
    )


def run(args: argparse.Namespace) -> int:
    """Identify (or load), generate, compile, check; 0 when the library agrees with Python, 1 when not."""
    problem = load_problem(args.problem)
    require("codegen", problem)
    robot = problem.robot
    if args.estimator is not None:
        chosen("codegen", robot, robot.model(), [], problem, args.estimator)  # an unknown one fails before any work
    compiler = codegen.find_compiler()  # fail before any fitting when there is none
    saved = ship.read_parameters(args.parameters) if args.parameters else None
    model = _model(robot, args.extension, saved)
    trials = load(args, "codegen", problem=problem).training if saved is None or saved.get("gmr") is None else []
    train = concat(trials) if trials else None
    if saved is None:
        choice = chosen("codegen", robot, model, trials, problem, args.estimator)
        args.estimator = choice.estimator
        print(f"ident-opt codegen: the {choice.estimator} fit ({choice.why})", file=sys.stderr)
    if not (saved and saved.get("gmr")):
        _announce_gmr(problem.residual, args.components, train)
    out = output_dir(args, problem, indexed=False)  # only once every input is read and checked
    written = _written(args, robot, trials)
    outputs.guard_owned(out, written, force=args.force)
    shipped = ship.prepare(robot, model, train, problem.residual, args.estimator, args.components, saved)
    print(
        f"ident-opt codegen: {robot.headline}; {len(model.names)} parameters ({shipped.estimator}), GMR with "
        f"{len(shipped.gmr.weights_)} components; generating C in {out}",
        flush=True,
    )
    built = report.build(shipped, robot, out, compiler, forward=not args.no_forward)
    errors = ship.check(built.library, shipped, train, built.names, np.random.default_rng(0))
    data = report.payload(shipped, built, errors, problem, [t.source for t in trials])
    update = _pi_update(args, problem, trials, out, compiler)
    if update is not None:
        data["pi_update"] = update
        errors["pi_update"] = update["max_difference_vs_size_or_se"] if not update["failures"] else float("inf")
    print(report.write(data, built, out, getattr(args, "json", None)))
    if update is not None:
        print(_update_line(update, ship.TOLERANCE["pi_update"]))
    outputs.remember_owned(out, written)
    bad = {name: err for name, err in errors.items() if not err <= ship.TOLERANCE[name]}
    if bad:
        print(f"ident-opt codegen: the compiled code disagrees with the Python model: {bad}", file=sys.stderr)
        return 1
    return 0


def _model(robot, extension: list[str] | None, saved: dict | None):
    """The model to ship: the arm with the --extension ones, else the saved parameters' (with their parameters
    checked: every one present and numeric, before --out is touched)."""
    extensions = extension if extension is not None else (saved or {}).get("extensions", [])
    try:
        model = robot.model(tuple(dict.fromkeys(extensions)))
    except ValueError as exc:
        raise InputError(f"codegen: {exc}") from None
    if saved is not None:
        ship.saved_vector(saved, model)
    return model


def _written(args: argparse.Namespace, robot, trials: list) -> list[str]:
    """The files this run writes to DIR (the online update's only with a trial to check it on, for an arm the
    online identifier serves)."""
    written = [f"{codegen.NAME}.c", f"{codegen.NAME}.h", codegen.library_name(), "main.c", "README.md"]
    written.append("parameters.json")
    if _with_update(args, robot, trials):
        written += UPDATE_FILES
    return written


def _with_update(args: argparse.Namespace, robot, trials: list) -> bool:
    """Whether pi_update (the online update in C) is generated: not --no-update, a trial to check it on, and an arm
    the online identifier serves."""
    return not args.no_update and bool(trials) and "online" in robot.serves


#: What the online update adds to DIR (`ident_opt.shipping.codegen.generate_pi_update`, `compile_pi_update`, the check).
UPDATE_FILES = [
    "pi_update.c",
    "pi_update.h",
    "pi_update_casadi.c",
    "pi_update_casadi.h",
    "pi_update_main.c",
    "libpi_update.so",
    "pi_update_example",
    "pi_update_samples.csv",
]


def _pi_update(args: argparse.Namespace, problem, trials: list, out, compiler) -> dict | None:
    """pi_update generated, compiled and checked on the first trial's online part (`_with_update`)."""
    if not _with_update(args, problem.robot, trials):
        return None
    print("ident-opt codegen: generating pi_update (the online update) and checking it against Python", flush=True)
    return online_codegen.verify(problem, trials[0], out, compiler)


def _update_line(update: dict, limit: float) -> str:
    """The terminal line on the pi_update check (`limit`: its tolerance)."""
    return (
        f"  pi_update: generated C vs the Python online path over {update['samples']} samples, largest difference "
        f"{update['max_difference_vs_size_or_se']:.2e} of a parameter's size (or of its standard error, nearer 0; "
        f"limit {limit:.0e}; relative to the size alone {update['max_relative_difference']:.1e}), of the torques "
        f"{update['max_torque_relative_difference']:.1e}; {update['c_ns_per_update']:.0f} ns per update from a C loop"
    )


def _announce_gmr(spec, components: int | None, train) -> None:
    """Check --components and say what is about to be fitted (the GMR is the slow part)."""
    if components is not None and components < 1:
        raise InputError(f"codegen: --components must be >= 1, got {components}")
    k = components if components is not None else spec.components
    print(
        f"ident-opt codegen: fitting the GMR residual ({k or 'K chosen among ' + str(list(spec.candidates))}"
        f" components) on {train.n} samples",
        flush=True,
    )
