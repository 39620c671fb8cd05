"""Box-bounded least squares on the statistics: exact (KKT, lsq_linear on stacked data), warm = cold."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from ident_opt.arm.planar import RIGID, PlanarArm
from ident_opt.fitting.bounded import Bounds, default_bounds, kkt_residual, solve_bounded
from ident_opt.fitting.stats import Stats


def _data(n: int, seed: int, pi: np.ndarray, noise: float = 0.3):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-np.pi, np.pi, (n, 2))
    dq = rng.normal(0, 1.0, (n, 2))
    ddq = rng.normal(0, 3.0, (n, 2))
    Y = RIGID.regressor(q, dq, ddq)
    tau = Y @ pi + noise * rng.standard_normal((n, 2))
    return Y, tau


#: A plausible π whose friction fv2 is negative in truth: its lower bound 0 becomes active.
PI_ACTIVE = np.array([0.8, 0.05, 0.1, 3.7, 0.3, 1.5, -0.2, 0.6, 0.4])
PI_INACTIVE = np.array([0.8, 0.05, 0.1, 3.7, 0.3, 1.5, 0.2, 0.6, 0.4])


def _reference(Y: np.ndarray, tau: np.ndarray, bounds: Bounds) -> np.ndarray:
    """The paper's way: bounded LS on all stacked rows (BVLS: an exact active-set method)."""
    return lsq_linear(
        Y.reshape(-1, Y.shape[2]), tau.reshape(-1), bounds=(bounds.lower, bounds.upper), method="bvls", tol=1e-15
    ).x


@pytest.mark.parametrize("pi_true, n_active", [(PI_INACTIVE, 0), (PI_ACTIVE, 1)])
def test_matches_lsq_linear_and_kkt(pi_true, n_active):
    Y, tau = _data(3000, 1, pi_true)
    bounds = default_bounds(RIGID)
    H, h, _ = Stats.from_regressor(Y, tau).combined()
    sol = solve_bounded(H, h, bounds)
    assert np.count_nonzero(sol.state) == n_active
    ref = _reference(Y, tau, bounds)
    assert np.max(np.abs(sol.pi - ref)) <= 1e-9 * np.max(np.abs(ref))
    assert kkt_residual(H, h, sol.pi, bounds, sol.state) < 1e-12


def test_upper_bounds_and_many_active():
    """Tight two-sided boxes: several parameters at lower and upper bounds at once."""
    Y, tau = _data(2000, 2, PI_INACTIVE)
    lower = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    upper = np.array([0.5, 0.01, 0.05, 5.0, 0.1, 1.0, 1.0, 0.1, 1.0])
    bounds = Bounds(lower, upper)
    H, h, _ = Stats.from_regressor(Y, tau).combined()
    sol = solve_bounded(H, h, bounds)
    assert np.count_nonzero(sol.state > 0) >= 3
    ref = _reference(Y, tau, bounds)
    assert np.max(np.abs(sol.pi - ref)) <= 1e-9 * np.max(np.abs(ref))


@pytest.mark.parametrize("seed", range(5))
def test_any_warm_start_gives_the_same_answer(seed):
    """Warm starting from a wrong point and a wrong active set changes the work, never the answer."""
    rng = np.random.default_rng(seed)
    Y, tau = _data(1500, 10 + seed, PI_ACTIVE)
    bounds = Bounds(np.zeros(9), np.full(9, 2.0))
    H, h, _ = Stats.from_regressor(Y, tau).combined()
    cold = solve_bounded(H, h, bounds)
    state = rng.integers(-1, 2, 9).astype(np.int8)
    warm = solve_bounded(H, h, bounds, start=rng.uniform(-1, 3, 9), state=state)
    np.testing.assert_array_equal(warm.state, cold.state)
    assert np.max(np.abs(warm.pi - cold.pi)) <= 1e-12 * np.max(np.abs(cold.pi))


def test_default_bounds_are_physical():
    b = default_bounds(PlanarArm(extensions=("armature", "asymmetric_coulomb")))
    names = PlanarArm(extensions=("armature", "asymmetric_coulomb")).names
    lower = dict(zip(names, b.lower))
    assert all(lower[n] == 0 for n in ("a1", "a3", "ia2", "fv1", "fv2", "fc1p", "fc1n", "fc2p", "fc2n"))
    assert all(lower[n] == -np.inf for n in ("a2", "b1", "b2"))
    signed = default_bounds(RIGID, signs_from=np.array([1, -1, 1, 1, 0, 1, 1, 1, 1.0]))
    assert signed.upper[1] == 0 and signed.lower[3] == 0 and signed.lower[4] == -np.inf


def test_bad_bounds_rejected():
    with pytest.raises(ValueError):
        Bounds(np.ones(3), np.zeros(3))
