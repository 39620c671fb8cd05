"""`ident-opt identify`: every model (RR, the nominal models DM, PBR, CPBR, each ± GMR) on the problem's trials
under every protocol — a chronological split and cross-trial (identify on the training trials, test on the
held-out ones, pooled and each), and for the planar two-link arm also the paper's shuffled 70/30 over its seeds,
with the paper's tables and figures — plus the trust checks' warnings.

Writes to --out (default: the problem's [output] dir, else results/): identify_*.md/.csv tables,
figures/identify_*.png, README.md; with --json the result of `docs/cli.md`.
"""

from __future__ import annotations

import argparse
import sys
import time

from tqdm import tqdm

from ident_opt.commands.common import add_problem_arguments, add_switches, load, output_dir
from ident_opt.evaluation.identify import identify, steps
from ident_opt.report import identify as report


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """--problem, --data, --json, --out, plus --no-variants."""
    add_problem_arguments(parser)
    parser.add_argument("--out", metavar="DIR", help="output folder (default: the problem's [output] dir)")
    add_switches(
        parser, {"--no-variants": "skip the GMR variants of the paper's protocol (diagonal covariances; one component)"}
    )


def run(args: argparse.Namespace) -> int:
    """Identify, evaluate, write tables/figures/README/JSON, print a summary and the warnings."""
    start = time.perf_counter()
    loaded = load(args, "identify", min_samples=50)
    problem = loaded.problem
    out = output_dir(args, problem)
    n, paper, unseen = problem.robot.n_joints, problem.robot.paper_views, bool(loaded.testing)
    total = steps(problem, unseen, not args.no_variants) + report.figure_count(n, paper, unseen)
    with tqdm(total=total, desc="identify", unit="step", file=sys.stderr, leave=False) as bar:
        result = identify(problem, loaded.training, loaded.testing, variants=not args.no_variants, progress=bar)
        bar.set_postfix_str("figures")
        seconds = report.write(result, out, args.json, _command(args), start, bar.update)
    print(report.terminal(result, out, args.json, seconds))
    for warning in result.warnings:
        print(warning, file=sys.stderr)
    return 0


def _command(args: argparse.Namespace) -> str:
    """The command line, rebuilt from the parsed flags (for the README)."""
    parts = ["ident-opt identify", f"--problem {args.problem}"]
    parts += [f"--data {d}" for d in (args.data or [])]
    parts += [f"--test-data {d}" for d in (args.test_data or [])]
    parts += [f"--out {args.out}"] if args.out else []
    parts += [f"--json {args.json}"] if args.json else []
    parts += ["--no-variants"] if args.no_variants else []
    return " ".join(parts)
