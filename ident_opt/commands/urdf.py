"""The URDF-arm paths of `ident-opt compare` and `ident-opt codegen` (a problem whose [robot] has `urdf`).

Not a subcommand of its own: `compare` and `codegen` hand a URDF problem to these functions.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ident_opt import outputs
from ident_opt.arm.chain import ChainRobot
from ident_opt.commands.common import output_dir
from ident_opt.errors import InputError


def urdf_problem(args: argparse.Namespace):
    """The problem of `--problem` when its robot is an arm from a URDF (these paths apply), else None."""
    from ident_opt.problem import load_problem  # deferred: it loads the effect catalogue; --help must stay fast

    problem = load_problem(args.problem)
    return problem if isinstance(problem.robot, ChainRobot) else None


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


def compare(args: argparse.Namespace, problem) -> int:
    """OLS on base parameters, consistent, plausible and CAD fits, scored on --test-data (or a time split)."""
    from ident_opt.report import urdf as report  # deferred: NumPy, Pinocchio, CasADi, cvxpy
    from ident_opt.studies import urdf as study

    options = {"allow_implausible": args.allow_implausible, "drop_invalid": args.drop_invalid}
    paths, held = trial_paths(args, problem)
    trials = study.load_trials(paths, problem, **options)
    test = study.load_trials(held, problem, **options)
    weights = None if getattr(args, "weights", "ols") == "ols" else "wls"
    result = study.run(problem, trials, test, weights=weights)
    out = output_dir(args, problem)
    path = report.write(result, out, getattr(args, "json", None))
    print(report.terminal(result))
    print(f"wrote {path.name} and compare.json to {out.resolve()}")
    return 0


#: codegen's checks: the compiled tau_hat against the Python model (relative, per sample) and ddq_hat's
#: normwise backward error.
CODEGEN_TOLERANCE = {"tau_hat": 1e-9, "ddq_hat": 1e-9}


def codegen(args: argparse.Namespace, problem) -> int:
    """Fit the chosen estimator on the problem's trials, generate tau_hat (and ddq_hat) for the n joints, compile,
    load back and check against the Python model; parameters.json holds π by name. 0 when they agree, 1 if not."""
    import numpy as np  # deferred: NumPy, Pinocchio, CasADi, cvxpy

    from ident_opt import codegen as cg
    from ident_opt.identify.base import fit_base_ols
    from ident_opt.identify.constrained import fit_constrained
    from ident_opt.identify.physical import fit_physical
    from ident_opt.report import write_json
    from ident_opt.studies import urdf as study

    robot = problem.robot
    arm = robot.arm
    out = output_dir(args, problem)
    compiler = cg.find_compiler()
    paths, _ = trial_paths(args, problem)
    trials = study.load_trials(paths, problem, allow_implausible=args.allow_implausible, drop_invalid=args.drop_invalid)
    stats = study.stats_of(arm, trials)
    estimator = getattr(args, "estimator", None) or "consistent"
    if estimator == "ols":
        pi = fit_base_ols(stats, arm).pi
    elif estimator == "constrained":
        pi = fit_constrained(stats, arm).pi
    else:
        estimator = "consistent"
        pi = fit_physical(
            stats, arm, prior_weight=robot.prior_weight, mass_range=robot.mass_range, com_box=robot.com_box
        ).pi
    forward = not getattr(args, "no_forward", False)
    written = [f"{cg.NAME}.c", f"{cg.NAME}.h", cg.library_name(), "README.md", "parameters.json"]
    outputs.guard_owned(out, written, force=getattr(args, "force", False))  # the output rules of every command
    functions = cg.build_functions(arm, pi, forward=forward)
    source, header = cg.generate_sources(functions, out)
    library = cg.compile_library(source, out, compiler)
    readme = cg.write_readme(out, functions)
    rng = np.random.default_rng(0)
    q = np.concatenate([trials[0].q[:200], rng.uniform(-np.pi, np.pi, (200, arm.n_joints))])
    dq = np.concatenate([trials[0].dq[:200], rng.uniform(-2, 2, (200, arm.n_joints))])
    ddq = np.concatenate([trials[0].ddq[:200], rng.uniform(-5, 5, (200, arm.n_joints))])
    tau = arm.predict(pi, q, dq, ddq)
    errors = {"tau_hat": cg.relative_error(cg.evaluate(cg.load_external(library, "tau_hat"), q, dq, ddq), tau)}
    if forward:
        ddq_hat = cg.evaluate(cg.load_external(library, "ddq_hat"), q, dq, tau)
        errors["ddq_hat"] = cg.forward_backward_error(arm, pi, q, dq, tau, ddq_hat)
    payload = {
        "problem": problem.name,
        "urdf": str(robot.urdf),
        "joints": list(robot.joint_names),
        "estimator": estimator,
        "parameters": arm.as_dict(pi),
        "functions": [f.name() for f in functions],
        "check": errors,
        "trials": [t.source for t in trials],
    }
    write_json(out / "parameters.json", payload)
    write_json(getattr(args, "json", None), payload)
    outputs.remember_owned(out, written)  # a later run may overwrite what this one wrote
    names = ", ".join(p.name for p in (source, header, library, readme))
    print(f"ident-opt codegen: {arm.n_joints} joints, {arm.n_params} parameters ({estimator}); wrote {names}")
    print("check against Python: " + ", ".join(f"{k} {v:.2g}" for k, v in errors.items()))
    bad = {k: v for k, v in errors.items() if not v <= CODEGEN_TOLERANCE[k]}
    if bad:
        print(f"ident-opt codegen: the compiled code disagrees with the Python model: {bad}", file=sys.stderr)
        return 1
    return 0


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
