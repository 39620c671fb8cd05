"""The bounded online update in generated C (online_kernel): the NumPy path's parameters at every step, and a
refused sample changes nothing."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from ident_opt.adaptation.estimator import Estimator
from ident_opt.adaptation.identifier import ArmDesign, OnlineIdentifier
from ident_opt.adaptation.kernel import attach
from ident_opt.arm.planar import RIGID
from ident_opt.fitting.bounded import default_bounds
from ident_opt.fitting.stats import Stats

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
    assert attach(b, ArmDesign(RIGID))
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
    assert attach(ident, ArmDesign(RIGID))
    state = ident._kernel.state
    theta, R, n = ident.theta.copy(), np.array(state.R[state.cur * 81 : (state.cur + 1) * 81]), ident.n_updates
    bad = Y[500].copy()
    bad[0, 0] = np.inf
    with pytest.raises(FloatingPointError):
        ident.add(bad, tau[500])
    assert np.array_equal(ident.theta, theta) and ident.n_updates == n
    assert np.array_equal(np.array(state.R[state.cur * 81 : (state.cur + 1) * 81]), R)


def test_attach_declines_other_estimators():
    Y, tau = _trial(200)
    ident = OnlineIdentifier(
        RIGID.regressor, Estimator("ridge", penalty=np.full(9, 1e-3)), np.zeros(9), Stats.from_regressor(Y, tau)
    )
    assert not attach(ident, ArmDesign(RIGID))


def test_compiled_step_predicts_as_python_with_the_guard():
    from ident_opt.models.gmr import GMR, Support

    rng = np.random.default_rng(2)
    n = 3000
    q, dq, ddq = rng.uniform(-3, 3, (n, 2)), rng.normal(0, 1, (n, 2)), rng.normal(0, 3, (n, 2))
    Y = RIGID.regressor(q, dq, ddq)
    tau = Y @ PI + 0.2 * np.sin(3 * q) + 0.05 * rng.standard_normal((n, 2))
    X = np.hstack([q, dq, ddq])
    est = Estimator("bounded", bounds=default_bounds(RIGID))
    theta0 = OnlineIdentifier(RIGID.regressor, est, np.zeros(9), Stats.from_regressor(Y[:2000], tau[:2000])).theta
    gmr = GMR(n_components=3).fit(X[:2000], tau[:2000] - Y[:2000] @ theta0)
    ref = OnlineIdentifier(
        RIGID.regressor,
        est,
        theta0,
        Stats.from_regressor(Y[:2000], tau[:2000]),
        gmr=gmr,
        support=Support.fit(gmr, X[:2000]),
    )
    fast = copy.deepcopy(ref)
    assert attach(fast, ArmDesign(RIGID)) and fast._predictor is not None
    far = 0
    for k in range(2000, n):
        x = (q[k], dq[k], ddq[k]) if k % 7 else (q[k], 20 * dq[k], 30 * ddq[k])  # some far outside
        p1, D1 = fast.step(*x)
        p2, D2 = ref.step(*x)
        np.testing.assert_allclose(D1, D2, rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(p1.tau, p2.tau, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(p1.std, p2.std, rtol=1e-9, atol=1e-12)
        assert p1.extrapolating == p2.extrapolating
        far += p1.extrapolating
        fast.add(D1, tau[k])
        ref.add(D2, tau[k])
    assert far > 100
    np.testing.assert_allclose(fast.gmr.means_, ref.gmr.means_, rtol=1e-9, atol=1e-12)  # the lazy transform
