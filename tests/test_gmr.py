"""GMR: the vectorised conditioning against a direct per-sample formula, fitting, units, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from ident_opt.errors import InputError
from ident_opt.models.gmr import GMR


def _random_spd(rng: np.random.Generator, D: int) -> np.ndarray:
    B = rng.normal(size=(D, D))
    return B @ B.T + 0.5 * np.eye(D)


def _direct(weights, means, covs, d, x):
    """Textbook per-sample GMR: Bayes' rule for h_k, Gaussian conditioning per component, mixture moments."""
    K = len(weights)
    dens = np.array([weights[k] * multivariate_normal(means[k, :d], covs[k, :d, :d]).pdf(x) for k in range(K)])
    h = dens / dens.sum()
    ms, Cs = [], []
    for k in range(K):
        Sxx, Sxr, Srr = covs[k, :d, :d], covs[k, :d, d:], covs[k, d:, d:]
        ms.append(means[k, d:] + Sxr.T @ np.linalg.solve(Sxx, x - means[k, :d]))
        Cs.append(Srr - Sxr.T @ np.linalg.solve(Sxx, Sxr))
    mean = sum(h[k] * ms[k] for k in range(K))
    cov = sum(h[k] * (Cs[k] + np.outer(ms[k] - mean, ms[k] - mean)) for k in range(K))
    return mean, cov


def _with(weights, means, covs, d) -> GMR:
    g = GMR()
    g.weights_, g.means_, g.covariances_, g.n_inputs = weights, means, covs, d
    return g


def test_one_component_is_gaussian_conditioning():
    rng = np.random.default_rng(1)
    d, D = 3, 5
    mu, S = rng.normal(size=D), _random_spd(rng, D)
    X = rng.normal(size=(50, d))
    mean, cov = _with(np.ones(1), mu[None], S[None], d).predict(X)
    A = S[d:, :d] @ np.linalg.inv(S[:d, :d])
    np.testing.assert_allclose(mean, mu[d:] + (X - mu[:d]) @ A.T, rtol=1e-12, atol=1e-12)
    C = S[d:, d:] - A @ S[:d, d:]
    np.testing.assert_allclose(cov, np.broadcast_to(C, cov.shape), rtol=1e-12, atol=1e-12)


def test_two_components_hand_built_match_direct_formula():
    # Two components that disagree strongly in the middle, so h_k matter and the between-component
    # spread is a visible part of the variance.
    weights = np.array([0.3, 0.7])
    means = np.array([[-1.0, 0.5, 2.0, -1.0], [1.5, -0.5, -1.0, 3.0]])
    covs = np.array(
        [
            [[1.0, 0.2, 0.5, 0.0], [0.2, 0.8, 0.0, 0.3], [0.5, 0.0, 1.2, 0.1], [0.0, 0.3, 0.1, 0.9]],
            [[0.6, -0.1, -0.2, 0.1], [-0.1, 1.5, 0.4, 0.0], [-0.2, 0.4, 0.7, -0.2], [0.1, 0.0, -0.2, 1.1]],
        ]
    )
    g = _with(weights, means, covs, 2)
    X = np.array([[0.0, 0.0], [-1.0, 0.5], [1.5, -0.5], [0.2, 0.1], [3.0, -2.0]])
    mean, cov = g.predict(X)
    for i, x in enumerate(X):
        m, C = _direct(weights, means, covs, 2, x)
        np.testing.assert_allclose(mean[i], m, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(cov[i], C, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(g.predict_mean(X), mean, rtol=1e-13, atol=1e-13)
    # between-component spread is included: at x = 0 the total variance exceeds every component's own
    C0 = [covs[k, 2:, 2:] - covs[k, 2:, :2] @ np.linalg.solve(covs[k, :2, :2], covs[k, :2, 2:]) for k in range(2)]
    assert cov[0, 0, 0] > max(C0[0][0, 0], C0[1][0, 0])


def test_many_components_far_from_data_stay_finite_and_match():
    # Far-away inputs underflow every density; log-sum-exp keeps the answer (the nearest component).
    rng = np.random.default_rng(2)
    K, d, D = 6, 6, 8
    weights = rng.dirichlet(np.ones(K))
    means = rng.normal(size=(K, D))
    covs = np.stack([_random_spd(rng, D) for _ in range(K)])
    g = _with(weights, means, covs, d)
    X = rng.normal(size=(20, d)) * 3
    mean, cov = g.predict(X)
    for i in range(len(X)):
        m, C = _direct(weights, means, covs, d, X[i])
        np.testing.assert_allclose(mean[i], m, rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(cov[i], C, rtol=1e-9, atol=1e-10)
    far_mean, far_cov = g.predict(np.full((1, d), 200.0))
    assert np.isfinite(far_mean).all() and np.isfinite(far_cov).all()


def test_fit_reports_parameters_in_original_units():
    rng = np.random.default_rng(3)
    X = rng.normal(size=(400, 2)) * [10.0, 0.01] + [5.0, -3.0]
    R = 2.0 * X[:, :1] + rng.normal(size=(400, 1)) * 0.5
    g = GMR(n_components=1, reg_covar=1e-4).fit(X, R)
    Z = np.hstack([X, R])
    np.testing.assert_allclose(g.means_[0], Z.mean(axis=0), rtol=1e-10)
    # scikit-learn adds reg_covar to the standardised covariance: in original units that is reg·σ_i²
    expected = np.cov(Z.T, bias=True) + 1e-4 * np.diag(Z.var(axis=0))
    np.testing.assert_allclose(g.covariances_[0], expected, rtol=1e-8, atol=1e-12)
    assert g.n_components_ == 1 and g.n_inputs == 2


def test_recovers_known_nonlinear_residual():
    # A residual that no linear model captures: sin of one input, a square of another, plus noise.
    rng = np.random.default_rng(4)
    n = 4000
    X = rng.uniform(-2, 2, size=(n, 3))
    truth = np.column_stack([np.sin(2 * X[:, 0]), 0.5 * X[:, 1] ** 2 - 0.3 * X[:, 0]])
    R = truth + rng.normal(scale=0.1, size=truth.shape)
    g = GMR(candidates=(1, 4, 8, 12)).fit(X[:3000], R[:3000])
    est = g.predict_mean(X[3000:])
    nmse = np.mean((est - truth[3000:]) ** 2, axis=0) / np.var(truth[3000:], axis=0)
    assert (nmse < 0.05).all(), nmse
    assert g.n_components_ > 1 and set(g.selection_scores_) == {1, 4, 8, 12}
    # the 95 % interval covers about 95 % of fresh noisy samples
    mean, std = g.predict_std(X[3000:])
    inside = np.mean(np.abs(R[3000:] - mean) <= 1.96 * std, axis=0)
    assert ((inside > 0.85) & (inside < 0.995)).all(), inside


def test_bic_selection_and_diag_covariance():
    rng = np.random.default_rng(5)
    X = rng.uniform(-1, 1, size=(1500, 2))
    R = np.where(X[:, :1] > 0, 1.0, -1.0) + rng.normal(scale=0.05, size=(1500, 1))
    g = GMR(selection="bic", candidates=(1, 2, 4), covariance="diag").fit(X, R)
    assert g.n_components_ in (2, 4) and len(g.selection_scores_) == 3
    # diag: every off-diagonal covariance is zero, so each component predicts its own constant mean
    off = g.covariances_ * (1 - np.eye(3))
    assert np.all(off == 0)
    est = g.predict_mean(np.array([[0.5, 0.0], [-0.5, 0.0]]))
    np.testing.assert_allclose(est[:, 0], [1.0, -1.0], atol=0.1)


def test_blocked_validation_holds_out_the_last_rows():
    # Validation MSE does not depend on the order of the validation rows, and the training rows are
    # unchanged: permuting only the last quarter must leave blocked scores exactly as they were.
    rng = np.random.default_rng(9)
    X = rng.uniform(-2, 2, size=(800, 2))
    R = np.sin(2 * X[:, :1]) + rng.normal(scale=0.1, size=(800, 1))
    perm = np.r_[np.arange(600), 600 + rng.permutation(200)]
    a = GMR(candidates=(1, 3), validation="blocked").fit(X, R)
    b = GMR(candidates=(1, 3), validation="blocked").fit(X[perm], R[perm])
    assert a.selection_scores_ == pytest.approx(b.selection_scores_, rel=1e-9)
    with pytest.raises(InputError):
        GMR(validation="sideways").fit(X, R)


def test_mean_shift_moves_prediction_exactly():
    # The online consistency transform edits means_[k, n_inputs:]; predict must see it (no stale cache).
    rng = np.random.default_rng(6)
    X = rng.normal(size=(500, 2))
    R = np.column_stack([X[:, 0] ** 2, X[:, 1]])
    g = GMR(n_components=3).fit(X, R)
    before = g.predict_mean(X[:10])
    g.means_[:, g.n_inputs :] += np.array([0.25, -1.0])
    np.testing.assert_allclose(g.predict_mean(X[:10]) - before, np.tile([0.25, -1.0], (10, 1)), atol=1e-12)


def test_subsamples_to_max_train_samples():
    rng = np.random.default_rng(7)
    X = rng.normal(size=(3000, 2))
    g = GMR(n_components=2, max_train_samples=500).fit(X, X[:, :1] * 2)
    assert g.n_train_ == 500


@pytest.mark.parametrize(
    "X, R",
    [
        (np.ones((10, 2)), np.ones((9, 1))),
        (np.ones(10), np.ones((10, 1))),
        (np.full((10, 2), np.nan), np.ones((10, 1))),
        (np.ones((1, 2)), np.ones((1, 1))),
    ],
)
def test_bad_input_is_input_error(X, R):
    with pytest.raises(InputError):
        GMR(n_components=1).fit(X, R)


def test_candidates_too_large_for_the_data_are_skipped():
    X = np.random.default_rng(10).normal(size=(40, 2))
    g = GMR(candidates=(1, 2, 100)).fit(X, X[:, :1] ** 2)
    assert set(g.selection_scores_) == {1, 2} and g.n_components_ in (1, 2)
    with pytest.raises(InputError):
        GMR(candidates=(100,)).fit(X, X[:, :1])


def test_bad_settings_and_predict_shape():
    X = np.random.default_rng(8).normal(size=(50, 2))
    with pytest.raises(InputError):
        GMR(n_components=60).fit(X, X[:, :1])
    with pytest.raises(InputError):
        GMR(covariance="spherical").fit(X, X[:, :1])
    g = GMR(n_components=1).fit(X, X[:, :1])
    with pytest.raises(InputError):
        g.predict(np.ones((3, 3)))
    with pytest.raises(RuntimeError):
        GMR().predict(X)


def test_column_constant_up_to_rounding_is_not_blown_up():
    """A joint at rest for the whole window (std ~1e-16 from rounding) behaves like an exactly constant one."""
    rng = np.random.default_rng(5)
    X = rng.normal(size=(400, 2))
    R = (X[:, :1] ** 2) + 0.1 * rng.normal(size=(400, 1))
    X_round = X.copy()
    X_round[:, 1] = 0.3 + 1e-16 * rng.choice([-1.0, 1.0], 400)  # constant up to rounding
    X_const = X.copy()
    X_const[:, 1] = 0.3
    a = GMR(n_components=2, random_state=0).fit(X_round, R)
    b = GMR(n_components=2, random_state=0).fit(X_const, R)
    assert np.allclose(a.means_, b.means_, atol=1e-8)
    assert np.allclose(a.covariances_, b.covariances_, atol=1e-8)
    assert np.min(np.linalg.eigvalsh(a.covariances_)) > 1e-6
