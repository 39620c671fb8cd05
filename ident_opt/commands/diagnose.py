"""`ident-opt diagnose`: what the nominal model gets wrong, which catalogue cause explains it, the extended
model and its held-out gain (`docs/cli.md`, `docs/effects.md`).

With two --data files the first trains and the second is held out; with one, its first part (the problem's
train_fraction, in time) trains and the rest is held out. Writes diagnosis.md and two figures to --out
(default: the problem's output folder) and, with --json, the machine-readable result.
"""

from __future__ import annotations

import argparse
import sys

from ident_opt.commands.common import add_problem_arguments, load, output_dir, write_json
from ident_opt.diagnosis import diagnose, report


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_problem_arguments(parser)
    parser.add_argument("--out", metavar="DIR", help="folder for diagnosis.md and the figures")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    loaded = load(args, "diagnose")
    result = diagnose(
        loaded.problem.robot,
        loaded.train,
        loaded.unseen,
        train_fraction=loaded.problem.split.train_fraction,
        progress=not args.no_progress,
        torque_filter_hz=loaded.problem.data.derivative_cutoff_hz,
    )
    out = output_dir(args, loaded.problem)
    files = report.write(result, out)
    print(report.summary(result))
    print(f"report: {out / 'diagnosis.md'}", file=sys.stderr)
    payload = result.as_json()
    payload["files"] = [str(out / f) for f in files]
    write_json(args.json, payload)
    return 0
