"""`ident-opt identify`: every model (RR, DM in both conventions, PBR, CPBR, each ± GMR) on the problem's
trials under three protocols — the paper's shuffled 70/30 over its seeds, a chronological split, and
cross-trial (identify on the first trial, test on the second) — with the paper's tables and figures.

Writes to --out (default: the problem's [output] dir, else results/): identify_*.md/.csv tables,
figures/identify_*.png, README.md; with --json the result of `docs/cli.md`.
"""

from __future__ import annotations

import argparse
import sys
import time

from ident_opt.commands import urdf
from ident_opt.commands.common import add_problem_arguments, add_switches, load, output_dir


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """--problem, --data, --json, --out, plus --no-variants."""
    add_problem_arguments(parser)
    parser.add_argument("--out", metavar="DIR", help="output folder (default: the problem's [output] dir)")
    add_switches(
        parser, {"--no-variants": "skip the GMR variants of the paper's protocol (diagonal covariances; one component)"}
    )


def run(args: argparse.Namespace) -> int:
    """Identify, evaluate, write tables/figures/README/JSON, print a summary."""
    # Deferred: the study loads NumPy, pandas, scikit-learn and CasADi, the report matplotlib; `ident-opt
    # --help` builds every subcommand's parser and stays fast only if that waits until a command runs.
    from tqdm import tqdm

    from ident_opt.report import identify as report
    from ident_opt.studies.identify import identify, steps

    urdf_problem = urdf.urdf_problem(args)
    if urdf_problem is not None:  # an n-joint arm from a URDF: ident_opt.commands.urdf
        return urdf.identify(args, urdf_problem)
    start = time.perf_counter()
    from ident_opt.data import concat

    loaded = load(args, "identify", min_samples=50)
    # Several training (held-out) trials are pooled: derivatives were estimated per file, so nothing straddles.
    problem, trial = loaded.problem, concat(loaded.training)
    unseen = concat(loaded.testing) if loaded.testing else None
    out = output_dir(args, problem)
    total = steps(problem, unseen, not args.no_variants) + report.figure_count(unseen is not None)
    with tqdm(total=total, desc="identify", unit="step", file=sys.stderr, leave=False) as bar:
        result = identify(problem, trial, unseen, variants=not args.no_variants, progress=bar)
        bar.set_postfix_str("figures")
        seconds = report.write(result, out, args.json, _command(args), start, bar.update)
    print(report.terminal(result, out, args.json, seconds))
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
