"""Models and protocols on short simulated trials (the datasheet, read physically, is the simulator's truth)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ident_opt.arm.planar import RIGID
from ident_opt.data.dataset import shuffled_split
from ident_opt.models.hybrid import HybridModel, RidgeModel, RigidModel, datasheet_model, features, make_gmr
from ident_opt.paper.protocols import chronological_protocol, evaluate_split, paper_protocol
from ident_opt.problem import ResidualSpec, SplitSpec, load_problem
from ident_opt.simulator.trial import simulate_trial

PROBLEM = "problems/tudor_2dof.toml"


@pytest.fixture(scope="module")
def problem():
    p = load_problem(PROBLEM)
    # small candidate set and sample cap: same code paths, test-sized cost
    return replace(p, residual=ResidualSpec(candidates=(1, 3, 6), max_train_samples=3000), split=SplitSpec(0.7, (0, 1)))


@pytest.fixture(scope="module")
def trial(problem):
    return simulate_trial(problem.robot, duration=30.0, rate_hz=100.0, seed=3, progress=False).dataset()


def _known_residual(x: np.ndarray) -> np.ndarray:
    """A smooth nonlinear torque error no rigid model has [N m]: position- and velocity-dependent."""
    return np.column_stack(
        [0.6 * np.sin(2 * x[:, 0]) + 0.3 * np.tanh(3 * x[:, 2]), 0.4 * np.cos(x[:, 0] + x[:, 1]) * np.tanh(2 * x[:, 3])]
    )


def test_gmr_recovers_a_known_residual_added_to_simulated_data(problem):
    # A noise-free rigid simulation (truth = the physical datasheet, exact derivatives), plus a known
    # nonlinear residual and white noise of 0.05 N m: the GMR on the datasheet model's residual must
    # recover the known residual on held-out samples (nMSE of the residual estimate < 0.1).
    sim = simulate_trial(
        problem.robot, duration=30.0, seed=3, noise=False, exact_derivatives=True, progress=False
    ).dataset()
    added = _known_residual(features(sim))
    noise = np.random.default_rng(0).normal(scale=0.05, size=added.shape)
    data = replace(sim, tau=sim.tau + added + noise)
    train, test = shuffled_split(data.n, 0.7, 0)
    spec = replace(problem.residual, candidates=(1, 3, 6, 10))
    hybrid = HybridModel(datasheet_model(problem.robot, "physical"), make_gmr(spec)).fit(data.subset(train))
    test_set = data.subset(test)
    est = hybrid.gmr.predict_mean(features(test_set))
    nmse = np.mean((est - added[test]) ** 2, axis=0) / np.var(added[test], axis=0)
    assert (nmse < 0.1).all(), nmse
    # and the hybrid predicts the torques far better than the datasheet model alone
    base_err = np.mean((test_set.tau - hybrid.base.predict(test_set)) ** 2, axis=0)
    hyb_err = np.mean((test_set.tau - hybrid.predict(test_set)) ** 2, axis=0)
    assert (hyb_err < 0.2 * base_err).all()


@pytest.mark.parametrize(
    "make_base",
    [
        lambda robot: RidgeModel(),
        lambda robot: datasheet_model(robot, "paper"),
        lambda robot: RigidModel("pbr", RIGID, estimator="ols"),
    ],
)
def test_residual_correction_never_worse_on_training_data(trial, problem, make_base):
    data = replace(trial, tau=trial.tau + _known_residual(features(trial)))
    base = make_base(problem.robot)
    hybrid = HybridModel(base, make_gmr(problem.residual)).fit(data)
    base_mse = np.mean((data.tau - base.predict(data)) ** 2, axis=0)
    hyb_mse = np.mean((data.tau - hybrid.predict(data)) ** 2, axis=0)
    assert (hyb_mse <= base_mse).all(), (hyb_mse, base_mse)


def test_ridge_reports_its_penalty(trial):
    rr = RidgeModel().fit(trial)
    assert rr.alpha_.shape == (2,) and np.all(rr.alpha_ > 0)
    assert rr.predict(trial).shape == (trial.n, 2)


def test_paper_protocol_averages_seeds_and_reports_everything(trial, problem):
    result = paper_protocol(trial, problem)
    keys = {"rr", "dm", "dm_physical", "pbr", "cpbr"}
    keys |= {k + "+gmr" for k in keys}
    for metric in ("rmse", "nmse", "nmse_range"):
        assert set(result.metrics[metric]) == keys
        assert all(np.isfinite(v).all() and len(v) == 2 for v in result.metrics[metric].values())
    assert set(result.coverage) == {k for k in keys if k.endswith("+gmr")}
    assert all(0 <= c <= 1 for v in result.coverage.values() for c in v)
    # the mean over seeds is the mean of the per-seed values
    per_seed = np.array(result.rmse_per_split["pbr"])
    assert per_seed.shape == (2, 2)
    np.testing.assert_allclose(result.metrics["rmse"]["pbr"], per_seed.mean(axis=0))
    # components chosen on the first seed are reused, and are among the candidates
    assert set(result.components.values()) <= set(problem.residual.candidates)


def test_chronological_protocol_trains_on_the_past(trial, problem):
    result = chronological_protocol(trial, problem, constrained=False)
    test_t = result.example.test.t
    assert test_t[0] >= trial.t[round(0.7 * trial.n) - 1]
    assert "cpbr" not in result.metrics["rmse"]


def test_evaluate_split_with_fixed_diagonal_gmr(trial, problem):
    train, test = shuffled_split(trial.n, 0.7, 0)
    r = evaluate_split(
        trial.subset(train),
        trial.subset(test),
        problem,
        constrained=False,
        components={"pbr+gmr": 2},
        covariance="diag",
    )
    assert r.components["pbr+gmr"] == 2
    g = r.models["pbr+gmr"].gmr
    assert np.all(g.covariances_ * (1 - np.eye(8)) == 0)
