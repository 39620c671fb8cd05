"""Consistency of a URDF arm's fits: pseudo-inertias ⪰ 0, the constrained fit equals OLS where nothing binds,
the plausible fit stays near the CAD model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ident_opt.arm.chain import ChainArm
from ident_opt.fitting.base import fit_base_ols
from ident_opt.fitting.constrained import fit_constrained
from ident_opt.fitting.physical import fit_physical, log_det_divergence
from ident_opt.fitting.stats import Stats

KUKA = Path(__file__).resolve().parents[1] / "data" / "kuka_lwr4" / "kuka_lwr4.urdf"


@pytest.fixture(scope="module")
def kuka() -> ChainArm:
    return ChainArm(str(KUKA), tuple(f"lwr_{i}_joint" for i in range(7)), offsets=True)


@pytest.fixture(scope="module")
def simulated(kuka):
    """Statistics of 300 random states of a consistent arm (CAD inertials, positive joint terms)."""
    rng = np.random.default_rng(4)
    q, dq, ddq = (rng.uniform(-2, 2, (300, 7)) for _ in range(3))
    truth = kuka.cad_parameters()
    truth[kuka.n_link_params :] = rng.uniform(0.1, 1.0, kuka.n_params - kuka.n_link_params)
    tau = kuka.predict(truth, q, dq, ddq)
    return truth, Stats.from_regressor(kuka.regressor(q, dq, ddq), tau)


def test_constrained_equals_ols_where_nothing_binds(kuka, simulated):
    truth, stats = simulated
    ols = fit_base_ols(stats, kuka)
    fit = fit_constrained(stats, kuka)
    base = ols.base
    # The least-norm OLS π is not consistent (its unseen directions are 0), so the solver runs; the data
    # come from a consistent arm, so it reaches the same base parameters (the same torques).
    assert fit.status == "Solved"
    np.testing.assert_allclose(base.project(fit.pi), ols.fit.pi, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(ols.fit.pi, base.project(truth), atol=1e-8)
    assert kuka.min_mass_eigenvalue(fit.pi) >= 0


def test_plausible_fit_is_consistent_and_near_the_cad_masses(kuka, simulated):
    truth, stats = simulated
    fit = fit_physical(stats, kuka)
    assert np.linalg.eigvalsh(kuka.pseudo_inertias(fit.pi))[:, 0].min() > 0
    assert fit.consistent
    cad = kuka.link_masses(truth)
    for link, mass in fit.details["link_masses"].items():
        assert 0.5 * cad[link] - 1e-6 <= mass <= 1.5 * cad[link] + 1e-6
    # noise-free data of a consistent arm: the fit reproduces the torques (the prior only moves unseen directions)
    np.testing.assert_allclose(fit.rss, 0.0, atol=1e-6 * stats.s.max())


def test_a_heavy_prior_returns_the_cad_inertials(kuka, simulated):
    _, stats = simulated
    cad = kuka.cad_parameters()
    fit = fit_physical(stats, kuka, prior_weight=1e2, mass_range=None, com_box=None)
    np.testing.assert_allclose(fit.pi[: kuka.n_link_params], cad[: kuka.n_link_params], rtol=1e-3, atol=1e-5)
    J0 = kuka.pseudo_inertias(cad)
    assert log_det_divergence(J0[0], J0[0]) == pytest.approx(0.0, abs=1e-12)
    assert log_det_divergence(2 * J0[0], J0[0]) == pytest.approx(4 - 4 * np.log(2))


def _objective(arm: ChainArm, stats: Stats, pi: np.ndarray, weight: float) -> float:
    """The plausible fit's objective (module doc of identify.physical) up to a constant, at π."""
    H, h = stats.combined()[:2]
    J0 = arm.pseudo_inertias(arm.cad_parameters())
    J = arm.pseudo_inertias(pi)
    prior = sum(np.trace(np.linalg.solve(a, b)) - np.linalg.slogdet(b)[1] for a, b in zip(J0, J))
    return float((pi @ H @ pi - 2 * h @ pi) / stats.n + weight * stats.s.sum() / stats.n * prior)


def test_direct_clarabel_program_matches_the_cvxpy_oracle(kuka, simulated):
    _, clean = simulated
    rng = np.random.default_rng(9)
    noisy = Stats(clean.G, clean.b + rng.normal(scale=0.05, size=clean.b.shape), clean.s + 1.0, clean.n)
    direct = fit_physical(noisy, kuka, prior_weight=1e-3)
    oracle = fit_physical(noisy, kuka, prior_weight=1e-3, backend="cvxpy")
    assert direct.consistent and oracle.consistent
    f_direct, f_oracle = (_objective(kuka, noisy, fit.pi, 1e-3) for fit in (direct, oracle))
    assert f_direct <= f_oracle + 1e-7 * abs(f_oracle)  # the same minimum (the direct one at least as low)
    # the minimiser is flat along what the data hardly see: the same point to a percent of the largest π
    np.testing.assert_allclose(direct.pi, oracle.pi, atol=1e-2 * np.abs(oracle.pi).max())
