"""Nonlinear identification with CasADi + IPOPT.

Two tools:

- `fit_expression` (`ident_opt.numerics.nlp`): the generic "fit these parameters of this CasADi expression to this
  data" (bounded nonlinear least squares), for effects that are not linear in their parameters.
- `fit_physical`: identify the *physical* parameters (masses, centres of mass, inertias, armature,
  friction) within physical bounds; π follows from them through `datasheet.grouped`, so the result is
  physically consistent by construction (friction and other sign-constrained parameters kept ≥ 0 from
  their declared kinds, `consistency.sign_constraints`). Works from the sufficient statistics: the
  objective Σ_j RSS_j(π(θ)) = π(θ)ᵀHπ(θ) − 2hᵀπ(θ) + s costs nothing per sample.
"""

from __future__ import annotations

import time

import casadi as ca
import numpy as np

from ident_opt.arm.datasheet import grouped, rigid_body
from ident_opt.arm.planar import PlanarArm
from ident_opt.consistency import sign_constraints
from ident_opt.fitting.fit import LinearFit, check_stats, finish, joint_weights, normal_equations
from ident_opt.fitting.stats import Stats
from ident_opt.numerics.nlp import _solve_nlp

PHYSICAL_INERTIAL = ("m1", "m2", "lc1", "lc2", "Ic1", "Ic2", "ia1", "ia2")


def physical_start(robot, model: PlanarArm) -> tuple[dict[str, float], dict[str, tuple[float, float]]]:
    """Datasheet start values (physical convention) and physical bounds for every parameter θ.

    Masses ≥ 1 g, centres of mass on their link (0 ≤ lc ≤ l), inertias and armatures ≥ 0; the other
    parameters ≥ 0 when their kind is sign-constrained (friction, armature), else unbounded (e.g. offsets).
    """
    body = rigid_body(robot, "physical")
    inf = np.inf
    theta = {  # name: (datasheet value, (lower, upper))
        "m1": (body.m1, (1e-3, inf)),
        "m2": (body.m2, (1e-3, inf)),
        "lc1": (body.lc1, (0.0, body.l1)),
        "lc2": (body.lc2, (0.0, body.l2)),
        "Ic1": (body.Ic1, (0.0, inf)),
        "Ic2": (body.Ic2, (0.0, inf)),
        "ia1": (body.armature[0], (0.0, inf)),
    }
    if "ia2" in model.names:  # without the armature extension a joint-2 armature cannot be represented
        theta["ia2"] = (body.armature[1], (0.0, inf))
    sheet = {}
    for j, k in enumerate(("1", "2")):
        sheet |= {f"fv{k}": body.fv[j], f"fc{k}": body.fc[j]}
        sheet |= {f"fc{k}p": body.fc_positive[j], f"fc{k}n": body.fc_negative[j]}
    nonnegative = {model.names[c.index] for c in sign_constraints(model.parameters)}
    for name in model.names:
        if name not in ("a1", "a2", "a3", "b1", "b2", "ia2"):
            theta[name] = (sheet.get(name, 0.0), (0.0, inf) if name in nonnegative else (-inf, inf))
    return {k: v for k, (v, _) in theta.items()}, {k: b for k, (_, b) in theta.items()}


def pi_of_physical(theta: dict, robot, model: PlanarArm) -> list:
    """π(θ) in the model's order, through `datasheet.grouped` (works on numbers and CasADi symbols)."""
    l1, g = robot.link1.length, robot.gravity
    a1, a2, a3, b1, b2 = grouped(
        theta["m1"], theta["m2"], l1, theta["lc1"], theta["lc2"], theta["Ic1"], theta["Ic2"], g
    )
    inertial = {"a1": a1 + theta["ia1"], "a2": a2, "a3": a3, "b1": b1, "b2": b2}
    return [inertial[n] if n in inertial else theta[n] for n in model.names]


def fit_physical(
    source: Stats | object,
    robot,
    model: PlanarArm | None = None,
    *,
    prior_weight: float = 1e-6,
    weights: str | np.ndarray | None = None,
    options: dict | None = None,
) -> LinearFit:
    """Physical parameters θ (m [kg], lc [m], Ic and armature [kg m²], friction) by IPOPT, π = π(θ).

    `source` is a `Stats` (for `model`) or a Dataset (statistics are computed from it). The grouped π
    do not determine every physical parameter (e.g. m1, lc1, Ic1 give only a1 and b1), so a weak pull
    toward the datasheet, prior_weight · Σ ((θ − θ_sheet)/θ_scale)² per sample, picks one of the
    equivalent solutions; at the default weight it changes π by far less than its standard errors.
    Returns a `LinearFit` (method "nlp_physical") whose `details["physical"]` holds θ by name.
    """
    model = model or PlanarArm()
    stats = source if isinstance(source, Stats) else Stats.from_data(model, source.q, source.dq, source.ddq, source.tau)
    check_stats(stats, model)
    w = joint_weights(stats, weights)
    H, h = normal_equations(stats, w)
    start, bounds = physical_start(robot, model)
    names = tuple(start)
    theta = ca.SX.sym("theta", len(names))
    sym = {n: theta[i] for i, n in enumerate(names)}
    pi = ca.vertcat(*pi_of_physical(sym, robot, model))
    n = max(stats.n, 1)
    x0 = np.array([start[k] for k in names])
    scale = np.maximum(np.abs(x0), 1e-3)
    data_term = (ca.dot(pi, ca.DM(H) @ pi) - 2 * ca.dot(ca.DM(h), pi) + float(w @ stats.s)) / n
    prior_term = prior_weight * ca.sumsqr((theta - ca.DM(x0)) / ca.DM(scale))
    lb = np.array([bounds[k][0] for k in names])
    ub = np.array([bounds[k][1] for k in names])
    t0 = time.perf_counter()
    x, _, st = _solve_nlp(theta, data_term + prior_term, np.clip(x0, lb, ub), lb, ub, options=options)
    elapsed = time.perf_counter() - t0
    # IPOPT may relax bounds by ~1e-8; put the answer back inside them (θ is physical only inside).
    values = dict(zip(names, (float(v) for v in np.clip(x, lb, ub))))
    pi_hat = np.array(pi_of_physical(values, robot, model), dtype=float)
    fit = finish(stats, model, pi_hat, w, "nlp_physical", st["return_status"], [], elapsed)
    fit.details["physical"] = values
    fit.details["at_bound"] = [
        k for k in names if min(values[k] - bounds[k][0], bounds[k][1] - values[k]) < 1e-6 * max(1.0, abs(values[k]))
    ]
    return fit
