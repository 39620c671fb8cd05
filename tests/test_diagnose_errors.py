"""Standard errors of the reported model: every coefficient and every searched θ together, residual
correlation counted (`candidates.joint_errors`). Checked against the truth of simulated trials on seeds not
used while writing it (500–505): z = (estimate − truth) / se must look like the noise's."""

from __future__ import annotations

import numpy as np
import pytest

from ident_opt.diagnosis import diagnose, hidden
from ident_opt.diagnosis.candidates import hac_lag


def test_hac_lag_grows_with_the_residuals_correlation():
    rng = np.random.default_rng(0)
    white = rng.normal(size=(20000, 2))
    assert hac_lag(white) <= 3
    box = np.ones(20) / 20.0  # a 20-sample moving average: correlated over about 20 samples
    smooth = np.column_stack([np.convolve(white[:, j], box, mode="same") for j in range(2)])
    assert 25 <= hac_lag(smooth) <= 60


@pytest.mark.slow
def test_offset_standard_errors_cover_the_noise(physical_problem):
    """Encoder offsets are limited by the torque noise (noise-free trials find them within 1 mrad), so their
    standard errors must cover the errors: RMS z near 1. Independent-residual errors, about half as large,
    gave RMS z ≈ 1.6 here."""
    from ident_opt.simulate import simulate_trial

    robot = physical_problem.robot
    z = []
    for seed in range(500, 506):
        effects = {"joint_offset": hidden.draw("joint_offset", np.random.default_rng([seed, 7]), robot)}
        trial = simulate_trial(robot, trajectory="tud01", duration=80.0, seed=seed, effects=effects, progress=False)
        d = diagnose(robot, trial.dataset(), progress=False)
        assert d.cause == "joint_offset", [(c["cause"], c["score"]) for c in d.candidates[:3]]
        se = d.as_json()["extended_model"]["standard_errors"]
        assert all(isinstance(se[k], float) and se[k] > 0 for k in ("delta1", "delta2"))
        truth = effects["joint_offset"]["offset"]
        z += [(d.named.parameters[k] - t) / se[k] for k, t in zip(("delta1", "delta2"), truth)]
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.5 <= rms <= 1.4, (rms, np.round(z, 2))
    assert max(np.abs(z)) < 3.0, np.round(z, 2)
