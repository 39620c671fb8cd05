"""Nonlinear polish with CasADi + IPOPT after the variable-projection search (`linear.search`).

The search is the global initialiser: a grid over the nonlinear parameters θ with the linear coefficients
β solved exactly at each point, then a bounded scalar refinement per coordinate. It is the right tool
against local minima; IPOPT then refines where a joint, gradient-based step can add something:

- Stribeck (`stribeck`): vs enters nonlinearly. IPOPT moves (fs_j, vs_j) jointly, per joint, with every
  other coefficient held. Only samples where joint j moves are used: at rest the Stribeck term is zero
  (dq = 0) and the rest stretches' projection does not touch them, so this is exactly the candidate's
  objective restricted to (fs_j, vs_j).
- Elasticity (`elastic_nlp.polish`): the mode (f, ζ) jointly with every β, by multiple shooting.
- Joint offsets (`offsets`): (δ1, δ2) jointly with π (the search refines them one at a time).
- Delay: no IPOPT polish, on purpose. The delay is already a continuous parameter (the prediction is
  delayed by linear interpolation between samples, `signals.delayed`, i.e. the torque channel interpolated),
  and with β solved exactly at every d the objective is a function of d alone, which the bounded Brent
  refinement minimises to 1e-4 of the 0.15 s search range (15 µs, far below the 2 ms tolerance). A joint
  (d, β) NLP has the same minimiser, and linear interpolation makes the objective's derivative jump at
  every whole-sample delay, which gradient-based IPOPT handles worse than Brent's bracketing.

IPOPT sees at most `POLISH_ROWS` samples (evenly strided: CasADi builds the expression graph per sample, so
a 2 kHz trial would otherwise cost seconds just to set up). Every polish is kept only if it lowers the
candidate's objective on all training samples (`candidates.fit` re-solves β exactly at the polished θ).
"""

from __future__ import annotations

import numpy as np

#: Most samples an IPOPT polish is set up on (per joint for Stribeck).
POLISH_ROWS = 6000


def stribeck(
    rest: np.ndarray,
    dq: np.ndarray,
    tau: np.ndarray,
    offset: np.ndarray,
    X: np.ndarray,
    names: list[str],
    beta: np.ndarray,
    theta: dict,
) -> tuple[np.ndarray, dict, list[str]]:
    """(β, θ, IPOPT statuses) with (fs_j, vs_j) polished; inputs as in `candidates.fit` (training part)."""
    import casadi as ca

    from ident_opt.identify.nlp import fit_expression

    beta, theta, statuses = beta.copy(), dict(theta), []
    fs, vs, v = ca.SX.sym("fs"), ca.SX.sym("vs"), ca.SX.sym("dq")
    expr = fs * ca.sign(v) * ca.exp(-((v / vs) ** 2))  # N m, the excess over the Coulomb level
    f = ca.Function("stribeck", [v, fs, vs], [expr])
    for j in range(2):
        k = names.index(f"fs{j + 1}")
        moving = rest[:, j] < 0
        if moving.sum() < 10:
            continue
        others = beta.copy()
        others[k] = 0.0
        target = (tau[:, j] - offset[:, j] - X[:, j, :] @ others)[moving]
        x0 = [beta[k], theta[f"vs{j + 1}"]]
        every = max(1, int(moving.sum()) // POLISH_ROWS)

        def cost(p, target=target, moving=moving, j=j):
            pred = np.array(f(dq[moving, j][None, :], p[0], p[1])).ravel()
            return float(np.sum((target - pred) ** 2))

        fit = fit_expression(
            expr,
            ca.vertcat(fs, vs),
            [v],
            [dq[moving, j][::every]],
            target[::every],
            x0=x0,
            lb=[0.0, 0.002],
            ub=[np.inf, 1.0],
            names=[f"fs{j + 1}", f"vs{j + 1}"],
            options={"ipopt.max_iter": 100},
        )
        statuses.append(f"joint {j + 1}: {fit.status}")
        if fit.success and cost(fit.values) < cost(x0):
            beta[k], theta[f"vs{j + 1}"] = float(fit.values[0]), float(fit.values[1])
    return beta, theta, statuses


def offsets(
    model,
    q: np.ndarray,
    dq: np.ndarray,
    ddq: np.ndarray,
    tau: np.ndarray,
    labels: np.ndarray,
    weights: np.ndarray,
    pi_fixed: np.ndarray | None,
    beta: np.ndarray,
    theta: dict,
    bounds: tuple[float, float],
) -> tuple[dict | None, dict]:
    """IPOPT on the encoder offsets (δ1, δ2) jointly with π (rigid_fit; `pi_fixed` None) or with the
    datasheet π held (`pi_fixed`): the candidate's objective, Σ_j w_j |demean_runs(τ_j − τ̂_j(q + δ))|².

    The search moves δ1 and δ2 one at a time (grid sweeps, then a Brent refinement per coordinate); gravity
    couples them (b2 cos(q1 + q2 + δ1 + δ2) sees their sum), so a joint step can still lower the cost. The
    model is smooth in δ (sines and cosines), so IPOPT (exact Hessian) is cheap here. Returns (θ or None,
    info); the caller re-solves π exactly at the new δ and keeps it only if the training objective drops."""
    import time

    import casadi as ca

    from ident_opt.diagnose.elastic_nlp import demean_mx
    from ident_opt.identify.nlp import IPOPT_QUIET

    t0 = time.perf_counter()
    every = max(1, -(-len(q) // POLISH_ROWS))
    q, dq, ddq, tau, labels = (a[::every] for a in (q, dq, ddq, tau, labels))
    if every > 1:
        from ident_opt.diagnose.signals import rest_runs

        labels = rest_runs(np.where(labels >= 0, 0.0, 1.0))
    n, k = len(q), len(beta)
    delta = ca.MX.sym("delta", 2)
    # π on unit-norm columns (as `linear.solve`): they differ by orders of magnitude (inertias vs gravity).
    scale = np.ones(0)
    if pi_fixed is None:
        Y = model.regressor(q + np.array([theta["delta1"], theta["delta2"]]), dq, ddq)
        scale = 1.0 / np.maximum(np.sqrt(np.einsum("njk,j->k", Y**2, weights)), 1e-300)
    bs = ca.MX.sym("b", k if pi_fixed is None else 0)
    pi = bs * ca.DM(scale) if pi_fixed is None else ca.DM(pi_fixed)
    f = model.function("tau").map(n)
    pred = f(ca.DM(q.T) + ca.repmat(delta, 1, n), ca.DM(dq.T), ca.DM(ddq.T), ca.repmat(pi, 1, n))  # 2 × n
    objective = 0
    for j in range(2):
        r = demean_mx(ca.DM(tau[:, j]) - pred[j, :].T, labels[:, j])
        objective = objective + float(weights[j]) * ca.sumsqr(r)
    z = ca.vertcat(delta, bs)
    x0 = np.concatenate([[theta["delta1"], theta["delta2"]], beta / scale if pi_fixed is None else []])
    lb = np.concatenate([[bounds[0]] * 2, np.full(len(x0) - 2, -np.inf)])
    ub = np.concatenate([[bounds[1]] * 2, np.full(len(x0) - 2, np.inf)])
    # Exact Hessian: π enters linearly, so the problem is a quadratic in π coupled to δ — quasi-Newton
    # crawls along that ill-conditioned quadratic; Newton steps take it in one.
    solver = ca.nlpsol("offsets", "ipopt", {"x": z, "f": objective / n}, {**IPOPT_QUIET, "ipopt.max_iter": 50})
    sol = solver(x0=x0, lbx=lb, ubx=ub)
    st = solver.stats()
    zs = np.array(sol["x"]).ravel()
    info = {
        "method": f"IPOPT, (δ1, δ2) jointly with {'π' if pi_fixed is None else 'the datasheet π held'}",
        "status": st["return_status"],
        "iterations": int(st["iter_count"]),
        "seconds": time.perf_counter() - t0,
    }
    if not np.all(np.isfinite(zs[:2])):
        return None, info
    return {"delta1": float(zs[0]), "delta2": float(zs[1])}, info
