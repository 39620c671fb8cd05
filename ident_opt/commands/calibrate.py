"""`ident-opt calibrate`: how close the simulator's default trial (the problem's [simulate] section) is to a real
trial. Both get the same treatment: the rigid model fitted by OLS on the whole trial, then its residual per
joint — size, spectrum, where its power sits — and the real trial's link-deflection channels (--channel, e.g.
strain gauges) beside the simulated spring deflection.

Writes simulator_calibration.md and figures/simulator_calibration.png into --out (default: the real problem's
[output] dir, else results/) and prints the report.
"""

from __future__ import annotations

import argparse

from ident_opt.commands.common import output_dir, problem_for
from ident_opt.errors import InputError
from ident_opt.paper.calibration import calibrate
from ident_opt.report import calibration as report


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--problem", required=True, metavar="P", help="the simulated problem (with [simulate])")
    parser.add_argument(
        "--real", required=True, metavar="R", help="the real problem whose [data] trials are the target"
    )
    parser.add_argument(
        "--channel",
        action="append",
        default=[],
        metavar="NAME",
        help="a column of the real trials that measures link deflection (e.g. a strain gauge); repeatable",
    )
    parser.add_argument("--out", metavar="DIR", help="output folder (default: the real problem's, else results/)")


def run(args: argparse.Namespace) -> int:
    """Load both problems, calibrate, write the report, print it."""
    sim, real = problem_for(args, "calibrate"), problem_for(args, "calibrate", "real")
    if sim.simulate is None:
        raise InputError(f"{sim.path}: no [simulate] section: nothing to calibrate")
    if not real.data.trials:
        raise InputError(f"{real.path}: no trials under [data]: nothing to calibrate against")
    out = output_dir(args, real)
    print(report.write(calibrate(real, sim, args.channel), out, _command(args)))
    return 0


def _command(args: argparse.Namespace) -> str:
    """The command line, rebuilt from the parsed flags (for the report)."""
    parts = ["ident-opt calibrate", f"--problem {args.problem}", f"--real {args.real}"]
    parts += [f"--channel {c}" for c in args.channel]
    parts += [f"--out {args.out}"] if args.out else []
    return " ".join(parts)
