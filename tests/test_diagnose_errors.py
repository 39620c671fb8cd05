"""Standard errors of the reported model: every coefficient and every searched θ together, residual
correlation counted (`candidates.joint_errors`, `linear.sandwich`). Checked against the truth of simulated trials
on seeds not used while writing it (500–505): z = (estimate − truth) / se must look like the noise's."""

from __future__ import annotations

import numpy as np
import pytest

from ident_opt.diagnosis import diagnose_trial, hidden
from ident_opt.numerics.least_squares import hac_lag, sandwich


def test_hac_lag_grows_with_the_residuals_correlation():
    rng = np.random.default_rng(0)
    white = rng.normal(size=(20000, 2))
    assert hac_lag(white) <= 3
    box = np.ones(20) / 20.0  # a 20-sample moving average: correlated over about 20 samples
    smooth = np.column_stack([np.convolve(white[:, j], box, mode="same") for j in range(2)])
    assert 25 <= hac_lag(smooth) <= 60


def test_the_sandwich_reads_each_joints_own_noise_whatever_the_weights_say():
    """Two joints, one column each, white residuals of σ = 0.1 and 2.0: least squares with the weights 1/σ² gives
    σ_j / |x_j|; the sandwich must give the same with weights a hundred times wrong (a joint's variance from a model
    that lacked a cause), where the pooled least-squares error is off by the weights' error."""
    rng = np.random.default_rng(3)
    N, sigma = 20000, np.array([0.1, 2.0])
    X = np.zeros((N, 2, 2))
    X[:, 0, 0], X[:, 1, 1] = rng.normal(size=N), rng.normal(size=N)
    r = rng.normal(size=(N, 2)) * sigma
    exact = sigma / np.linalg.norm(X[:, [0, 1], [0, 1]], axis=0)
    for weights in (1.0 / sigma**2, np.array([1e-2, 1.0]) / sigma**2):
        assert np.allclose(sandwich(X, r, weights), exact, rtol=0.05)
    # residuals correlated over ~20 samples with a column that is too: errors about √20 wider than white ones
    box = np.ones(20) / np.sqrt(20.0)
    slow = np.column_stack([np.convolve(r[:, j], box, mode="same") for j in range(2)])
    Xs = np.zeros_like(X)
    for j in range(2):
        Xs[:, j, j] = np.convolve(X[:, j, j], box, mode="same")
    wide = sandwich(Xs, slow, 1.0 / sigma**2) / (sigma / np.linalg.norm(Xs[:, [0, 1], [0, 1]], axis=0))
    assert np.all((wide > 2.5) & (wide < 6.0)), wide


@pytest.mark.slow
def test_offset_standard_errors_cover_the_noise(physical_problem):
    """Encoder offsets are limited by the torque noise (noise-free trials find them within 1 mrad), so their
    standard errors must cover the errors: RMS z near 1. Independent-residual errors, about half as large,
    gave RMS z ≈ 1.6 here."""
    from ident_opt.simulator import simulate_trial

    robot = physical_problem.robot
    z = []
    for seed in range(500, 506):
        effects = {"joint_offset": hidden.draw("joint_offset", np.random.default_rng([seed, 7]), robot)}
        trial = simulate_trial(robot, trajectory="tud01", duration=80.0, seed=seed, effects=effects, progress=False)
        d = diagnose_trial(robot, trial.dataset(), progress=False)
        assert d.cause == "joint_offset", [(c["cause"], c["score"]) for c in d.candidates[:3]]
        se = d.as_json()["extended_model"]["standard_errors"]
        assert all(isinstance(se[k], float) and se[k] > 0 for k in ("delta1", "delta2"))
        truth = effects["joint_offset"]["offset"]
        z += [(d.named.parameters[k] - t) / se[k] for k, t in zip(("delta1", "delta2"), truth)]
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.5 <= rms <= 1.4, (rms, np.round(z, 2))
    assert max(np.abs(z)) < 3.0, np.round(z, 2)
