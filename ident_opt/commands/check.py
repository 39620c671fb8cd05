"""Validate a problem file and its data, and summarise each trial (samples, rate, ranges, derivatives).

Nothing is fitted and nothing is written except the optional --json summary. Use it first on a new
robot's logs: every fault is reported with the file, column and first offending row, exit status 2.
"""

from __future__ import annotations

import argparse

from ident_opt.arm.chain import ChainRobot
from ident_opt.commands.common import add_problem_arguments, load, write_json


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_problem_arguments(parser)


def summary(trial) -> dict:
    """A JSON-able description of one loaded trial."""
    return {
        "source": trial.source,
        "samples": trial.n,
        "duration_s": float(trial.t[-1] - trial.t[0]),
        "rate_hz": trial.rate_hz,
        "derivatives": trial.derivatives,
        "dropped_rows": trial.dropped_rows,
        "extra_columns": list(trial.extra.columns),
        "ranges": {
            name: [[float(arr[:, j].min()), float(arr[:, j].max())] for j in range(arr.shape[1])]
            for name, arr in (("q", trial.q), ("dq", trial.dq), ("ddq", trial.ddq), ("tau", trial.tau))
        },
    }


def run(args: argparse.Namespace) -> int:
    loaded = load(args, fit=False)  # a constant torque is a warning here: nothing is fitted
    reports = [summary(trial) for trial in loaded.trials]
    extra = {}
    if isinstance(loaded.problem.robot, ChainRobot):  # an n-joint arm: its summary is ident_opt.studies.urdf's
        from ident_opt.studies import urdf as study

        extra["robot"] = study.check_summary(loaded.problem)
        print("\n".join(study.check_lines(loaded.problem, extra["robot"])))
    else:
        problem = loaded.problem
        print(f"problem {problem.name!r} ({problem.path}): robot convention {problem.robot.convention!r}")
        if hasattr(problem.robot, "statement"):  # a two-joint URDF arm: the angle offsets applied to its data
            extra["robot"] = problem.robot.summary()
            print("\n".join(problem.robot.statement))
    units = {"q": "rad", "dq": "rad/s", "ddq": "rad/s²", "tau": "N·m"}
    for rep in reports:
        print(
            f"{rep['source']}: {rep['samples']} samples, {rep['duration_s']:.2f} s at {rep['rate_hz']:.6g} Hz; "
            f"derivatives {rep['derivatives']}; dropped rows: {rep['dropped_rows']}"
        )
        for name, ranges in rep["ranges"].items():
            joints = ", ".join(f"joint {j} [{lo:.4g}, {hi:.4g}]" for j, (lo, hi) in enumerate(ranges, 1))
            print(f"  {name:>3} [{units[name]}]: {joints}")
    write_json(args.json, {"problem": loaded.problem.name, **extra, "trials": reports})
    return 0
