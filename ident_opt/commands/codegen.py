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

from ident_opt import api, outputs
from ident_opt.commands.common import (
    add_components,
    add_estimator_flag,
    add_problem_arguments,
    add_switches,
    load,
    output_dir,
    problem_for,
)
from ident_opt.fitting.recommend import choose
from ident_opt.report import codegen as report
from ident_opt.shipping import codegen, generate, ship


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
    add_estimator_flag(parser, "the fit of the generated π")
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
    problem = problem_for(args, "codegen")
    if args.estimator is not None:  # an unknown one fails before any work
        choose(problem, [], estimator=args.estimator, command="codegen")
    codegen.find_compiler()  # fail before any fitting when there is none
    saved = ship.read_parameters(args.parameters) if args.parameters else None
    generate.shipped_model(problem.robot, args.extension, saved)  # a bad extension or file fails before reading data
    trials = load(args, "codegen", problem=problem).training if saved is None or saved.get("gmr") is None else []
    out = output_dir(args, problem, indexed=False)  # only once every input is read and checked
    made = api.codegen(  # the API's: its checks, and the files written remembered as the tool's
        problem,
        trials,
        out,
        estimator=args.estimator,
        extensions=args.extension,
        saved=saved,
        components=args.components,
        forward=not args.no_forward,
        update=not args.no_update,
        force=args.force,
        say=lambda line: print(f"ident-opt codegen: {line}", file=sys.stderr, flush=True),
    )
    print(report.write(made.payload, made.built, out, getattr(args, "json", None)))
    outputs.remember_owned(out, made.written)  # again: the report has rewritten parameters.json and the README
    if "pi_update" in made.payload:
        print(_update_line(made.payload["pi_update"], ship.TOLERANCE["pi_update"]))
    if made.disagreeing:
        print(
            f"ident-opt codegen: the compiled code disagrees with the Python model: {made.disagreeing}", file=sys.stderr
        )
        return 1
    return 0


def _update_line(update: dict, limit: float) -> str:
    """The terminal line on the pi_update check (`limit`: its tolerance)."""
    return (
        f"  pi_update: generated C vs the Python online path over {update['samples']} samples, largest difference "
        f"{update['max_difference_vs_size_or_se']:.2e} of a parameter's size (or of its standard error, nearer 0; "
        f"limit {limit:.0e}; relative to the size alone {update['max_relative_difference']:.1e}), of the torques "
        f"{update['max_torque_relative_difference']:.1e}; {update['c_ns_per_update']:.0f} ns per update from a C loop"
    )
