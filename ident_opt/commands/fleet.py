"""`ident-opt fleet`: every robot of a fleet identified every day on Dask, and what changed, named.

    ident-opt fleet --problem P --logs ROOT [--out DIR] [--json F] [--store PATH] [--scheduler ADDRESS]
                    [--workers N] [--baseline-days K] [--estimator NAME] [--connect-timeout S]
                    [--figures new|all|none] [--no-progress]

ROOT holds the logs in the fleet layout, ROOT/robot=<id>/day=<YYYY-MM-DD>/*.parquet|csv|csv.gz (a local folder or a
URL the installed filesystem libraries read); every file is a trial of the problem's arm, read with its column
mapping. One Dask task per file reads it, estimates the derivatives and reduces it to sufficient statistics (the
samples never leave the worker); each robot-day gets the recommended fit (judged once per robot on its first
readable day, as identify judges its trials; --estimator NAME: that fit instead), with standard errors. Each
robot's first K days (default 5) are its baseline; a parameter the data determine that leaves its baseline on 3 or
more consecutive days, by more on average than the fleet's day-to-day scatter allows, has changed, and the change is
named: wear (a joint's friction), payload (a body on the last link), drive (one factor on a joint's torque) or other
(docs/fleet.md). A file that fails validation is listed as skipped, with the
reason, and the run goes on. Symbolic links under ROOT (a robot or day folder, a file) are not followed: each is
listed as skipped, and nothing outside ROOT is read.

Without --scheduler: a local cluster of --workers processes (default: the cores). With --scheduler tcp://host:8786:
an existing cluster (`dask scheduler`, `dask worker`), whose workers need ident-opt and the problem file and logs
at the same paths; a scheduler that does not answer within --connect-timeout (10 s), or an address where something
else listens (a web server), is an error (exit 2). Ctrl-C or SIGTERM to the process group ends the run in one line
(status 130 or 143), the local cluster's workers closed (`fleet.interrupts`).

--store PATH (or sqlite:///PATH; default DIR/fleet.db): what each file gave, kept between runs (`fleet.store`): a run
reads only the files the store does not hold (new, or changed since), and its result is a from-scratch run's. A
store written for another model (the problem file, --estimator, the loader's switches) is an error (exit 2).

Writes to --out (default: the problem's [output] dir, else results/): fleet.md, fleet_changes.csv,
fleet_series.csv and .parquet, changes.jsonl, metrics.prom, figures/fleet_overview.png (every robot's tested
parameters' latest z) and figures/fleet_<robot>.png (--figures new: each robot with a change its figure in --out
does not show yet, so that a day added redraws only what it changed; all: every robot; none); with --json the result of
`docs/cli.md` (fleet). Neither --out, --json nor --store may lie inside ROOT, however ROOT is given (a path,
relative, or a file:// URL): an error (exit 2) before any work.
"""

from __future__ import annotations

import argparse
import sys

from tqdm import tqdm

from ident_opt import outputs
from ident_opt.commands.common import (
    add_estimator_flag,
    add_problem_arguments,
    add_progress_flag,
    output_dir,
    problem_for,
)
from ident_opt.errors import InputError
from ident_opt.fleet import store as fleet_store
from ident_opt.fleet.engine import CONNECT_TIMEOUT_S
from ident_opt.fleet.layout import local_root
from ident_opt.fleet.run import run_fleet
from ident_opt.report import fleet as report


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """--problem, --logs, --out, --json, --store, --scheduler, --workers, --baseline-days, --figures, --estimator,
    --no-progress
    and the loader's switches."""
    add_problem_arguments(parser, data=False)
    parser.add_argument("--logs", required=True, metavar="ROOT", help="the fleet's logs: ROOT/robot=<id>/day=<date>/")
    parser.add_argument("--out", metavar="DIR", help="output folder (default: the problem's [output] dir)")
    parser.add_argument(
        "--store", metavar="PATH", help="what each file gave, kept between runs (default: DIR/fleet.db; sqlite:///PATH)"
    )
    parser.add_argument("--scheduler", metavar="ADDRESS", help="an existing Dask scheduler (default: a local cluster)")
    parser.add_argument("--workers", type=int, metavar="N", help="local cluster's worker processes (default: cores)")
    parser.add_argument(
        "--connect-timeout",
        type=float,
        default=CONNECT_TIMEOUT_S,
        metavar="S",
        help=f"seconds to wait for --scheduler to answer and have a worker ({CONNECT_TIMEOUT_S:g})",
    )
    parser.add_argument(
        "--baseline-days", type=int, default=5, metavar="K", help="each robot's first K days are its baseline (5)"
    )
    parser.add_argument(
        "--figures",
        choices=report.FIGURE_CHOICES,
        default="new",
        help="robots' figures drawn: new (a change not yet drawn in --out; default), all (every robot, ~1 s each), "
        "none (not even the fleet overview)",
    )
    add_estimator_flag(
        parser, "the fit of every robot-day", "each robot's recommended fit, judged on its first readable day"
    )
    add_progress_flag(parser)


def run(args: argparse.Namespace) -> int:
    """Check the flags, run the fleet on the cluster, write the reports, print the changes and the warnings."""
    problem = problem_for(args, "fleet")
    if args.scheduler and args.workers:
        raise InputError("--workers sets the local cluster's size; with --scheduler the cluster's own workers run")
    store = fleet_store.location(args.store) if args.store else None
    _outside(args, store)
    out = output_dir(args, problem)
    store = store or fleet_store.location(out / fleet_store.DEFAULT_NAME)  # inside --out: outside the logs too
    if args.json and store.path is not None and outputs.same_or_inside(args.json, store.path):
        raise InputError(f"--json {args.json}: is the store (--store {store.given}); write the JSON elsewhere")
    result = run_fleet(
        problem,
        args.logs,
        scheduler=args.scheduler,
        workers=args.workers,
        baseline_days=args.baseline_days,
        allow_implausible=args.allow_implausible,
        drop_invalid=args.drop_invalid,
        progress=not args.no_progress,
        connect_timeout=args.connect_timeout,
        estimator=args.estimator,
        store=store,
    )
    print(report.recommended_line(result), file=sys.stderr)

    def bar(due: list) -> tqdm:
        return tqdm(due, desc="fleet: figures", unit="robot", file=sys.stderr, disable=args.no_progress)

    report.write(result, out, args.json, _command(args), bar, args.figures)
    print(report.terminal(result, out, args.json))
    for warning in result.warnings:
        print(warning, file=sys.stderr)
    return 0


def _outside(args: argparse.Namespace, store: fleet_store.StoreLocation | None) -> None:
    """Before any work: --out, --json and the store must not lie inside the logs' local folder or be the archive
    they are read from, however --logs names them (a report there would overwrite a log, or be found in the next
    run's layout); they are then inputs of the run (`outputs.declare_inputs`), so that no output, the default --out
    included, is ever written inside them."""
    # The root folder, and any archive or file a chained URL's other parts read (zip://…::file:///data/fleet.zip).
    parts = [args.logs, *args.logs.split("::")[1:]] if "::" in args.logs else [args.logs]
    read = [root for root in map(local_root, parts) if root is not None and root.exists()]
    for root in read:
        for flag, path in (("--out", args.out), ("--json", args.json), ("--store", store and store.path)):
            if path and outputs.same_or_inside(path, root):
                raise InputError(f"{flag} {path}: inside --logs {args.logs} ({root}); write the reports elsewhere")
    outputs.declare_inputs(read)  # not on this machine (an object store, memory://): `layout.discover` says so


def _command(args: argparse.Namespace) -> str:
    """The command line, rebuilt from the parsed flags (for fleet.md)."""
    parts = ["ident-opt fleet", f"--problem {args.problem}", f"--logs {args.logs}"]
    parts += [f"--out {args.out}"] if args.out else []
    parts += [f"--store {args.store}"] if args.store else []
    parts += [f"--scheduler {args.scheduler}"] if args.scheduler else []
    parts += [f"--workers {args.workers}"] if args.workers else []
    parts += [f"--baseline-days {args.baseline_days}"] if args.baseline_days != 5 else []
    parts += [f"--estimator {args.estimator}"] if args.estimator else []
    return " ".join(parts)
