"""`ident-opt diagnose`: what the nominal model gets wrong, which catalogue cause explains it, the extended
model and its held-out gain (`docs/cli.md`, `docs/effects.md`).

With two --data files the first trains and the second is held out; with one, its first part (the problem's
train_fraction, in time) trains and the rest is held out. Writes diagnosis.md and two figures to --out
(default: the problem's output folder) and, with --json, the machine-readable result. On an arm with n joints the
rigid fit is the recommended fit (`studies.recommend`, judged on the training part) unless --estimator says
otherwise; its name and reason go to the terminal, the report and the JSON.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from ident_opt.commands.common import add_problem_arguments, load, output_dir, write_json
from ident_opt.data import Dataset
from ident_opt.diagnosis import diagnose, report
from ident_opt.errors import InputError
from ident_opt.identify.estimators import ESTIMATORS
from ident_opt.studies.recommend import Recommendation, chosen, evidence
from ident_opt.warnings import ResultWarning

#: What the planar two-link diagnosis fits π with (it does not take the recommended fit).
PLANAR_RIGID_FIT = Recommendation(
    "wls", "the planar diagnosis's weighted least squares, on the objective every candidate is scored on"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_problem_arguments(parser)
    parser.add_argument("--out", metavar="DIR", help="folder for diagnosis.md and the figures")
    parser.add_argument(
        "--estimator",
        choices=tuple(ESTIMATORS),
        default=None,
        help="how the rigid fit's π is identified on an arm with n joints, among the arm's fits (default: the "
        "recommended fit, chosen from the training part's evidence)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _training(trial: Dataset, unseen: Dataset | None, fraction: float) -> Dataset:
    """The part of the data the diagnosis trains on: all of `trial` when a held-out trial is given, else its first
    `fraction` in time."""
    if unseen is not None:
        return trial
    return trial.subset(np.nonzero(trial.t <= trial.t[0] + fraction * (trial.t[-1] - trial.t[0]))[0])


def rigid_fit(loaded, asked: str | None) -> tuple[Recommendation, list[ResultWarning]]:
    """The estimator of the rigid fit and why, with the warnings of the evidence behind it: `asked` (--estimator),
    else the recommended fit on the training part (`studies.recommend`); the planar diagnosis's own fit."""
    problem = loaded.problem
    robot = problem.robot
    if robot.engine == "planar":
        if asked is not None:
            raise InputError(
                f"diagnose --estimator {asked}: the planar two-link diagnosis fits its rigid model by its own "
                "weighted least squares; --estimator serves arms with n joints"
            )
        return PLANAR_RIGID_FIT, []
    if asked is not None:
        return chosen("diagnose", robot, robot.model(), [], problem, asked), []
    train = _training(loaded.train, loaded.unseen, problem.split.train_fraction)
    found = evidence(robot, robot.model(), [train], problem.data.conversions, problem.data.derivative_cutoff_hz)
    return found.recommendation, list(found.trust.warnings)


def run(args: argparse.Namespace) -> int:
    loaded = load(args, "diagnose")
    choice, warnings = rigid_fit(loaded, args.estimator)
    warnings = [*loaded.warnings, *warnings]  # the trials' own (a held-out trial that trains) come first
    print(f"ident-opt diagnose: rigid fit: the {choice.estimator} fit ({choice.why})", file=sys.stderr)
    for w in warnings:
        print(w, file=sys.stderr)
    result = diagnose(
        loaded.problem.robot,
        loaded.train,
        loaded.unseen,
        train_fraction=loaded.problem.split.train_fraction,
        progress=not args.no_progress,
        torque_filter_hz=loaded.problem.data.derivative_cutoff_hz,
        rigid_fit=None if loaded.problem.robot.engine == "planar" else choice,
    )
    result.nominal["rigid_fit"].update(estimator=choice.estimator, why=choice.why)
    result.warnings = warnings
    out = output_dir(args, loaded.problem)
    files = report.write(result, out)
    print(report.summary(result))
    print(f"report: {out / 'diagnosis.md'}", file=sys.stderr)
    payload = result.as_json()
    payload["files"] = [str(out / f) for f in files]
    write_json(args.json, payload)
    return 0
