"""The bounded online update in generated C (online_kernel): the NumPy path's parameters at every step, and a
refused sample changes nothing."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from ident_opt.identify.bounded import default_bounds
from ident_opt.identify.stats import Stats
from ident_opt.online import Estimator, OnlineIdentifier
from ident_opt.online_kernel import attach
from ident_opt.robot import RIGID

PI = np.array([0.7527, 0.05218, -0.03602, 3.752, 0.3125, 1.568, 0.02847, 0.5806, 0.3739])  # a3 < 0: bound active


def _trial(n, seed=0):
    rng = np.random.default_rng(seed)
    Y = RIGID.regressor(rng.uniform(-3, 3, (n, 2)), rng.normal(0, 1, (n, 2)), rng.normal(0, 3, (n, 2)))
    return Y, Y @ PI + 0.3 * rng.standard_normal((n, 2))


def test_kernel_follows_the_numpy_path_exactly():
    Y, tau = _trial(3000)
    a = OnlineIdentifier(
        RIGID.regressor,
        Estimator("bounded", bounds=default_bounds(RIGID)),
        np.zeros(9),
        Stats.from_regressor(Y[:500], tau[:500]),
    )
    b = copy.deepcopy(a)
    assert attach(b, RIGID)
    assert b.theta[2] == 0.0  # the active bound a3 ≥ 0
    for k in range(500, 3000):
        a.add(Y[k], tau[k])
        b.add(Y[k], tau[k])
        np.testing.assert_allclose(b.theta, a.theta, rtol=1e-11, atol=1e-14)
    np.testing.assert_allclose(b.parametric_var, a.parametric_var, rtol=1e-12)
    assert b.n_updates == a.n_updates and b.stats.n == a.stats.n


def test_kernel_refuses_non_finite_rows_and_changes_nothing():
    Y, tau = _trial(600, seed=1)
    ident = OnlineIdentifier(
        RIGID.regressor,
        Estimator("bounded", bounds=default_bounds(RIGID)),
        np.zeros(9),
        Stats.from_regressor(Y[:500], tau[:500]),
    )
    assert attach(ident, RIGID)
    theta, H, n = ident.theta.copy(), ident._H.copy(), ident.n_updates
    bad = Y[500].copy()
    bad[0, 0] = np.inf
    with pytest.raises(FloatingPointError):
        ident.add(bad, tau[500])
    assert np.array_equal(ident.theta, theta) and np.array_equal(ident._H, H) and ident.n_updates == n


def test_attach_declines_other_estimators():
    Y, tau = _trial(200)
    ident = OnlineIdentifier(
        RIGID.regressor, Estimator("ridge", penalty=np.full(9, 1e-3)), np.zeros(9), Stats.from_regressor(Y, tau)
    )
    assert not attach(ident, RIGID)
