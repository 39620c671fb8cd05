"""Logging rates: slower logs are decimations of the 1 kHz loop; faster logs run the loop at their own rate."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ident_opt.arm.planar import PlanarArm
from ident_opt.errors import InputError
from ident_opt.fitting.ols import solve_ols
from ident_opt.fitting.stats import Stats
from ident_opt.problem import load_problem
from ident_opt.simulator import simulate_trial
from ident_opt.simulator.closed_loop import MAX_TRACKING_ERROR

PROBLEM = Path(__file__).resolve().parents[1] / "problems" / "tudor_2dof.toml"
MODEL = PlanarArm(("armature",))
CLEAN = {"duration": 6.0, "seed": 2, "noise": False, "exact_derivatives": True, "progress": False}


@pytest.fixture(scope="module")
def robot():
    return load_problem(PROBLEM).robot


@pytest.fixture(scope="module")
def trials(robot):
    return {rate: simulate_trial(robot, rate_hz=rate, **CLEAN) for rate in (500.0, 1000.0, 2000.0)}


def test_slower_logs_are_every_other_sample_of_the_same_1khz_loop(trials):
    slow, fast = trials[500.0], trials[1000.0]
    assert slow.truth["controller"]["control_hz"] == fast.truth["controller"]["control_hz"] == 1000.0
    # Same loop, only decimated: equal bit for bit, not merely close.
    np.testing.assert_array_equal(slow.frame.to_numpy(), fast.frame.iloc[::2].to_numpy())


def test_2khz_log_is_a_2khz_loop_not_an_upsampled_1khz_one(trials):
    f = trials[2000.0].frame
    assert trials[2000.0].truth["controller"]["control_hz"] == 2000.0
    assert len(f) == 12000 and np.allclose(np.diff(f["t"]), 5e-4)
    # The torque is updated every 0.5 ms: a 1 kHz zero-order hold would repeat each value at the odd samples.
    tau = f[["tau1", "tau2"]].to_numpy()
    moving = np.abs(f[["dq1", "dq2"]].to_numpy()).max(1) > 0.1
    changed = np.abs(tau[1::2] - tau[0::2]).max(1) > 1e-9
    assert changed[moving[0::2]].mean() > 0.99


def test_2khz_clean_trial_satisfies_the_rigid_model_and_tracks_the_1khz_one(trials, robot):
    fast, base = trials[2000.0], trials[1000.0]
    d = fast.dataset()
    pi = solve_ols(Stats.from_data(MODEL, d.q, d.dq, d.ddq, d.tau))
    np.testing.assert_allclose(pi, MODEL.vector(fast.truth["pi"]), rtol=1e-6)
    # Same gains, faster hold: the clean loop tracks its reference within the stated clean limit.
    error = fast.frame[["q1", "q2"]].to_numpy() - fast.frame[["q1_ref", "q2_ref"]].to_numpy()
    assert np.abs(error).max() < MAX_TRACKING_ERROR["clean"]
    assert fast.truth["controller"]["kp"] == base.truth["controller"]["kp"]


def test_rates_neither_dividing_1khz_nor_within_the_fast_range_are_input_errors(robot):
    for rate in (300.0, 1e4, -2000.0):
        with pytest.raises(InputError, match="control rate"):
            simulate_trial(robot, rate_hz=rate, duration=1.0, progress=False)
