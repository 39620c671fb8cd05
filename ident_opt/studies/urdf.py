"""The comparison on an n-joint arm from a URDF: OLS on the base parameters, the plain consistent fit, the
plausible consistent fit (the default) and the URDF's CAD inertials, scored on held-out data.

Split: the test trials when given (`cross_trial`: another recording), else each trial's first
`train_fraction` in time trains and the rest tests (`chronological`). Everything is fitted from the
training statistics (`identify.stats.Stats`). Returned as one JSON-ready dict (`docs/cli.md`):

- `parameters.<estimator>`: standard parameters by name (`ident_opt.arm.chain`); `base_parameters.ols`:
  each base parameter's value, SE and definition (`identify.base`);
- `metrics.<protocol>.<estimator>`: held-out `rmse` [N m] and `nmse` per joint (by URDF joint name);
- `consistency.<estimator>`: each link's pseudo-inertia λ_min [kg m²], the active constraints;
- `mass.<estimator>`: total and per-link masses [kg] next to the URDF's (`mass.urdf`);
- `base`: the number of base parameters, the rank tolerance, the condition number on the training data.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np

from ident_opt import metrics
from ident_opt.arm.chain import ChainArm
from ident_opt.arm.rnea import N_LINK
from ident_opt.data import Dataset, chronological_split, load_dataset
from ident_opt.errors import InputError
from ident_opt.identify.base import BaseFit, base_parameters, fit_base_ols
from ident_opt.identify.constrained import fit_constrained
from ident_opt.identify.fit import LinearFit
from ident_opt.identify.physical import fit_physical
from ident_opt.identify.stats import Stats

#: The estimators of the comparison, in report order.
ESTIMATORS = ("ols", "constrained", "consistent", "cad")
#: What each is, for the report.
MEANING = {
    "ols": "least squares on the base parameters (dependent standard parameters set to 0)",
    "constrained": "consistent least squares: every pseudo-inertia ⪰ 0, friction and armature ≥ 0, no prior",
    "consistent": "the default: consistent, CAD mass range and centre-of-mass box, log-det prior to the URDF",
    "cad": "the URDF's CAD inertials, no friction, armature or offsets",
}
#: A pseudo-inertia whose λ_min is below this [kg m²] is reported active (the constrained fit's margin is 1e-6).
ACTIVE_EIGENVALUE = 1e-5
_JOINT_COLUMN = re.compile(r"(q|dq|ddq|tau|i)(\d+)")


def load_trials(paths: list[Path], problem, **options) -> list[Dataset]:
    """The trials at `paths` for a URDF problem; InputError naming the file when its joint count is not the arm's."""
    n = problem.robot.n_joints
    trials = []
    for path in paths:
        trial = load_dataset(path, problem.data, problem.robot, **options)
        extra = [int(m.group(2)) for c in trial.extra.columns if (m := _JOINT_COLUMN.fullmatch(str(c)))]
        if extra and max(extra) > n:
            raise InputError(
                f"{path}: the data have joint columns up to joint {max(extra)}, the URDF arm {problem.robot.urdf} "
                f"has {n} joints ({', '.join(problem.robot.joint_names)})"
            )
        trials.append(trial)
    return trials


def split(trials: list[Dataset], test: list[Dataset], train_fraction: float) -> tuple[str, list, list]:
    """(protocol, training sets, test sets): the test trials if any, else a time split of every trial."""
    if test:
        return "cross_trial", trials, test
    train, held = [], []
    for trial in trials:
        first, rest = chronological_split(trial.n, train_fraction)
        train.append(trial.subset(first))
        held.append(trial.subset(rest))
    return "chronological", train, held


def stats_of(arm: ChainArm, trials: list[Dataset]) -> Stats:
    """The sufficient statistics of the arm's regressor over the trials."""
    total = Stats.zeros(arm.n_params, arm.n_joints)
    for trial in trials:
        total += Stats.from_data(arm, trial.q, trial.dq, trial.ddq, trial.tau, chunk=4096)  # Y: 4096 × n × P
    return total


def _consistency(arm: ChainArm, pi: np.ndarray, fit: LinearFit | None) -> dict:
    """Each link's pseudo-inertia λ_min [kg m²], whether all are ≥ 0 and the signs hold, which are active
    (0 ≤ λ_min < `ACTIVE_EIGENVALUE`) and which violated (λ_min < 0), the fit's active constraints."""
    lam = np.linalg.eigvalsh(arm.pseudo_inertias(pi))[:, 0]
    return {
        "pseudo_inertia_min_eigenvalue": dict(zip(arm.links, lam.tolist())),
        "consistent": bool(lam.min() >= 0 and (fit is None or not fit.sign_violations)),
        "active_pseudo_inertias": [link for link, v in zip(arm.links, lam) if 0 <= v < ACTIVE_EIGENVALUE],
        "violated_pseudo_inertias": [link for link, v in zip(arm.links, lam) if v < 0],
        "active": list(fit.active) if fit is not None else [],
    }


def fit_all(robot, stats: Stats, weights: str | None = None) -> tuple[dict, dict, BaseFit, dict]:
    """(fits, π, the base OLS fit, seconds) of every estimator (`ESTIMATORS`) from the statistics."""
    arm: ChainArm = robot.arm
    fits: dict[str, LinearFit | None] = {}
    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    base_fit = fit_base_ols(stats, arm, weights=weights)
    seconds["ols"] = time.perf_counter() - t0
    fits["ols"] = base_fit.fit
    pis = {"ols": base_fit.pi}
    t0 = time.perf_counter()
    fits["constrained"] = fit_constrained(stats, arm, weights=weights)
    seconds["constrained"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    fits["consistent"] = fit_physical(
        stats,
        arm,
        prior_weight=robot.prior_weight,
        mass_range=robot.mass_range,
        com_box=robot.com_box,
        weights=weights,
    )
    seconds["consistent"] = time.perf_counter() - t0
    pis.update(constrained=fits["constrained"].pi, consistent=fits["consistent"].pi, cad=arm.cad_parameters())
    fits["cad"] = None
    return fits, pis, base_fit, seconds


def summary(problem, fits: dict, pis: dict, base_fit: BaseFit) -> dict:
    """What both the comparison and the identification report: the robot, base parameters, each estimator's
    standard parameters (and SEs), consistency and masses against the URDF's."""
    robot = problem.robot
    arm: ChainArm = robot.arm
    urdf_masses = arm.link_masses(pis["cad"])
    return {
        "problem": problem.name,
        "robot": {
            "urdf": str(robot.urdf),
            "joints": list(robot.joint_names),
            "links": list(arm.links),
            "n_params": arm.n_params,
            "gravity": list(robot.gravity),
        },
        "base": {
            "count": base_fit.base.rank,
            "rank_tolerance": base_fit.base.tolerance,
            "random_states": base_fit.base.n_states,
            "condition_number": base_fit.fit.cond,
            "rank_on_training_data": base_fit.fit.rank,
        },
        "estimators": {name: MEANING[name] for name in ESTIMATORS},
        "prior": {"weight": robot.prior_weight, "mass_range": robot.mass_range, "com_box_m": robot.com_box},
        "parameters": {name: arm.as_dict(pi) for name, pi in pis.items()},
        "se": {name: fit.se_dict() for name, fit in fits.items() if fit is not None and name != "ols"},
        "base_parameters": {"ols": base_fit.summary()},
        "ols_impossible_base_values": impossible_base_values(arm, base_fit),
        "consistency": {name: _consistency(arm, pi, fits[name]) for name, pi in pis.items()},
        "mass": {
            "urdf": {"total": sum(urdf_masses.values()), "links": urdf_masses},
            **{
                name: {"total": sum(arm.link_masses(pi).values()), "links": arm.link_masses(pi)}
                for name, pi in pis.items()
                if name != "cad"
            },
        },
    }


def _scores(arm: ChainArm, joints: tuple[str, ...], pis: dict, sets: list[Dataset]) -> dict:
    """rmse [N m] and nmse per joint of every π on the data sets."""
    tau = np.concatenate([t.tau for t in sets])
    q, dq, ddq = (np.concatenate([getattr(t, a) for t in sets]) for a in ("q", "dq", "ddq"))
    Y = arm.regressor(q, dq, ddq)
    out = {}
    for name, pi in pis.items():
        hat = Y @ pi
        out[name] = {
            "rmse": dict(zip(joints, metrics.rmse(tau, hat).tolist())),
            "nmse": dict(zip(joints, metrics.nmse(tau, hat).tolist())),
        }
    return out


def run(problem, trials: list[Dataset], test: list[Dataset], weights: str | None = None) -> dict:
    """The comparison of the module doc for a URDF problem; returns the JSON-ready result."""
    robot = problem.robot
    arm: ChainArm = robot.arm
    protocol, train, held = split(trials, test, problem.split.train_fraction)
    t0 = time.perf_counter()
    stats = stats_of(arm, train)
    stats_seconds = time.perf_counter() - t0
    fits, pis, base_fit, seconds = fit_all(robot, stats, weights)
    scores = _scores(arm, robot.joint_names, pis, held)
    return {
        **summary(problem, fits, pis, base_fit),
        "split": {
            "protocol": protocol,
            "train": [t.source for t in trials],
            "test": [t.source for t in test] if test else [f"last {1 - problem.split.train_fraction:.0%} of each"],
            "train_samples": int(stats.n),
            "test_samples": sum(t.n for t in held),
        },
        "metrics": {protocol: scores},
        "within_10_percent_of_ols": _within(scores, robot.joint_names),
        "seconds": {"statistics": stats_seconds, **seconds},
    }


def identify(problem, trials: list[Dataset], weights: str | None = None) -> dict:
    """Every estimator on all the trials (no held-out data): parameters, SEs, base parameters, consistency,
    masses, and the in-sample rmse/nmse per joint (`metrics.fit`)."""
    robot = problem.robot
    arm: ChainArm = robot.arm
    stats = stats_of(arm, trials)
    fits, pis, base_fit, seconds = fit_all(robot, stats, weights)
    return {
        **summary(problem, fits, pis, base_fit),
        "trials": [t.source for t in trials],
        "samples": int(stats.n),
        "metrics": {"fit": _scores(arm, robot.joint_names, pis, trials)},
        "seconds": seconds,
    }


def check_summary(problem) -> dict:
    """What `ident-opt check` reports of a URDF problem's robot (JSON-ready): the file, its joints and moving
    links, gravity [m/s²], the joint terms and couplings, the number of standard and base parameters, and the
    URDF's total mass [kg] (None when a link has no <inertial>, which `missing_inertials` names)."""
    robot = problem.robot
    arm: ChainArm = robot.arm  # builds Pinocchio's model: a URDF fault shows here, naming the element
    mass = None if arm.missing_inertials else sum(arm.link_masses(arm.cad_parameters()).values())
    return {
        "urdf": str(robot.urdf),
        "joints": list(robot.joint_names),
        "links": list(arm.links),
        "gravity": list(robot.gravity),
        "joint_terms": list(arm.joint_terms),
        "couplings": [list(c) for c in robot.couplings],
        "parameters": arm.n_params,
        "base_parameters": base_parameters(arm).rank,
        "urdf_mass_kg": mass,
        "missing_inertials": list(arm.missing_inertials),
    }


def check_lines(problem, robot: dict) -> list[str]:
    """`check_summary` as the lines `ident-opt check` prints before the trials."""
    n = len(robot["joints"])
    terms = ", ".join(robot["joint_terms"]) or "none"
    mass = (
        f"{robot['urdf_mass_kg']:.3f} kg"
        if robot["urdf_mass_kg"] is not None
        else f"unknown: no <inertial> on {', '.join(robot['missing_inertials'])}"
    )
    lines = [
        f"problem {problem.name!r} ({problem.path}): {n}-joint arm from the URDF {robot['urdf']}",
        f"  joints: {', '.join(robot['joints'])}",
        f"  gravity [m/s²]: ({', '.join(f'{g:g}' for g in robot['gravity'])})",
        f"  parameters: {robot['parameters']} standard ({N_LINK} per link, joint terms: {terms}), "
        f"{robot['base_parameters']} base",
        f"  URDF mass of the moving links: {mass}",
    ]
    lines += [f"  coupling: drive {a} also acts on {b} (ratio {r:g})" for a, b, r in robot["couplings"]]
    return lines


def necessarily_nonnegative(arm: ChainArm, K: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """For each row k of K (B, P): is K_k · π ≥ 0 for every consistent π (pseudo-inertias ⪰ 0, friction and
    armature ≥ 0)? The consistent set is a cone, so that holds exactly when K_k is in its dual: on each link,
    the symmetric S_i with K_k,i · π_i = tr(S_i J_i(π_i)) is ⪰ 0 (the 10 pseudo-inertia maps span the 4×4
    symmetric matrices); on the joint terms, coefficients ≥ 0 for friction and armature, 0 for the others."""
    A = arm.pseudo_inertia_map()
    rows, cols = np.triu_indices(4)
    scale = np.where(rows == cols, 1.0, 2.0)  # tr(S A) = Σ_upper scale · S_rc A_rc
    basis = A[:, rows, cols] * scale  # (10, 10): K_p = basis[p] · upper(S)
    L = arm.n_link_params
    signed = np.array([p.kind in ("friction", "armature") for p in arm.parameters[L:]])
    out = []
    for k in K:
        ok = bool(np.all(k[L:][signed] >= -tol) and np.all(np.abs(k[L:][~signed]) <= tol))
        for i in range(arm.n_joints):
            upper = np.linalg.solve(basis, k[N_LINK * i : N_LINK * (i + 1)])
            S = np.zeros((4, 4))
            S[rows, cols] = upper
            S = S + np.triu(S, 1).T
            ok = ok and np.linalg.eigvalsh(S)[0] >= -tol * max(1.0, np.abs(S).max())
        out.append(ok)
    return np.array(out)


def impossible_base_values(arm: ChainArm, base_fit) -> dict[str, dict]:
    """The OLS base parameters that no consistent arm can have negative, yet are negative: name → value, SE,
    and how many SE below 0. What a consistent fit cannot follow (module doc of `identify.physical`)."""
    base = base_fit.base
    sign_definite = necessarily_nonnegative(arm, base.K)
    out = {}
    for name, definite, value, se in zip(base.names, sign_definite, base_fit.fit.pi, base_fit.fit.se):
        if definite and value < 0:
            out[name] = {"value": float(value), "se": float(se), "se_below_zero": float(-value / max(se, 1e-300))}
    return out


def _within(scores: dict, joints: tuple[str, ...]) -> dict:
    """Per joint: is OLS better than the CAD prior, and is the consistent fit's RMSE within 10 % of OLS's?"""
    out = {}
    for j in joints:
        ols, cad, con = (scores[k]["rmse"][j] for k in ("ols", "cad", "consistent"))
        out[j] = {"ols_better_than_cad": ols < cad, "ratio_to_ols": con / ols, "within": con <= 1.1 * ols}
    return out
