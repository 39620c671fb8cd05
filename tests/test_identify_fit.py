"""OLS from sufficient statistics: equals lstsq on the full regressor; SEs cover the truth; diagnostics."""

from __future__ import annotations

import numpy as np
import pytest

from ident_opt.arm.datasheet import datasheet_pi
from ident_opt.arm.planar import PlanarArm
from ident_opt.evaluation.constraints import multisine_trial
from ident_opt.fitting.constrained import fit_constrained
from ident_opt.fitting.fit import base_combinations, fit_ols
from ident_opt.fitting.ols import solve_ols
from ident_opt.fitting.stats import Stats
from ident_opt.parameters import Parameter

RIGID = PlanarArm()


@pytest.fixture(scope="module")
def truth(physical_problem):
    return RIGID.vector(datasheet_pi(physical_problem.robot, "physical"))


def _stats(trial, model=RIGID):
    return Stats.from_data(model, trial.q, trial.dq, trial.ddq, trial.tau, chunk=333)


def test_ols_equals_lstsq_on_full_matrix(truth):
    trial = multisine_trial(RIGID, truth, duration=20.0, seed=3)
    Y = RIGID.regressor(trial.q, trial.dq, trial.ddq)
    expected = np.linalg.lstsq(Y.reshape(-1, RIGID.n_params), trial.tau.reshape(-1), rcond=None)[0]
    fit = fit_ols(_stats(trial), RIGID)
    np.testing.assert_allclose(fit.pi, expected, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(solve_ols(_stats(trial)), expected, rtol=1e-9, atol=1e-12)
    assert fit.rank == RIGID.n_params and np.isfinite(fit.cond) and fit.method == "ols"
    assert set(fit.as_dict()) == set(RIGID.names)


def test_weighted_ols_equals_lstsq_on_weighted_rows(truth):
    trial = multisine_trial(RIGID, truth, duration=10.0, seed=4, noise=(1.0, 0.1))
    w = np.array([0.25, 9.0])
    Y = RIGID.regressor(trial.q, trial.dq, trial.ddq) * np.sqrt(w)[None, :, None]
    expected = np.linalg.lstsq(Y.reshape(-1, RIGID.n_params), (trial.tau * np.sqrt(w)).reshape(-1), rcond=None)[0]
    np.testing.assert_allclose(fit_ols(_stats(trial), RIGID, weights=w).pi, expected, rtol=1e-9, atol=1e-12)
    wls = fit_ols(_stats(trial), RIGID, weights="wls")
    # WLS weights are 1/σ_j²: the noisier joint 1 gets the smaller weight, about (0.1/1.0)² of joint 2's.
    assert 0.005 < wls.weights[0] / wls.weights[1] < 0.02


def test_per_joint_residual_variance_matches_noise(truth):
    trial = multisine_trial(RIGID, truth, duration=60.0, seed=5, noise=(0.5, 0.2))
    fit = fit_ols(_stats(trial), RIGID)
    np.testing.assert_allclose(fit.sigma2, [0.25, 0.04], rtol=0.1)


def test_standard_errors_cover_the_truth(truth):
    """Over 40 rigid trials, the truth lies within ±2 SE about 95 % of the time for every parameter."""
    inside = []
    for seed in range(40):
        trial = multisine_trial(RIGID, truth, duration=8.0, seed=100 + seed, noise=(0.5, 0.3))
        fit = fit_ols(_stats(trial), RIGID)
        inside.append(np.abs(fit.pi - truth) <= 2 * fit.se)
    rate = np.mean(inside)
    assert 0.9 <= rate <= 0.99, rate
    assert np.mean(inside, axis=0).min() >= 0.8  # no parameter's SE is badly off


def test_unexcited_joint_is_named(truth):
    trial = multisine_trial(RIGID, truth, duration=5.0, seed=6, amplitude=(0.8, 0.0))
    fit = fit_ols(_stats(trial), RIGID)
    assert fit.rank == 7
    assert set(fit.unexcited) == {"fv2", "fc2"}
    assert {"fv2", "fc2"} <= set(fit.poorly_determined)
    assert any("not excited: fv2, fc2" in w for w in fit.warnings)


def test_base_combinations_of_dependent_columns():
    rng = np.random.default_rng(0)
    Y = rng.normal(size=(200, 3))
    Y = np.column_stack([Y, 2.0 * Y[:, 0] - 0.5 * Y[:, 1]])  # column 3 = 2·col0 − 0.5·col1
    rank, _cond, unexcited, base = base_combinations(Y.T @ Y, ("p0", "p1", "p2", "p3"))
    assert rank == 3 and unexcited == []
    # Each listed combination π_i + c·π_k must be invariant along the null direction of Y (Y n = 0).
    null = np.array([2.0, -0.5, 0.0, -1.0])
    np.testing.assert_allclose(Y @ null, 0.0, atol=1e-10)
    names = ("p0", "p1", "p2", "p3")
    assert len(base) == 2
    for combo in base:
        first, rest = combo.split()
        c, other = rest.split("·")
        along = null[names.index(first)] + float(c) * null[names.index(other)]
        assert along == pytest.approx(0.0, abs=1e-3), combo


def test_consistency_is_checked(truth):
    fit = fit_ols(_stats(multisine_trial(RIGID, truth, duration=20.0, seed=7)), RIGID)
    assert fit.consistent and fit.min_mass_eigenvalue > 0
    assert fit.min_mass_eigenvalue == pytest.approx(RIGID.min_mass_eigenvalue(fit.pi))


def test_mismatched_statistics_rejected(truth):
    trial = multisine_trial(RIGID, truth, duration=3.0, seed=8)
    with pytest.raises(ValueError):
        fit_ols(_stats(trial), PlanarArm(("armature",)))
    with pytest.raises(ValueError):
        fit_ols(_stats(trial), RIGID, weights="nonsense")


class ThreePendulums:
    """Three decoupled joints τ_j = I_j ddq_j + fv_j dq_j (test only): the part of the `Arm` interface the
    estimators use, for a number of joints other than two. Its mass LMIs are 1×1: I_j ⪰ margin."""

    n_joints = 3
    parameters = tuple(Parameter(f"I{j}", "kg m^2", f"joint-{j} inertia", "inertia") for j in (1, 2, 3)) + tuple(
        Parameter(f"fv{j}", "N m s/rad", f"joint-{j} viscous friction", "friction") for j in (1, 2, 3)
    )
    names = tuple(p.name for p in parameters)
    n_params = 6

    def regressor(self, q, dq, ddq):
        Y = np.zeros((len(q), 3, 6))
        for j in range(3):
            Y[:, j, j], Y[:, j, 3 + j] = ddq[:, j], dq[:, j]
        return Y

    def mass_lmis(self):
        return {f"inertia_{j + 1}": np.eye(6)[:, j, None, None] for j in range(3)}

    def min_mass_eigenvalue(self, pi):
        return float(np.min(pi[:3]))


def test_estimators_take_any_number_of_joints():
    """Statistics, (weighted) OLS and the constrained fit work from the arm's n_joints and declarations."""
    arm = ThreePendulums()
    rng = np.random.default_rng(0)
    q, dq, ddq = (rng.normal(size=(400, 3)) for _ in range(3))
    pi_true = np.array([0.5, 0.2, 0.1, 0.3, 0.2, -0.02])  # fv3 < 0: a sign constraint must bind
    tau = arm.regressor(q, dq, ddq) @ pi_true + rng.normal(size=(400, 3)) * np.array([0.01, 0.05, 0.01])
    st = Stats.from_data(arm, q, dq, ddq, tau)
    assert st.G.shape == (3, 6, 6) and st.n_joints == 3
    ols, wls = fit_ols(st, arm), fit_ols(st, arm, weights="wls")
    assert ols.weights.shape == wls.weights.shape == (3,) and wls.weights[1] < wls.weights[0]
    np.testing.assert_allclose(ols.pi, pi_true, atol=0.01)
    assert not ols.friction_ok and ols.sign_violations == {"friction": ["fv3"]}
    con = fit_constrained(st, arm, margin=1e-4)
    assert con.active == ["friction_fv3"] and con.consistent and con.as_dict()["fv3"] == pytest.approx(0, abs=1e-9)
    with pytest.raises(ValueError, match="3 positive"):
        fit_ols(st, arm, weights=np.ones(2))
