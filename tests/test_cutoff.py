"""The derivative cut-off read from the data (`derivative_cutoff_hz = "auto"`): it sits just above the
motion's band, and on a noisy trial it removes most of the errors-in-variables bias a fixed 15 Hz leaves."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from ident_opt.arm.datasheet import datasheet_pi
from ident_opt.arm.planar import PHYSICAL
from ident_opt.data import load_dataset
from ident_opt.derivatives import choose_cutoff
from ident_opt.identify.fit import fit_ols
from ident_opt.identify.stats import Stats
from ident_opt.problem import DataSpec, load_problem

from .conftest import PROBLEMS


def multisine(t: np.ndarray, top_hz: float, seed: int) -> np.ndarray:
    """Two joints, each a sum of sinusoids at 0.2 .. top_hz [rad]."""
    rng = np.random.default_rng(seed)
    freqs = np.linspace(0.2, top_hz, 6)
    q = np.zeros((t.size, 2))
    for j in range(2):
        amp = 0.4 / (1 + freqs) * rng.uniform(0.5, 1.0, freqs.size)
        q[:, j] = (amp[:, None] * np.sin(2 * np.pi * freqs[:, None] * t + rng.uniform(0, 6, freqs.size)[:, None])).sum(
            0
        )
    return q


@pytest.mark.parametrize(("rate", "top_hz"), [(500.0, 2.0), (1000.0, 5.0), (200.0, 1.0)])
def test_cutoff_sits_just_above_the_motion_band(rate, top_hz):
    t = np.arange(0, 20, 1 / rate)
    q = multisine(t, top_hz, seed=1) + np.random.default_rng(2).normal(0, 2e-4, (t.size, 2))  # encoder noise
    fc = choose_cutoff(t, q)
    assert top_hz < fc < 2.5 * top_hz


def trial(tmp_path, rate: float, noise: float, seed: int):
    """A noisy trial of the physical TUDOR model (truth = its datasheet π), written as a CSV without dq, ddq."""
    problem = load_problem(PROBLEMS / "tudor_2dof.toml")
    pi = PHYSICAL.vector(datasheet_pi(problem.robot))
    t = np.arange(0, 30, 1 / rate)
    q = multisine(t, 1.5, seed) + np.pi / 4
    dq, ddq = np.gradient(q, t, axis=0), np.gradient(np.gradient(q, t, axis=0), t, axis=0)
    tau = PHYSICAL.predict(pi, q, dq, ddq)
    q_meas = q + np.random.default_rng(seed).normal(0, noise, q.shape)
    path = tmp_path / f"noisy{seed}.csv"
    frame = {"t": t, "q1": q_meas[:, 0], "q2": q_meas[:, 1], "tau1": tau[:, 0], "tau2": tau[:, 1]}
    pd.DataFrame(frame).to_csv(path, index=False)
    return path, problem.robot, pi


def test_auto_cutoff_reduces_the_errors_in_variables_bias(tmp_path):
    errors = {}
    for setting in ("auto", 15.0):
        rel = []
        for seed in (3, 4):
            path, robot, pi = trial(tmp_path, rate=500.0, noise=5e-4, seed=seed)
            d = load_dataset(path, DataSpec(derivative_cutoff_hz=setting), robot)
            fit = fit_ols(Stats.from_data(PHYSICAL, d.q, d.dq, d.ddq, d.tau), PHYSICAL)
            inertial = [PHYSICAL.names.index(n) for n in ("a1", "a2", "a3", "b1", "b2")]
            rel.append(np.median(np.abs(fit.pi[inertial] / pi[inertial] - 1)))
        errors[setting] = np.median(rel)
        if setting == "auto":
            assert d.cutoff_hz < 5.0 and "chosen from where the motion's spectrum ends" in d.derivatives
    assert errors["auto"] < 0.5 * errors[15.0]


def test_auto_in_a_problem_file(tmp_path):
    problem = load_problem(PROBLEMS / "dfki_c0.toml")
    assert problem.data.derivative_cutoff_hz == "auto"
    d = load_dataset(problem.data.trials[0], problem.data, problem.robot)
    assert 2.0 < d.cutoff_hz < 10.0
