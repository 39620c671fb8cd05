"""`ident-opt export`: the identified arm as a robot description other tools load.

    ident-opt export --problem P [--data D] [--estimator NAME] --format urdf|mjcf --out FILE

Fits the arm on the problem's training trials (or every --data) with the fit the tool stands behind (its
physically consistent one unless --estimator says otherwise) and writes it as a URDF (with a JSON sidecar
FILE.json: every identified value with its standard error, the notes) or a MuJoCo MJCF: per moving link the
identified mass, centre of mass and inertia; per joint viscous and Coulomb friction (URDF <dynamics damping
friction>, MJCF damping and frictionloss) and armature (MJCF armature; URDF: in its comment and the sidecar).
A planar two-link arm's grouped parameters are realised by one physically consistent set of rigid bodies, and the
file says which values the data did not determine. Pinocchio (URDF) and MuJoCo (MJCF) reproduce the fit's torques
from the file (`tests/test_export.py`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ident_opt import outputs
from ident_opt.commands.common import add_problem_arguments, load, require, write_json
from ident_opt.fitting.recommend import chosen
from ident_opt.problem import load_problem
from ident_opt.shipping import identified, write_mjcf, write_urdf
from ident_opt.shipping.description import identified_arm

#: The formats of --format, and the file ending each expects.
FORMATS = {"urdf": ".urdf", "mjcf": ".xml"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """--problem/--data/--json, --estimator, --format and --out."""
    add_problem_arguments(parser)
    parser.add_argument("--format", required=True, choices=tuple(FORMATS), help="urdf (with FILE.json) or mjcf")
    parser.add_argument("--out", required=True, metavar="FILE", help="the robot description to write")
    parser.add_argument(
        "--estimator",
        metavar="NAME",
        help="the fit to export, among the arm's (default: the recommended fit, chosen from the data's own "
        "evidence: the arm's physically consistent fit, or the robust one when noise biases it)",
    )


def run(args: argparse.Namespace) -> int:
    """Fit, realise, write, print what was written and the notes."""
    problem = load_problem(args.problem)
    require("export", problem)
    robot = problem.robot
    sidecar = Path(f"{args.out}.json")
    if args.format == "urdf":
        outputs.check_file_output(sidecar, "--out's sidecar")
    if args.estimator is not None and args.estimator not in robot.estimators:
        chosen("export", robot, robot.model(), [], problem, args.estimator)  # the InputError naming the arm's fits
    loaded = load(args, "export", min_samples=2 * robot.model().n_params, problem=problem)
    choice = chosen("export", robot, robot.model(), loaded.training, problem, args.estimator)
    print(f"ident-opt export: the {choice.estimator} fit ({choice.why})", file=sys.stderr)
    estimator = choice.estimator
    exported = identified_arm(robot, loaded.training, estimator)
    record = {
        **identified(exported.model.names, exported.fit.pi, exported.fit.se, estimator),
        "problem": problem.name,
        "trials": exported.trials,
        "model": {"extensions": list(exported.model.extensions), **exported.model.settings()},
        "not_determined": exported.fit.details.get("not_determined", []),
    }
    if args.format == "urdf":
        written = list(write_urdf(exported.description, args.out, record))
    else:
        written = [write_mjcf(exported.description, args.out)]
    notes = list(exported.description.notes)
    print(f"ident-opt export: {robot.headline}; the {estimator} fit on {len(exported.trials)} trial(s)")
    print("\n".join(f"  note: {line}" for line in notes))
    print("wrote " + ", ".join(str(p) for p in written))
    write_json(args.json, {**record, "format": args.format, "files": [str(p) for p in written], "notes": notes})
    return 0
