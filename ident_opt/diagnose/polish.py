"""Nonlinear polish with CasADi + IPOPT (`identify.nlp.fit_expression`) after the variable-projection search.

The Stribeck velocity vs enters nonlinearly. The search (`linear.search`) finds it on a grid with a bounded
scalar refinement, holding the static excess fs at its least-squares value for each vs; IPOPT then moves
(fs_j, vs_j) jointly, per joint, with every other coefficient held. Only samples where joint j moves are
used: at rest the Stribeck term is zero (dq = 0) and the rest stretches' projection does not touch them, so
this is exactly the candidate's objective restricted to (fs_j, vs_j). IPOPT sees at most `POLISH_ROWS` of
those samples (evenly strided: CasADi builds the expression graph per sample, so a 2 kHz trial would
otherwise cost seconds just to set up); the polish is kept only if it lowers the objective on all of them.
"""

from __future__ import annotations

import numpy as np

#: Most samples an IPOPT polish is set up on (per joint for Stribeck).
POLISH_ROWS = 12000


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
