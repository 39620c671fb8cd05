"""Validate a problem file and its data, and summarise the robot and each trial (samples, rate, ranges, derivatives).

Nothing is fitted and nothing is written except the optional --json summary. Use it first on a new
robot's logs: every fault is reported with the file, column and first offending row, exit status 2.
"""

from __future__ import annotations

import argparse
import sys

from ident_opt.commands.common import add_problem_arguments, load, write_json
from ident_opt.fitting.base import base_parameters
from ident_opt.outputs import shown

#: Units of the ranges printed per signal.
UNITS = {"q": "rad", "dq": "rad/s", "ddq": "rad/s²", "tau": "N·m"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_problem_arguments(parser)


def summary(trial) -> dict:
    """A JSON-able description of one loaded trial."""
    return {
        "source": shown(trial.source),
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


def robot_summary(problem) -> tuple[dict, list[str]]:
    """The robot's JSON summary (`Robot.summary` with its identifiable base parameters) and the lines printed."""
    robot = problem.robot
    arm = robot.model()
    info = {**robot.summary(), "base_parameters": base_parameters(arm).rank}
    if "urdf" in info:  # as people read it: relative to the working folder when inside it
        info["urdf"] = shown(info["urdf"])
    lines = [f"problem {problem.name!r} ({problem.path}): {robot.headline}", *robot.describe()]
    lines.append(f"  identifiable: {info['base_parameters']} base parameters of the {arm.n_params} of its model")
    return info, lines


def run(args: argparse.Namespace) -> int:
    loaded = load(args, "check", fit=False)  # a constant torque is a warning here: nothing is fitted
    reports = [summary(trial) for trial in loaded.trials]
    robot, lines = robot_summary(loaded.problem)
    print("\n".join(lines))
    for rep in reports:
        print(
            f"{rep['source']}: {rep['samples']} samples, {rep['duration_s']:.2f} s at {rep['rate_hz']:.6g} Hz; "
            f"derivatives {rep['derivatives']}; dropped rows: {rep['dropped_rows']}"
        )
        for name, ranges in rep["ranges"].items():
            joints = ", ".join(f"joint {j} [{lo:.4g}, {hi:.4g}]" for j, (lo, hi) in enumerate(ranges, 1))
            print(f"  {name:>3} [{UNITS[name]}]: {joints}")
    for warning in loaded.warnings:  # nothing is scored here, but the held-out trials are not held out
        print(warning, file=sys.stderr)
    payload = {"problem": loaded.problem.name, "robot": robot, "trials": reports}
    write_json(args.json, {**payload, "warnings": [w.as_dict() for w in loaded.warnings]})
    return 0
