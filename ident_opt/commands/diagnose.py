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

from ident_opt.commands.common import (
    add_estimator_flag,
    add_problem_arguments,
    add_progress_flag,
    load,
    output_dir,
    write_json,
)
from ident_opt.diagnosis import diagnose
from ident_opt.report import diagnosis as report


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_problem_arguments(parser)
    parser.add_argument("--out", metavar="DIR", help="folder for diagnosis.md and the figures")
    add_estimator_flag(
        parser,
        "the rigid fit's π (and the fit of a --nominal compare JSON)",
        "the recommended fit, chosen from the training part's evidence",
    )
    parser.add_argument(
        "--nominal",
        metavar="FIT",
        help="an identified arm as the nominal model instead of the datasheet: a `compare --json` or an `export` "
        "sidecar (ARM.urdf.json, ARM.xml.json); answers 'what changed since this model?'",
    )
    add_progress_flag(parser)


def run(args: argparse.Namespace) -> int:
    loaded = load(args, "diagnose")
    result = diagnose(
        loaded.problem,
        loaded.training,
        loaded.testing,
        estimator=args.estimator,
        nominal=args.nominal,
        progress=not args.no_progress,
    )
    rigid = result.nominal["rigid_fit"]
    print(f"ident-opt diagnose: rigid fit: the {rigid['estimator']} fit ({rigid['why']})", file=sys.stderr)
    print(f"ident-opt diagnose: compared: {result.compared()}", file=sys.stderr)
    for w in result.warnings:
        print(w, file=sys.stderr)
    out = output_dir(args, loaded.problem)
    files = report.write(result, out)
    print(report.summary(result))
    print(f"report: {out / 'diagnosis.md'}", file=sys.stderr)
    payload = result.as_json()
    payload["files"] = [str(out / f) for f in files]
    write_json(args.json, payload)
    return 0
