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

from ident_opt import api, outputs
from ident_opt.api import export  # the API's, which checks its output as this command does (one path)
from ident_opt.commands.common import add_estimator_flag, add_problem_arguments, load, problem_for, write_json
from ident_opt.fitting.recommend import choose
from ident_opt.shipping.description import FORMATS


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """--problem/--data/--json, --estimator, --format and --out."""
    add_problem_arguments(parser)
    parser.add_argument("--format", required=True, choices=tuple(FORMATS), help="urdf (with FILE.json) or mjcf")
    parser.add_argument("--out", required=True, metavar="FILE", help="the robot description to write")
    add_estimator_flag(parser, "the fit to export")


def run(args: argparse.Namespace) -> int:
    """Fit, realise, write, print what was written and the notes."""
    problem = problem_for(args, "export")
    robot = problem.robot
    if args.format == "urdf":
        outputs.check_file_output(Path(f"{args.out}.json"), "--out's sidecar")
    if args.estimator is not None:  # an unknown fit is refused before any trial is read
        choose(problem, [], estimator=args.estimator, command="export")
    loaded = load(args, "export", min_samples=2 * robot.model().n_params, problem=problem)
    fit = api.fit(problem, loaded.training, args.estimator)
    print(f"ident-opt export: the {fit.choice.estimator} fit ({fit.choice.why})", file=sys.stderr)
    exported = export(problem, fit, args.out, args.format)
    print(f"ident-opt export: {robot.headline}; the {fit.choice.estimator} fit on {len(fit.trials)} trial(s)")
    print("\n".join(f"  note: {line}" for line in exported.notes))
    print("wrote " + ", ".join(str(p) for p in exported.files))
    write_json(args.json, exported.as_json())
    return 0
