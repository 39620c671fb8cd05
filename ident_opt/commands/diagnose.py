"""`ident-opt diagnose`: what the nominal model gets wrong, which catalogue cause explains it, the extended
model and its held-out gain (`docs/cli.md`, `docs/effects.md`).

With two --data files the first trains and the second is held out; with one, its first part (the problem's
train_fraction, in time) trains and the rest is held out. Writes diagnosis.md and two figures to --out
(default: the problem's output folder) and, with --json, the machine-readable result. The rigid fit is the
recommended fit (`fitting.recommend`, judged on the training part) unless --estimator says otherwise, on every
arm; its name and reason go to the terminal, the report and the JSON.
"""

from __future__ import annotations

import argparse
import sys

from ident_opt.commands.common import add_problem_arguments, load, output_dir, write_json
from ident_opt.diagnosis import diagnose
from ident_opt.fitting.estimators import ESTIMATORS
from ident_opt.fitting.recommend import Recommendation, chosen, for_diagnosis
from ident_opt.report import diagnosis as report
from ident_opt.warnings import ResultWarning


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_problem_arguments(parser)
    parser.add_argument("--out", metavar="DIR", help="folder for diagnosis.md and the figures")
    parser.add_argument(
        "--estimator",
        choices=tuple(ESTIMATORS),
        default=None,
        help="how the rigid fit's π is identified, among the arm's fits (default: the recommended fit, chosen from "
        "the training part's evidence)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def rigid_fit(loaded, asked: str | None) -> tuple[Recommendation, list[ResultWarning]]:
    """The estimator of the rigid fit and why, with the warnings of the evidence behind it: `asked` (--estimator),
    else the recommended fit on the training part (`fitting.recommend`)."""
    problem = loaded.problem
    robot = problem.robot
    if asked is not None:
        return chosen("diagnose", robot, robot.model(), [], problem, asked), []
    data = problem.data
    found = for_diagnosis(
        robot, loaded.train, loaded.unseen, problem.split.train_fraction, data.conversions, data.derivative_cutoff_hz
    )
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
        rigid_fit=choice,
    )
    for w in result.warnings:  # the diagnosis's own (a joint the held-out part barely moves)
        print(w, file=sys.stderr)
    result.warnings = [*warnings, *result.warnings]
    out = output_dir(args, loaded.problem)
    files = report.write(result, out)
    print(report.summary(result))
    print(f"report: {out / 'diagnosis.md'}", file=sys.stderr)
    payload = result.as_json()
    payload["files"] = [str(out / f) for f in files]
    write_json(args.json, payload)
    return 0
