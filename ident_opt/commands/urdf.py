"""The URDF-arm paths of `ident-opt compare` and `ident-opt codegen` (a problem whose [robot] has `urdf`).

Not a subcommand of its own: `compare` and `codegen` hand a URDF problem to these functions.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ident_opt.commands.common import output_dir
from ident_opt.errors import InputError


def urdf_problem(args: argparse.Namespace):
    """The problem of `--problem` when the paper's identify pipeline does not serve its arm, else None."""
    from ident_opt.problem import load_problem  # deferred: it loads the effect catalogue; --help must stay fast

    problem = load_problem(args.problem)
    return None if problem.robot.paper_views else problem


def trial_paths(args: argparse.Namespace, problem) -> tuple[list[Path], list[Path]]:
    """(training, held-out) files, as every command reads them: every --data trains and every --test-data is
    held out; without --data the problem's [data] decides (`train`/`test`, or `trials`: the first trains, the
    second is held out)."""
    data = [Path(p) for p in (getattr(args, "data", None) or [])]
    test = [Path(p) for p in (getattr(args, "test_data", None) or [])]
    if not data:
        data, test = list(problem.data.training), test or list(problem.data.testing)
    if not data:
        raise InputError(f"{problem.path}: no data: give --data D or list trials under [data] in the problem file")
    return data, test


def identify(args: argparse.Namespace, problem) -> int:
    """Every estimator on all the problem's trials (or --data): identify.md and identify.json."""
    from ident_opt.report import urdf as report  # deferred: NumPy, Pinocchio, CasADi, cvxpy
    from ident_opt.studies import urdf as study

    paths, _ = trial_paths(args, problem)
    trials = study.load_trials(paths, problem, allow_implausible=args.allow_implausible, drop_invalid=args.drop_invalid)
    result = study.identify(problem, trials, weights=None if getattr(args, "weights", "ols") == "ols" else "wls")
    out = output_dir(args, problem)
    path = report.write_identify(result, out, getattr(args, "json", None))
    masses = {name: m["total"] for name, m in result["mass"].items() if name != "ols"}
    print(
        f"{result['problem']}: {result['base']['count']} base parameters, {result['samples']} samples; total mass [kg] "
        + ", ".join(f"{k} {v:.2f}" for k, v in masses.items())
    )
    print(f"wrote {path.name} and identify.json to {out.resolve()}")
    return 0
