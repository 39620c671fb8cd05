"""Background realism terms (stiction, drift, ripple): off by default, exact at magnitude 0, each with its
signature, kept out of the diagnosis catalogue; and the calibrated default resembles the real exp1."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import signal

from ident_opt.arm.planar import RIGID, PlanarArm
from ident_opt.data.loader import load_dataset
from ident_opt.effects import BACKGROUND, describe
from ident_opt.fitting.ols import solve_ols
from ident_opt.fitting.stats import Stats
from ident_opt.problem import load_problem
from ident_opt.simulator import CATALOGUE, parse_effect, simulate_trial

ROOT = Path(__file__).resolve().parents[1]
MODEL = PlanarArm(("armature",))
EXACT = {"noise": False, "exact_derivatives": True, "progress": False}


@pytest.fixture(scope="module")
def robot():
    return load_problem(ROOT / "problems" / "tudor_2dof.toml").robot


def true_residual(trial):
    """τ − Y(q, dq, ddq) π_true [N m]: what the truth's rigid part does not explain."""
    d = trial.dataset()
    return d.tau - MODEL.predict(MODEL.vector(trial.truth["pi"]), d.q, d.dq, d.ddq)


def test_background_terms_are_not_in_the_diagnosis_catalogue():
    names = {
        "armature",
        "asymmetric_coulomb",
        "stribeck",
        "elasticity",
        "payload",
        "delay",
        "joint_offset",
        "torque_scale",
        "load_friction",
        "torque_offset",
    }
    assert set(CATALOGUE) == names
    assert set(BACKGROUND) == {"stiction", "drift", "ripple", "contact"} and not set(BACKGROUND) & names
    assert parse_effect("stiction:breakaway=[0.5,0.4]") == ("stiction", {"breakaway": (0.5, 0.4)})
    text = describe()
    assert all(f"  {name}:" in text for name in BACKGROUND)


@pytest.mark.parametrize(
    "effect",
    [
        "stiction:scale=0",
        "stiction:breakaway=[0,0]",
        "drift:std=[0,0]",
        "drift:scale=0",
        "ripple:amplitude=[0,0]",
        "ripple:scale=0",
    ],
)
def test_magnitude_zero_reproduces_the_clean_trial_exactly(robot, effect):
    base = simulate_trial(robot, duration=3.0, seed=2, progress=False)
    trial = simulate_trial(robot, duration=3.0, seed=2, effects=[effect], progress=False)
    pd.testing.assert_frame_equal(trial.frame, base.frame, check_exact=True)
    assert trial.truth["background"] == {} and trial.truth["effects"] == {}


def test_background_values_go_to_the_truth_background_not_its_effects(robot):
    trial = simulate_trial(
        robot, duration=2.0, effects=["payload:mass=0.1", "drift:std=[0.3,0.1],time=2"], progress=False
    )
    assert set(trial.truth["effects"]) == {"payload"}
    assert trial.truth["background"] == {"drift": {"std": [0.3, 0.1], "time": 2.0}}


def test_same_seed_same_background_other_seed_other(robot):
    effects = ["stiction", "drift", "ripple"]
    a, b, c = (simulate_trial(robot, duration=3.0, seed=s, effects=effects, progress=False) for s in (4, 4, 5))
    pd.testing.assert_frame_equal(a.frame, b.frame, check_exact=True)
    assert not np.allclose(a.frame["tau2"], c.frame["tau2"])


def test_a_resting_joint_holds_the_torque_its_last_motion_left(robot):
    """Stiction: at rest after a move, τ − G(q) is about the breakaway level, with the sign of that move
    (hysteresis); without it the same rests hold almost nothing."""
    kwargs = {**EXACT, "duration": 30.0, "seed": 3}
    breakaway = 0.6
    for effects in ([], [f"stiction:breakaway=[{breakaway},{breakaway}]"]):
        trial = simulate_trial(robot, effects=effects, **kwargs)
        d = trial.dataset()
        hold = d.tau - MODEL.predict(MODEL.vector(trial.truth["pi"]), d.q, 0 * d.dq, 0 * d.ddq)
        for j in range(2):
            # Rests and directions from the commanded reference: the joint is told to rest.
            q_ref = trial.frame[f"q{j + 1}_ref"].to_numpy()
            step = np.diff(q_ref, prepend=q_ref[0])
            moving = np.abs(step) > 0
            index = np.maximum.accumulate(np.where(moving, np.arange(len(d.t)), 0))
            last = np.sign(step)[index] * moving[index]  # direction of the last commanded move
            settled = np.arange(len(d.t)) - index > 30  # still for more than 0.3 s
            rest = settled & (last != 0)
            assert rest.sum() > 100
            h = hold[rest, j]
            if effects:
                assert np.mean(np.sign(h) == last[rest]) > 0.9
                assert 0.5 * breakaway < np.abs(h).mean() < 1.5 * breakaway
            else:
                assert np.abs(h).mean() < 0.1 * breakaway


def test_drift_is_a_slow_disturbance_of_the_stated_size_and_time(robot):
    """With exact derivatives the rigid truth leaves exactly −d(t): an OU process of the stated σ and time."""
    std, time = (0.5, 0.2), 0.25
    trial = simulate_trial(
        robot, effects=[f"drift:std=[{std[0]},{std[1]}],time={time}"], duration=40.0, seed=1, **EXACT
    )
    r = true_residual(trial)
    clean = true_residual(simulate_trial(robot, duration=40.0, seed=1, **EXACT))
    assert np.abs(clean).max() < 1e-6
    # 160 correlation times: the sample σ has a standard error of about 6 % (√(T / 2L)); 20 % is > 3 of them.
    np.testing.assert_allclose(r.std(0), std, rtol=0.2)
    lag = 25  # samples at 100 Hz: 0.25 s, one correlation time
    for j in range(2):
        x = r[:, j] - r[:, j].mean()
        rho = (x[:-lag] * x[lag:]).mean() / x.var()
        assert rho == pytest.approx(np.exp(-lag / 100.0 / time), abs=0.12)


def test_ripple_is_a_line_at_the_motor_rotation_frequency_while_moving(robot):
    """Ripple: once per motor revolution, at 230 × 1.12 rad/s / 2π ≈ 41 Hz on joint 1's speed plateau; it is a
    real torque, so with exact derivatives the rigid truth still holds, and with estimated ones it shows."""
    effect = ["ripple:amplitude=[1,0]"]
    kwargs = {"duration": 20.0, "seed": 1, "rate_hz": 1000.0, "noise": False, "progress": False}
    exact = simulate_trial(robot, effects=effect, exact_derivatives=True, **{**kwargs, "rate_hz": 100.0})
    assert np.abs(true_residual(exact)).max() < 1e-6
    spectra = []
    for effects in ([], effect):
        r = true_residual(simulate_trial(robot, effects=effects, **kwargs))
        f, P = signal.welch(r[:, 0], fs=1000.0, nperseg=4096)
        spectra.append(P)
    band = (f > 20) & (f < 80)
    line = 230.0 * 1.12 / (2 * np.pi)
    assert f[band][np.argmax(spectra[1][band])] == pytest.approx(line, abs=1.5)
    near = np.abs(f - line) < 2
    assert spectra[1][near].sum() > 20 * spectra[0][near].sum()  # an order of magnitude above


def test_default_simulated_trial_resembles_exp1(robot):
    """The calibrated default (problems/tudor_sim.toml): rigid-fit residual RMS per joint within ±25 % of the
    real exp1's, and the share of its power below 0.6 Hz within ±10 points."""
    real_problem = load_problem(ROOT / "problems" / "tudor_2dof.toml")
    sim = load_problem(ROOT / "problems" / "tudor_sim.toml")
    spec = sim.simulate
    real = load_dataset(real_problem.data.trials[0], real_problem.data, real_problem.robot)
    trial = simulate_trial(
        sim.robot, duration=spec.duration, seed=spec.seed, effects=list(spec.effects), progress=False
    )
    out = []
    for d in (real, trial.dataset()):
        pi = solve_ols(Stats.from_data(RIGID, d.q, d.dq, d.ddq, d.tau))
        r = d.tau - RIGID.predict(pi, d.q, d.dq, d.ddq)
        f, P = signal.welch(r, fs=d.rate_hz, nperseg=1024, axis=0)
        out.append((np.sqrt((r**2).mean(0)), P[f < 0.6].sum(0) / P.sum(0)))
    (rms_real, low_real), (rms_sim, low_sim) = out
    np.testing.assert_array_less(np.abs(rms_sim / rms_real - 1), 0.25)
    np.testing.assert_array_less(np.abs(low_sim - low_real), 0.10)
