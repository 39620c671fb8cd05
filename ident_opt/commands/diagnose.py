"""`ident-opt diagnose` (being built; see the open issue)."""

from __future__ import annotations

import argparse

from ident_opt.commands.common import add_problem_arguments


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_problem_arguments(parser)
    parser.add_argument("--out", metavar="DIR", help="output folder")


def run(args: argparse.Namespace) -> int:
    print("ident-opt diagnose: not built yet", flush=True)
    return 1
