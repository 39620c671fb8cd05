"""`ident-opt compare`: the nominal model (datasheet or URDF) against OLS and the physically consistent fits.

For the planar two-link arm: the datasheet under both conventions, OLS, the constrained fit (M(q) ≻ 0 for every
q, friction ≥ 0), the NLP on physical parameters and IV, on the paper's shuffled protocol, a chronological split
and the held-out trials. For an n-joint arm from a URDF: the URDF with its joints' nominal friction and armature,
OLS on the base parameters, the consistent fit (a pseudo-inertia ⪰ 0 per link), the plausible consistent fit
(the default: a log-det prior toward the URDF) and IV, on the chronological split and the held-out trials.

Writes to the output folder: compare.md (the report), compare_parameters.csv (values and standard
errors), compare_consistency.csv, compare_metrics.csv (held-out rmse / nmse / nmse_range per joint and
protocol), compare_seeds.csv + compare_seeds.png (the paper's seed study) and, with --json, the
machine-readable result. `--against OTHER.json` (a `compare --json` or `identify --json` of another run: last week's,
before a maintenance, at another cut-off) puts the two runs side by side (`ident_opt.runs`): this run's recommended
fit beside the other's same fit (its recommended when it has not that one), each parameter with its standard errors,
the difference and z = difference / √(se² + se_other²), |z| > 3 marked, and the held-out nMSE per joint of each:
compare_against.md, compare_against.csv, compare_against_errors.csv and the JSON's `against`.

`--constraints-study N` instead runs the study of where the constraints matter (N short simulated trials) and writes
constraints_study.md and constraints_study.csv.
"""

from __future__ import annotations

import argparse
import sys

from ident_opt import runs
from ident_opt.commands.common import add_problem_arguments, add_progress_flag, load, output_dir, problem_for
from ident_opt.errors import InputError
from ident_opt.evaluation import compare, constraints
from ident_opt.outputs import shown
from ident_opt.report import against as against_report
from ident_opt.report import compare as report
from ident_opt.report import constraints as constraints_report


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """--problem/--data/--json plus --out, --margin, --extension and --constraints-study."""
    add_problem_arguments(parser)
    parser.add_argument("--out", metavar="DIR", help="output folder (default: the problem's [output] dir)")
    parser.add_argument(
        "--margin",
        type=float,
        default=1e-6,
        metavar="KGM2",
        help="required margin of M(q) ⪰ margin·I in the constrained fit [kg m²] (default 1e-6)",
    )
    parser.add_argument(
        "--weights",
        choices=("ols", "wls"),
        default="ols",
        help="ols: both joints weigh the same; wls: each joint by 1/σ² of its residual (default ols)",
    )
    parser.add_argument(
        "--extension",
        action="append",
        default=[],
        metavar="NAME",
        help="fit an extended model (armature, asymmetric_coulomb, stribeck, offset); repeatable (default: the "
        "rigid model, plus armature for a robot given by its inertials with a rotor inertia)",
    )
    parser.add_argument(
        "--against",
        metavar="OTHER.json",
        help="another run's compare --json (or identify --json): its fit beside this run's, parameters moved beyond "
        "their errors marked, held-out errors of each",
    )
    parser.add_argument(
        "--constraints-study",
        type=int,
        metavar="N",
        help="run the constraints study on N short simulated trials instead of the comparison",
    )
    parser.add_argument(
        "--study-source",
        choices=("multisine", "simulator", "both"),
        default="both",
        help="trials of the constraints study: the local rigid multisine generator, the built-in "
        "simulator (short tud01 trials), or both (default)",
    )
    add_progress_flag(parser)


def run(args: argparse.Namespace) -> int:
    """Run the comparison (or the constraints study), write the files, print a summary."""
    problem = problem_for(args, "compare")
    robot = problem.robot
    if args.margin < 0:
        raise InputError(f"--margin must be ≥ 0 (got {args.margin})")
    try:
        model = robot.model(tuple(args.extension) if args.extension else None)
    except ValueError as exc:
        raise InputError(f"--extension: {exc}") from None
    if not args.extension and robot.model_note is not None:
        print(f"model: rigid + {robot.model_note} (--extension chooses another)", file=sys.stderr)
    if args.constraints_study is not None:
        return _constraints_study(args, problem)
    if args.against and args.constraints_study is not None:
        raise InputError("--against compares two runs' fits; the constraints study has none: give one or the other")
    other = runs.read_payload(args.against) if args.against else None
    if other is not None:
        runs.summarize(other, shown(args.against))  # a file that is not a run is an error before any work
    loaded = load(args, "compare", min_samples=2 * model.n_params, problem=problem)
    out = output_dir(args, loaded.problem)
    result = compare.compare(
        problem,
        loaded.training,
        loaded.testing,
        extensions=args.extension,
        margin=args.margin,
        weights=None if args.weights == "ols" else "wls",
        progress=not args.no_progress,
    )
    against = None
    if other is not None:
        this = runs.summarize(result.as_json(), "this run")
        theirs = runs.summarize(other, shown(args.against), prefer=this.estimator)  # like with like when it can
        against = runs.side_by_side(this, theirs)
    files = report.write(result, out, args.json, against)
    print(report.to_terminal(result))
    if against is not None:
        print(against_report.to_terminal(against))
    for warning in result.trust.warnings:
        print(warning, file=sys.stderr)
    print(f"wrote {', '.join(files)} to {out.resolve()}")
    return 0


def _constraints_study(args: argparse.Namespace, problem) -> int:
    """The study of where the constraints matter, on N short simulated trials of the problem's robot."""
    if args.constraints_study < 1:
        raise InputError("--constraints-study needs a positive number of trials")
    robot = problem.robot
    if not robot.paper_views:  # one of the paper's views: its truth is the planar arm's datasheet (`Robot.paper_views`)
        raise InputError(
            f"--constraints-study is a study of the planar two-link arm (its datasheet is the truth the fits are "
            f"scored against); {problem.path} describes {robot.described_as}: run `ident-opt compare` without it, "
            "or the study on a planar problem (e.g. problems/tudor_2dof.toml)"
        )
    problem.require("simulate")  # its trials come from the simulator
    out = output_dir(args, problem)
    sources = tuple(constraints.STUDY_SOURCES) if args.study_source == "both" else (args.study_source,)
    results, rich = constraints.study(
        problem.robot, args.constraints_study, sources, margin=args.margin, progress=not args.no_progress
    )
    constraints_report.write(results, rich, out, args.json)
    print(constraints_report.terminal(results, rich, out))
    return 0
