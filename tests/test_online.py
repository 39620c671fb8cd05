"""Online re-solves equal from-scratch batch solves; the consistency transform keeps predictions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from ident_opt.adaptation.estimator import Estimator, batch_theta
from ident_opt.adaptation.identifier import OnlineIdentifier
from ident_opt.arm.planar import RIGID
from ident_opt.fitting.bounded import Bounds, default_bounds, solve_bounded
from ident_opt.fitting.stats import Stats
from ident_opt.models.gmr import GMR


def _trial(n: int, seed: int, pi: np.ndarray, noise: float = 0.3):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-np.pi, np.pi, (n, 2))
    dq = rng.normal(0, 1.0, (n, 2))
    ddq = rng.normal(0, 3.0, (n, 2))
    tau = RIGID.predict(pi, q, dq, ddq) + noise * rng.standard_normal((n, 2))
    return q, dq, ddq, tau


#: fv2 slightly negative in truth: the bound fv2 ≥ 0 is active on some prefixes and not on others.
PI_EDGE = np.array([0.8, 0.05, 0.1, 3.7, 0.3, 1.5, -0.004, 0.6, 0.4])
PI_CLEAR = np.array([0.8, 0.05, 0.1, 3.7, 0.3, 1.5, 0.3, 0.6, 0.4])


def _replay(pi_true, bounds, seed=0, n0=60, n=1500, checks=12):
    """Online from an n0-sample offline fit; compare at random steps with two batch references."""
    q, dq, ddq, tau = _trial(n, seed, pi_true)
    Y = RIGID.regressor(q, dq, ddq)
    est = Estimator("bounded", bounds=bounds)
    online = OnlineIdentifier(RIGID.regressor, est, np.zeros(9), Stats.from_regressor(Y[:n0], tau[:n0]))
    steps = set(np.random.default_rng(seed).choice(np.arange(n0 + 1, n + 1), checks, replace=False))
    states = set()
    for k in range(n0, n):
        online.update(q[k], dq[k], ddq[k], tau[k], design=Y[k])
        m = k + 1  # samples seen
        states.add(tuple(np.flatnonzero(online._solve.__self__.last.state)))
        if m in steps:
            ref = lsq_linear(
                Y[:m].reshape(-1, 9), tau[:m].reshape(-1), bounds=(bounds.lower, bounds.upper), method="bvls", tol=1e-15
            ).x
            H, h, _ = Stats.from_regressor(Y[:m], tau[:m]).combined()
            cold = solve_bounded(H, h, bounds).pi
            scale = np.max(np.abs(ref))
            assert np.max(np.abs(online.parameters - ref)) <= 1e-9 * scale, m
            assert np.max(np.abs(online.parameters - cold)) <= 1e-9 * scale, m
    return states


def test_online_equals_batch_with_changing_active_set():
    states = _replay(PI_EDGE, default_bounds(RIGID))
    assert len(states) >= 2  # the active set really changed during the replay
    assert any(states)


def test_online_equals_batch_without_active_bounds():
    states = _replay(PI_CLEAR, default_bounds(RIGID), seed=3)
    assert states == {()}


def test_online_equals_batch_with_many_active_bounds():
    bounds = Bounds(np.zeros(9), np.array([0.5, 0.01, 0.05, 5.0, 0.1, 1.0, 1.0, 0.1, 1.0]))
    states = _replay(PI_CLEAR, bounds, seed=5, n=600)
    assert max(len(s) for s in states) >= 3


def test_ridge_is_exact_recursive_ridge():
    """RR: the online weights equal sklearn's Ridge (unpenalised intercept) refitted on the prefix."""
    from sklearn.linear_model import Ridge

    q, dq, ddq, tau = _trial(400, 7, PI_CLEAR)
    X = np.hstack([q, dq, ddq])

    def design(q, dq, ddq):  # joint j's features [1, x] in block j
        F = np.hstack([np.ones((len(q), 1)), q, dq, ddq])
        D = np.zeros((len(q), 2, 14))
        D[:, 0, :7], D[:, 1, 7:] = F, F
        return D

    alpha = 2.5
    penalty = np.r_[0.0, np.full(6, alpha), 0.0, np.full(6, alpha)]
    D = design(q, dq, ddq)
    online = OnlineIdentifier(
        design, Estimator("ridge", penalty=penalty), np.zeros(14), Stats.from_regressor(D[:50], tau[:50])
    )
    for k in range(50, 400):
        online.update(q[k], dq[k], ddq[k], tau[k])
        if k + 1 in (51, 137, 400):
            sk = Ridge(alpha=alpha).fit(X[: k + 1], tau[: k + 1])
            ref = np.r_[sk.intercept_[0], sk.coef_[0], sk.intercept_[1], sk.coef_[1]]
            assert np.max(np.abs(online.parameters - ref)) <= 1e-9 * np.max(np.abs(ref))


def test_fixed_model_does_not_move():
    q, dq, ddq, tau = _trial(100, 8, PI_CLEAR)
    online = OnlineIdentifier(RIGID.regressor, Estimator("fixed"), PI_EDGE, Stats.zeros(9))
    for k in range(100):
        p = online.update(q[k], dq[k], ddq[k], tau[k])
        np.testing.assert_allclose(p.tau, RIGID.predict(PI_EDGE, q[k : k + 1], dq[k : k + 1], ddq[k : k + 1])[0])
    np.testing.assert_array_equal(online.parameters, PI_EDGE)
    assert online.stats.n == 100


def test_batch_theta_is_the_cold_solution():
    q, dq, ddq, tau = _trial(300, 9, PI_EDGE)
    st = Stats.from_data(RIGID, q, dq, ddq, tau)
    est = Estimator("bounded", bounds=default_bounds(RIGID))
    H, h, _ = st.combined()
    np.testing.assert_array_equal(batch_theta(est, st), solve_bounded(H, h, est.bounds).pi)


def _separated_gmr(pi0: np.ndarray, n_per: int = 400, seed: int = 0) -> tuple[GMR, tuple]:
    """A GMR on well-separated clusters in x (responsibility ≈ 1 at each component's own mean)."""
    rng = np.random.default_rng(seed)
    centres = np.array(
        [[0.3, 0.5, 0.8, -0.4, 2.0, 1.0], [-1.2, 1.4, -0.6, 0.9, -2.0, 3.0], [1.5, -1.0, 0.0, 0.0, 0.0, -3.0]]
    )
    X = np.vstack([c + 0.03 * rng.standard_normal((n_per, 6)) for c in centres])
    q, dq, ddq = X[:, 0:2], X[:, 2:4], X[:, 4:6]
    tau = RIGID.predict(pi0 * 1.1, q, dq, ddq) + 0.05 * np.sin(7 * X[:, :2])
    r = tau - RIGID.predict(pi0, q, dq, ddq)
    return GMR(n_components=3, random_state=0).fit(X, r), (q, dq, ddq, tau)


@pytest.mark.parametrize("cross", [False, True])
def test_consistency_transform_keeps_prediction_at_component_means(cross):
    pi0 = PI_CLEAR
    gmr, _ = _separated_gmr(pi0)
    jac = _arm_jacobian() if cross else None
    online = OnlineIdentifier(
        RIGID.regressor, Estimator("fixed"), pi0, Stats.zeros(9), gmr=gmr, cross_covariance=cross, design_jacobian=jac
    )
    mu = gmr.means_[:, :6]
    before = [online.predict(m[0:2], m[2:4], m[4:6]).tau for m in mu]
    delta = np.array([0.05, -0.02, 0.03, 0.2, -0.1, 0.1, 0.05, -0.1, 0.07])
    online.theta = pi0 + delta  # only π moves
    online._transform(delta)
    after = [online.predict(m[0:2], m[2:4], m[4:6]).tau for m in mu]
    np.testing.assert_allclose(after, before, rtol=0, atol=1e-10)
    # The parametric part did move, so the GMR really compensated.
    assert not np.allclose(
        [online.predict(m[0:2], m[2:4], m[4:6]).parametric for m in mu],
        [RIGID.predict(pi0, m[None, 0:2], m[None, 2:4], m[None, 4:6])[0] for m in mu],
    )
    # The offline GMR is untouched (the transform works on a copy).
    assert not np.allclose(online.gmr.means_, gmr.means_)


def _arm_jacobian():
    from ident_opt.adaptation.identifier import arm_design_jacobian

    return arm_design_jacobian(RIGID)


def test_cross_covariance_transform_is_first_order_exact():
    """With the cross-covariance update, a component's conditional mean follows −Y(x)Δπ to first order:
    the hybrid prediction near μx_k changes by O(|x − μ|²) only."""
    pi0 = PI_CLEAR
    gmr, _ = _separated_gmr(pi0)
    delta = np.array([0.05, -0.02, 0.03, 0.2, -0.1, 0.1, 0.05, -0.1, 0.07])
    mu = gmr.means_[0, :6]
    errors = {}
    for cross in (False, True):
        online = OnlineIdentifier(
            RIGID.regressor,
            Estimator("fixed"),
            pi0,
            Stats.zeros(9),
            gmr=gmr,
            cross_covariance=cross,
            design_jacobian=_arm_jacobian() if cross else None,
        )
        x = mu + np.array([0.01, -0.01, 0.02, 0.01, 0.03, -0.02])
        before = online.predict(x[0:2], x[2:4], x[4:6]).tau
        online.theta = pi0 + delta
        online._transform(delta)
        errors[cross] = np.max(np.abs(online.predict(x[0:2], x[2:4], x[4:6]).tau - before))
    assert errors[True] < 0.1 * errors[False]


def test_lazy_statistics_equal_batch_statistics_across_flushes():
    """Per-joint statistics folded in lazily (in batches of 4096) equal the batch statistics."""
    q, dq, ddq, tau = _trial(9000, 11, PI_CLEAR)
    Y = RIGID.regressor(q, dq, ddq)
    online = OnlineIdentifier(
        RIGID.regressor,
        Estimator("bounded", bounds=default_bounds(RIGID)),
        np.zeros(9),
        Stats.from_regressor(Y[:100], tau[:100]),
    )
    for k in range(100, 9000):
        online.add(Y[k], tau[k])
    ref = Stats.from_regressor(Y, tau)
    got = online.stats
    assert got.n == ref.n == 9000
    np.testing.assert_allclose(got.G, ref.G, rtol=1e-12)
    np.testing.assert_allclose(got.b, ref.b, rtol=1e-12)
    np.testing.assert_allclose(got.s, ref.s, rtol=1e-12)
    np.testing.assert_allclose(online.residual_std(), np.sqrt(ref.rss(online.theta) / 9000), rtol=1e-9)
