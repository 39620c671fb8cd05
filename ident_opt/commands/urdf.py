"""The URDF-arm paths of `ident-opt compare` and `ident-opt codegen` (a problem whose [robot] has `urdf`).

Not a subcommand of its own: `compare` and `codegen` hand a URDF problem to these functions.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ident_opt.commands.common import output_dir
from ident_opt.errors import InputError


def compare(args: argparse.Namespace, problem) -> int:
    """OLS on base parameters, consistent, plausible and CAD fits, scored on --test-data (or a time split)."""
    from ident_opt.report import urdf as report  # deferred: NumPy, Pinocchio, CasADi, cvxpy
    from ident_opt.studies import urdf as study

    options = {"allow_implausible": args.allow_implausible, "drop_invalid": args.drop_invalid}
    paths = [Path(p) for p in (getattr(args, "data", None) or [])] or list(problem.data.trials)
    if not paths:
        raise InputError(f"{problem.path}: no data: give --data D or list trials under [data] in the problem file")
    trials = study.load_trials(paths, problem, **options)
    test = study.load_trials([Path(p) for p in (getattr(args, "test_data", None) or [])], problem, **options)
    weights = None if getattr(args, "weights", "ols") == "ols" else "wls"
    result = study.run(problem, trials, test, weights=weights)
    out = output_dir(args, problem)
    path = report.write(result, out, getattr(args, "json", None))
    print(report.terminal(result))
    print(f"wrote {path.name} and compare.json to {out.resolve()}")
    return 0
