"""The paper audit: the paper's datasheet model (Model 2) beside its own least-squares fit, the
datasheet read under both conventions, the causes named in plain words, and the torque error of
each datasheet model on the real trials without any fitting.

Writes `paper_audit.md`, `paper_audit_parameters.csv`, `paper_audit_data.csv` and
`figures/paper_audit_torque.png` into --out (default: the problem's [output] dir, else results/).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ident_opt.commands.common import add_problem_arguments, load, output_dir
from ident_opt.paper.audit import audit
from ident_opt.report import audit as report


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_problem_arguments(parser)
    parser.add_argument("--out", metavar="DIR", help="output folder (default: results/)")


def run(args: argparse.Namespace) -> int:
    """Load, audit, write the report, print the summary."""
    loaded = load(args, "audit")
    out = output_dir(args, loaded.problem, Path("results"))
    result = audit(loaded.problem, loaded.training, loaded.testing)
    report.write(result, out, args.json)
    print(report.terminal(result, out))
    for warning in result.warnings:
        print(warning, file=sys.stderr)
    return 0
