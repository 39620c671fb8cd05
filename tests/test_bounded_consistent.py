"""CPBR re-solves: the warm Newton/active-set solver is exact (KKT) and equals the conic fit."""

from __future__ import annotations

import numpy as np

from ident_opt.arm.planar import RIGID
from ident_opt.fitting.bounded import default_bounds
from ident_opt.fitting.bounded_consistent import WarmConsistentLS
from ident_opt.fitting.constrained import fit_constrained
from ident_opt.fitting.stats import Stats

#: An inconsistent truth (a3 < 0, like plain OLS on exp1): the mass-matrix cone is active in the fit.
PI_BAD = np.array([0.8, 0.05, -0.02, 3.7, 0.3, 1.5, 0.2, 0.6, 0.4])


def _trial(n: int, seed: int):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-np.pi, np.pi, (n, 2))
    dq = rng.normal(0, 1.0, (n, 2))
    ddq = rng.normal(0, 3.0, (n, 2))
    Y = RIGID.regressor(q, dq, ddq)
    return Y, Y @ PI_BAD + 0.3 * rng.standard_normal((n, 2))


def test_cold_solve_matches_clarabel_and_is_on_the_cone():
    Y, tau = _trial(2000, 0)
    stats = Stats.from_regressor(Y, tau)
    bounds = default_bounds(RIGID)
    solver = WarmConsistentLS(RIGID, bounds)
    pi = solver.solve(*stats.combined()[:2])
    assert solver.inexact == 0 and solver.mu.max() > 0  # a cone is active, and the polish verified
    assert RIGID.min_mass_eigenvalue(pi) >= 1e-6 * (1 - 1e-9)
    ref = fit_constrained(stats, RIGID, margin=1e-6, bounds=(bounds.lower, bounds.upper)).pi
    # Clarabel (an interior-point method) is accurate to about 1e-8 here; the KKT-polished answer is
    # the reference for the online test below.
    assert np.max(np.abs(pi - ref)) <= 1e-7 * np.max(np.abs(ref))


def test_online_consistent_equals_cold_solve_on_every_checked_prefix():
    Y, tau = _trial(1200, 1)
    bounds = default_bounds(RIGID)
    n0 = 100
    stats = Stats.from_regressor(Y[:n0], tau[:n0])
    H, h, _ = stats.combined()
    online = WarmConsistentLS(RIGID, bounds)
    online.solve(H, h)
    checks = set(np.random.default_rng(1).choice(np.arange(n0 + 1, 1201), 6, replace=False)) | {1200}
    for k in range(n0, 1200):
        H += Y[k].T @ Y[k]
        h += Y[k].T @ tau[k]
        pi = online.solve(H, h)
        if k + 1 in checks:
            cold = online.cold()
            ref = cold.solve(*Stats.from_regressor(Y[: k + 1], tau[: k + 1]).combined()[:2])
            assert cold.inexact == 0
            assert np.max(np.abs(pi - ref)) <= 1e-9 * np.max(np.abs(ref)), k
    assert online.inexact == 0
    assert online.fallbacks <= 3  # the conic solver is the exception, not the rule
