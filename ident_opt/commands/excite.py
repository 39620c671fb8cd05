"""`ident-opt excite`: design the trajectory to run next, a periodic Fourier excitation optimised by IPOPT.

Per joint a finite Fourier series with an offset (Swevers style), at rest at its start and end, within the
problem's [limits] (joint angles, speeds, accelerations, the datasheet model's torque), checked on a 1 kHz
grid. Criteria: d (D-optimal: the largest log det of the base parameters' information matrix; noise: the
datasheet model's RMS residual per joint on the problem's first trial, or 1 N m without data), cond (the
smallest condition number of the column-equilibrated regressor), discriminate (T-optimal: the largest
difference between two causes' predicted torques, --between CAUSE_A,CAUSE_B). Several random starts, the
best kept. Writes OUT.csv (t, q, dq, ddq at the controller rate and the feed-forward torque tau_ff),
OUT.png and OUT.json (criteria, limits' margins); `ident-opt simulate --trajectory-file OUT.csv` follows it.
A --duration at a --rate whose samples would not fit in memory (about 200 + 140 n bytes each for n joints, at most
half the memory available or 8 GiB; docs/cli.md) is refused before any work.

Examples:
  ident-opt excite --problem problems/tudor_2dof.toml --out traj.csv --duration 20 --criterion d
  ident-opt excite --problem problems/tudor_2dof.toml --out disc.csv --criterion discriminate \\
      --between asymmetric_coulomb,elasticity
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from ident_opt import outputs
from ident_opt.commands.common import add_problem_arguments, add_progress_flag, check_trial_names, problem_for
from ident_opt.data.loader import load_dataset
from ident_opt.errors import InputError
from ident_opt.excitation import design as excitation
from ident_opt.excitation import proof as excitation_proof
from ident_opt.excitation.excite import check_output_size, excite
from ident_opt.report import excitation as report

#: Accepted ranges of the numeric flags.
DURATION = (2.0, 3600.0)  # s
MAX_HARMONICS = 20
MAX_STARTS = 100


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """--problem/--data/--json plus the design's flags."""
    add_problem_arguments(parser)
    parser.add_argument(
        "--out", required=True, metavar="T.csv", help="the trajectory to write (CSV); with --proof, the report (*.md)"
    )
    parser.add_argument("--duration", type=float, default=20.0, metavar="S", help="trajectory length [s] (default 20)")
    parser.add_argument(
        "--criterion",
        choices=("d", "cond", "discriminate"),
        default="d",
        help="d: D-optimal (default); cond: least condition number; discriminate: T-optimal between --between",
    )
    parser.add_argument("--between", metavar="A,B", help="the two causes a discriminating design tells apart")
    parser.add_argument("--seed", type=int, default=0, help="random seed of the starts (default 0)")
    parser.add_argument("--starts", type=int, default=6, metavar="K", help="random starts (default 6)")
    parser.add_argument(
        "--workers",
        type=int,
        default=excitation.cores(),
        metavar="K",
        help=f"processes running the starts at once (default: the cores available, {excitation.cores()} here; the "
        "design does not depend on it)",
    )
    parser.add_argument("--harmonics", type=int, metavar="H", help="harmonics per joint (default 5; discriminate: 16)")
    parser.add_argument(
        "--base-hz",
        type=float,
        metavar="HZ",
        help="base frequency (default: near 0.1 Hz, discriminate: near 0.25 Hz, with a whole number of periods "
        "in the duration)",
    )
    parser.add_argument("--rate", type=float, default=1000.0, metavar="HZ", help="output rate (default 1000 Hz)")
    parser.add_argument(
        "--extension",
        action="append",
        default=[],
        metavar="NAME",
        help="design for an extended model (armature, asymmetric_coulomb, stribeck, offset); repeatable",
    )
    parser.add_argument(
        "--proof",
        type=int,
        metavar="N",
        help="instead: design D-, cond-optimal and discriminating (--between, default asymmetric_coulomb,elasticity) "
        "trajectories and prove them in the simulator with N noise seeds each; the report to --out (*.md)",
    )
    add_progress_flag(parser)


def _check(args: argparse.Namespace) -> None:
    """InputError for a flag out of range."""
    if not (math.isfinite(args.duration) and DURATION[0] <= args.duration <= DURATION[1]):
        raise InputError(f"--duration must be between {DURATION[0]:g} and {DURATION[1]:g} s, got {args.duration:g}")
    if args.harmonics is not None and not 1 <= args.harmonics <= MAX_HARMONICS:
        raise InputError(f"--harmonics must be an integer in [1, {MAX_HARMONICS}], got {args.harmonics}")
    if not 1 <= args.starts <= MAX_STARTS:
        raise InputError(f"--starts must be an integer in [1, {MAX_STARTS}], got {args.starts}")
    if not 1 <= args.workers <= MAX_STARTS:
        raise InputError(f"--workers must be an integer in [1, {MAX_STARTS}], got {args.workers}")
    if args.seed < 0:
        raise InputError(f"--seed must be ≥ 0, got {args.seed}")
    if not (math.isfinite(args.rate) and 10.0 <= args.rate <= 10000.0):
        raise InputError(f"--rate must be between 10 and 10000 Hz, got {args.rate:g}")
    if args.base_hz is not None:
        periods = args.base_hz * args.duration
        if not (math.isfinite(periods) and periods >= 1 and abs(periods - round(periods)) < 1e-6):
            raise InputError("--base-hz must give a whole number (≥ 1) of periods in --duration")
    if args.proof is not None:
        if not 1 <= args.proof <= MAX_STARTS:
            raise InputError(f"--proof must be a number of seeds in [1, {MAX_STARTS}], got {args.proof}")
        return
    if (args.criterion == "discriminate") != (args.between is not None):
        raise InputError("--between A,B goes with --criterion discriminate (and it needs it)")


def run(args: argparse.Namespace) -> int:
    """Design (`excitation.excite`), write the CSV, figure and JSON, print a summary."""
    problem = problem_for(args, "excite")
    _check(args)
    if args.proof is None:  # the output's memory, before any data is read or any start solved
        check_output_size(problem.robot.n_joints, args.duration, args.rate)
    if args.proof is not None and not problem.robot.extensions:
        raise InputError(
            "--proof (its discriminating design) tells two causes of the diagnosis apart, which only an arm with "
            f"model extensions has; {problem.robot.described_as} has none: design with --criterion d or cond (and "
            "see `python benchmarks/excitation_benefit.py` for the proof against random motions)"
        )
    if problem.limits is None:
        raise InputError(
            f"{problem.path}: section [limits] is required to design an excitation (docs/problem-files.md)"
        )
    check_trial_names(args)
    data = args.data or [str(p) for p in problem.data.trials]
    outputs.declare_inputs(data)  # the problem's own trials too: --out (declared by the CLI) is refused if one
    written = report.proof_paths(args.out)[:3] if args.proof is not None else report.paths(args.out)
    for path in written:
        outputs.check_file_output(path, "--out")  # the figure and JSON beside it, the proof's tables
    kwargs = {"allow_implausible": args.allow_implausible, "drop_invalid": args.drop_invalid}
    trial = load_dataset(data[0], problem.data, problem.robot, **kwargs) if data else None
    if args.proof is not None:
        return _proof(args, problem, trial)
    design = excite(
        problem,
        trial,
        criterion=args.criterion,
        duration=args.duration,
        between=args.between,
        harmonics=args.harmonics,
        base_hz=args.base_hz,
        extensions=args.extension,
        starts=args.starts,
        seed=args.seed,
        rate=args.rate,
        workers=args.workers,
        progress=not args.no_progress,
    )
    files = report.write(design, design.setup, args.out, args.json)
    print(report.terminal(design))
    print("wrote " + ", ".join(str(f) for f in files))
    return 0


def _proof(args: argparse.Namespace, problem, trial) -> int:
    """The simulator proof (`excitation.proof`): the report --out (*.md) and its files beside it."""
    if trial is None:
        raise InputError(
            f"{problem.path}: --proof needs data (the problem's [data] trials or --data): the noise "
            "model and the discriminated causes are fitted on it"
        )
    report.proof_paths(args.out)  # a bad name fails before the work
    proof = excitation_proof.run(
        problem,
        trial,
        duration=args.duration,
        seeds=args.proof,
        between=args.between or "asymmetric_coulomb,elasticity",
        starts=args.starts,
        progress=not args.no_progress,
        workers=args.workers,
    )
    report.write_proof(proof, args.out)
    print(report.proof_terminal(proof, Path(args.out)))
    return 0
