"""Validate a problem file and its data, and summarise each trial (samples, rate, ranges, derivatives).

Nothing is fitted and nothing is written except the optional --json summary. Use it first on a new
robot's logs: every fault is reported with the file, column and first offending row, exit status 2.
"""

from __future__ import annotations

import argparse

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
            name: [[float(arr[:, j].min()), float(arr[:, j].max())] for j in range(2)]
            for name, arr in (("q", trial.q), ("dq", trial.dq), ("ddq", trial.ddq), ("tau", trial.tau))
        },
    }


def run(args: argparse.Namespace) -> int:
    loaded = load(args, fit=False)  # a constant torque is a warning here: nothing is fitted
    reports = [summary(trial) for trial in loaded.trials]
    print(
        f"problem {loaded.problem.name!r} ({loaded.problem.path}): robot convention {loaded.problem.robot.convention!r}"
    )
    units = {"q": "rad", "dq": "rad/s", "ddq": "rad/s²", "tau": "N·m"}
    for rep in reports:
        print(
            f"{rep['source']}: {rep['samples']} samples, {rep['duration_s']:.2f} s at {rep['rate_hz']:.6g} Hz; "
            f"derivatives {rep['derivatives']}; dropped rows: {rep['dropped_rows']}"
        )
        for name, ((lo1, hi1), (lo2, hi2)) in rep["ranges"].items():
            print(f"  {name:>3} [{units[name]}]: joint 1 [{lo1:.4g}, {hi1:.4g}], joint 2 [{lo2:.4g}, {hi2:.4g}]")
    write_json(args.json, {"problem": loaded.problem.name, "trials": reports})
    return 0
