"""`ident-opt detect`: contacts and collisions (`docs/contacts.md`).

Fits the arm as `compare` does (the recommended fit, physically consistent; --estimator chooses another) on the
problem's training trials, calibrates per-joint thresholds on the collision-free trials --calibrate (default: the
problem's trials; their false alarms per minute held out one trial at a time), then runs the generalized-momentum
observer over each --data trial (q, dq and torques or currents; no accelerations). Writes per data trial
DIR/<stem>.csv (t, alarm, tau_ext1 … tau_extn [N m]) and DIR/<stem>.png, and with --json the thresholds, the
persistence, the calibration's false alarms and each trial's alarms (start, end, joint, peak).
"""

from __future__ import annotations

import argparse
import sys

from ident_opt import api, outputs
from ident_opt.commands.common import add_estimator_flag, add_switches, check_trial_names, output_dir, problem_for
from ident_opt.contact.thresholds import MARGIN
from ident_opt.report import detect as report
from ident_opt.report import write_json


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--problem", required=True, metavar="P", help="problem file (problems/*.toml)")
    parser.add_argument(
        "--calibrate",
        metavar="C",
        action="append",
        help="a collision-free trial to calibrate the thresholds on; repeatable (default: the problem's trials)",
    )
    parser.add_argument(
        "--data", metavar="T", action="append", required=True, help="a trial to watch for contacts; repeatable"
    )
    parser.add_argument("--out", metavar="DIR", help="folder for the CSV and figure of each trial")
    parser.add_argument("--json", metavar="F", help="also write a machine-readable result to F")
    add_estimator_flag(parser, "the fit the observer's model comes from")
    parser.add_argument(
        "--margin",
        type=float,
        default=MARGIN,
        metavar="X",
        help=f"thresholds = X × the largest collision-free level held for the persistence (default {MARGIN:g})",
    )
    add_switches(
        parser,
        {
            "--allow-implausible": "proceed when values look like the wrong unit (e.g. |q| > 100 rad)",
            "--drop-invalid": "skip rows with non-numeric/NaN/inf cells or non-increasing t (the count is reported)",
        },
    )


def run(args: argparse.Namespace) -> int:
    problem = problem_for(args, "detect")
    check_trial_names(args)
    for path in args.calibrate or []:
        outputs.check_length(path, "--calibrate", reading=True)
    flags = {"allow_implausible": args.allow_implausible, "drop_invalid": args.drop_invalid}
    training, testing = api.load_trials(problem, **flags)
    calibration = api.load_trials(problem, args.calibrate, **flags, fit=False)[0] if args.calibrate else None
    data = api.load_trials(problem, args.data, **flags, fit=False)[0]
    if calibration is None:
        calibration = [*training, *testing]
    out = output_dir(args, problem)
    result = api.detect(problem, training, calibration, data, estimator=args.estimator, margin=args.margin)
    files = report.write(result, out, tuple(problem.robot.joint_names))
    for warning in result.warnings:
        print(warning, file=sys.stderr)
    print(report.summary(result))
    payload = result.as_json()
    payload["files"] = [str(out / f) for f in files]
    write_json(args.json, payload)
    print(f"wrote {', '.join(files)} to {out.resolve()}")
    return 0
