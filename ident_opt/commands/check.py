"""Validate a problem file and its data, and summarise the robot and each trial (samples, rate, ranges, derivatives).

Nothing is fitted and nothing is written except the optional --json summary. Use it first on a new
robot's logs: every fault is reported with the file, column and first offending row, exit status 2.
"""

from __future__ import annotations

import argparse
import sys

from ident_opt import api
from ident_opt.commands.common import add_problem_arguments, load, write_json

#: Units of the ranges printed per signal.
UNITS = {"q": "rad", "dq": "rad/s", "ddq": "rad/s²", "tau": "N·m"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_problem_arguments(parser)


def run(args: argparse.Namespace) -> int:
    loaded = load(args, "check", fit=False)  # a constant torque is a warning here: nothing is fitted
    found = api.check(loaded.problem, loaded.training, loaded.testing)
    print("\n".join(found.lines))
    for rep in found.trials:
        print(
            f"{rep['source']}: {rep['samples']} samples, {rep['duration_s']:.2f} s at {rep['rate_hz']:.6g} Hz; "
            f"derivatives {rep['derivatives']}; dropped rows: {rep['dropped_rows']}"
        )
        for name, ranges in rep["ranges"].items():
            joints = ", ".join(f"joint {j} [{lo:.4g}, {hi:.4g}]" for j, (lo, hi) in enumerate(ranges, 1))
            print(f"  {name:>3} [{UNITS[name]}]: {joints}")
    for warning in found.warnings:  # nothing is scored here, but the held-out trials are not held out
        print(warning, file=sys.stderr)
    write_json(args.json, found.as_json())
    return 0
