"""Unit tests of the diagnosis tools: signals, linear solves, the naming rule, rest handling."""

from __future__ import annotations

import numpy as np
import pytest

from ident_opt.data.dataset import Dataset
from ident_opt.diagnosis import scoring
from ident_opt.diagnosis.split import at_rest, compared_warnings, split
from ident_opt.effects.elasticity import ELASTIC_BAND_HZ
from ident_opt.numerics import least_squares as linear
from ident_opt.numerics import signals


def test_delayed_shifts_a_ramp_by_a_fraction_of_a_sample():
    dt = 0.01
    x = np.arange(100, dtype=float)[:, None] * np.array([[1.0, -2.0]])
    y = signals.delayed(x, 0.0237, dt)  # 2.37 samples
    assert np.allclose(y[10:], x[10:] - 2.37 * np.array([1.0, -2.0]))


def test_deflection_filter_resonates_at_the_mode():
    dt, f0 = 0.001, 6.0
    n = 20000
    impulse = np.zeros(n)
    impulse[0] = 1.0
    h = signals.deflection_acceleration(impulse, f0, 0.02, dt)
    freqs = np.fft.rfftfreq(n, dt)
    peak = freqs[np.argmax(np.abs(np.fft.rfft(h)))]
    assert abs(peak - f0) < 0.1
    # High-pass: a constant acceleration leaves no deflection acceleration in steady state.
    step = signals.deflection_acceleration(np.ones(n), f0, 0.5, dt)
    assert abs(step[-1]) < 1e-6


def test_spectral_peak_frequency_and_damping():
    dt = 0.01
    rng = np.random.default_rng(0)
    white = rng.normal(size=60000)
    x = signals.deflection_acceleration(white, 4.0, 0.03, dt)
    peak = signals.peaks(x, dt, window_s=40.0)[0]
    assert abs(peak.frequency_hz - 4.0) < 0.15
    assert 0.01 < peak.damping < 0.08


def test_lag_sign_convention():
    dt = 0.01
    t = np.arange(3000) * dt
    ref = np.sin(2 * np.pi * 0.7 * t) + 0.5 * np.sin(2 * np.pi * 1.9 * t)
    lagged = signals.delayed(ref[:, None], 0.034, dt)[:, 0]
    assert signals.lag(ref, lagged, dt) == pytest.approx(0.034, abs=0.002)


def test_rest_stretches_are_compared_about_their_mean():
    dq = np.array([[0, 1.0], [0, 1.0], [1.0, 0], [0, 0], [0, 0]])
    labels = signals.rest_runs(dq)
    assert labels[:, 0].tolist() == [0, 0, -1, 1, 1]
    assert labels[:, 1].tolist() == [-1, -1, 0, 0, 0]
    x = np.array([[1.0, 5.0], [3.0, 6.0], [7.0, 1.0], [2.0, 2.0], [4.0, 3.0]])
    y = signals.demean_runs(x, labels)
    assert y[:, 0].tolist() == [-1.0, 1.0, 7.0, -1.0, 1.0]
    assert y[:, 1].tolist() == [5.0, 6.0, -1.0, 0.0, 1.0]


def test_samples_slower_than_the_stick_speed_leave_every_comparison():
    # the n-joint engine's labels: each slow sample (rests and the band above them) is a stretch of its own, so
    # demeaning zeroes it in data and prediction alike, whatever the torque stiction held there
    dq = np.array([[0.0, 1.0], [0.005, -0.02], [-0.05, 0.5], [0.02, 0.0], [0.3, -0.3]])
    labels = signals.rest_runs(dq, below=np.array([0.03, 0.03]))
    assert labels[:, 0].tolist() == [0, 1, -1, 2, -1]
    assert labels[:, 1].tolist() == [-1, 0, -1, 1, -1]
    x = np.arange(10.0).reshape(5, 2) + 1.0
    y = signals.demean_runs(x, labels)
    assert np.array_equal(y == 0, labels >= 0)
    assert np.array_equal(y[labels < 0], x[labels < 0])


def _moves(active: list[tuple[float, float]], n: int = 4000, dt: float = 0.01) -> Dataset:
    """A 2-joint trial: joint 1 swings throughout, joint 2 only within the `active` spans (fractions of the trial)."""
    t = np.arange(n) * dt
    dq = np.column_stack([np.sin(2 * np.pi * 0.5 * t), np.zeros(n)])
    for a, b in active:
        span = slice(int(a * n), int(b * n))
        dq[span, 1] = np.sin(2 * np.pi * 0.7 * t[span])
    q = np.cumsum(dq, axis=0) * dt
    return Dataset("x", t, q, dq, np.gradient(dq, dt, axis=0), np.random.default_rng(0).normal(size=(n, 2)))


def test_the_held_out_part_moves_every_joint_when_the_trial_allows():
    # joint 2 rests through the last 30 %: the first 30 % is held out instead, and no warning remains
    train, test, how = split(_moves([(0.0, 0.6)]), None, 0.7)
    assert "held out first" in how
    assert test.t[0] == 0.0 and train.n == 2800
    assert compared_warnings(train, test, ("a", "b")) == []
    # joint 2 moves in the last 30 %: the usual chronological split
    train, test, how = split(_moves([(0.5, 1.0)]), None, 0.7)
    assert how.startswith("chronological: first 70%") and test.t[0] > train.t[-1]
    # joint 2 moves only in the middle: neither end holds it; the last part stays held out, with a warning naming it
    train, test, how = split(_moves([(0.35, 0.65)]), None, 0.7)
    assert how.startswith("chronological: first 70%")
    (w,) = compared_warnings(train, test, ("a", "b"))
    assert w.code == "joint_not_compared" and "b (q2: 0%)" in w.message and "a (q1" not in w.message


def test_near_stops_marks_long_rests_and_their_surroundings_only():
    dt = 0.01
    dq = np.ones((100, 2))
    dq[20:50, 0] = 0.0  # a 0.3 s stop of joint 1
    dq[70:73, 0] = 0.0  # a 30 ms slow instant (a reversal): not a stop
    near = signals.near_stops(dq, dt, stop_s=0.25, within_s=0.05)
    np.testing.assert_array_equal(np.flatnonzero(near[:, 0]), np.arange(15, 55))
    assert not near[:, 1].any()
    assert not signals.near_stops(dq, dt, stop_s=0.35, within_s=0.05).any()  # shorter than a stop


def test_a_joint_with_nothing_compared_adds_nothing_to_the_score():
    # a joint whose held-out samples were all left out (never faster than its stick speed) has MSE 0 before and
    # after: it must neither lift nor sink the score, nor make it NaN
    with np.errstate(all="raise"):
        alone = scoring.score(np.array([2.0]), np.array([1.0]), 500, 3)
        assert scoring.score(np.array([2.0, 0.0]), np.array([1.0, 0.0]), 500, 3) == alone
        assert scoring.recovered(np.array([2.0, 0.0]), np.array([1.5, 0.0]), np.array([1.0, 0.0])) == pytest.approx(
            np.log(2.0 / 1.5) / np.log(2.0)
        )


def test_a_column_below_double_precision_gets_no_coefficient():
    # A Stribeck shape far from its hump is ~1e-160: fitted, it took a coefficient of ~1e160 that overflowed
    # on other data. It is held at 0 with an infinite standard error; the other columns fit as without it.
    rng = np.random.default_rng(0)
    X = np.zeros((100, 2, 3))
    X[:, 0, 0], X[:, 1, 2] = np.linspace(-1, 1, 100), rng.normal(size=100)
    tau = rng.normal(size=(100, 2))
    without = linear.solve(np.zeros((100, 2)), X[:, :, [0, 2]], tau, np.ones(2))
    X[:50, 1, 1] = 1e-160
    ls = linear.solve(np.zeros((100, 2)), X, tau, np.ones(2))
    assert ls.beta[1] == 0.0 and ls.se[1] == np.inf
    np.testing.assert_allclose(ls.beta[[0, 2]], without.beta, rtol=1e-12)
    np.testing.assert_allclose(ls.se[[0, 2]], without.se, rtol=1e-6)
    # Alone (the datasheet side of a candidate has only its own columns), against the target's size.
    alone = linear.solve(np.zeros((100, 2)), X[:, :, [1]], tau, np.ones(2))
    assert alone.beta[0] == 0.0 and alone.se[0] == np.inf


def test_least_squares_recovers_known_coefficients_and_respects_signs():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(500, 2, 3))
    beta = np.array([0.5, -0.2, 1.5])
    offset = rng.normal(size=(500, 2))
    tau = offset + X @ beta + 1e-3 * rng.normal(size=(500, 2))
    ls = linear.solve(offset, X, tau, np.ones(2))
    assert np.allclose(ls.beta, beta, atol=1e-3)
    assert np.all(ls.se > 0) and np.all(ls.se < 1e-3)
    signed = linear.solve_nonnegative(offset, X, tau, np.ones(2), [1])
    assert signed.beta[1] == 0.0 and signed.beta[0] > 0


def test_search_finds_a_one_dimensional_minimum():
    theta = linear.search(lambda th: (np.log(th["v"]) - np.log(0.037)) ** 2, [linear.Axis("v", 0.005, 0.5, 9, True)])
    assert theta["v"] == pytest.approx(0.037, rel=1e-2)


def test_naming_rule_needs_score_and_both_margins():
    before, var = np.array([1.0, 1.0]), np.array([100.0, 100.0])
    assert scoring.clears_margin(before, np.array([0.9, 1.0]), 5.0, var)
    assert not scoring.clears_margin(before, np.array([0.97, 0.99]), 5.0, var)  # < 5 % of the MSE
    assert not scoring.clears_margin(before, np.array([0.9, 1.0]), -1.0, var)  # penalty wins
    assert not scoring.clears_margin(np.array([1e-3, 1.0]), np.array([0.5e-3, 1.0]), 5.0, var)  # nil vs torque
    assert scoring.score(before, before, 1000, 2) < 0
    # The reason a candidate is not named is the first rule it fails, and there is none when it is named.
    cases = [
        (np.array([0.9, 1.0]), 5.0, True, None),
        (np.array([0.97, 0.99]), 5.0, True, "3.0% of the held-out MSE"),
        (np.array([0.9, 1.0]), -1.0, True, "score -1.0"),
        (np.array([0.9, 1.0]), 5.0, False, "own rule"),
        (np.array([0.9, 1.0]), 5.0, True, "50% of what refitting"),
    ]
    for after, score, resolved, expected in cases:
        share = 0.5 if expected and "refitting" in expected else None
        why = scoring.shortfall(before, after, score, var, resolved, share)
        assert (why is None) == (expected is None) and (expected is None or expected in why), why
        if share is None and resolved:
            assert (why is None) == scoring.clears_margin(before, after, score, var)
    assert not scoring.resolved("delay", {"seconds": 0.001}, 0.01)
    assert scoring.resolved("delay", {"seconds": 0.02}, 0.01)
    # A mode where the search stopped (an edge of the band) is not a resonance; one inside it is.
    lo, hi = ELASTIC_BAND_HZ
    assert not scoring.resolved("elasticity", {"joint": 1, "frequency_hz": hi}, 0.01)
    assert not scoring.resolved("elasticity", {"joint": 2, "frequency_hz": lo}, 0.01)
    assert scoring.resolved("elasticity", {"joint": 2, "frequency_hz": 0.5 * (lo + hi)}, 0.01)
    # A Stribeck "dip" that never falls off (vs at the fit's upper bound) is a Coulomb step; none resolved: nothing.
    assert not scoring.resolved("stribeck", {"static": [0.0, 0.37], "velocity": [0.0, 1.0]}, 0.01)
    assert not scoring.resolved("stribeck", {"static": [0.0, 0.0], "velocity": [0.0, 0.0]}, 0.01)
    assert scoring.resolved("stribeck", {"static": [0.8, 0.0], "velocity": [0.05, 0.0]}, 0.01)
    # Levels equal by direction (within 10 % of their mean) are a symmetric Coulomb level, not an asymmetry.
    assert not scoring.resolved("asymmetric_coulomb", {"positive": [0.36, 0.377], "negative": [0.348, 0.369]}, 0.01)
    assert scoring.resolved("asymmetric_coulomb", {"positive": [0.36, 0.25], "negative": [0.348, 0.7]}, 0.01)


def test_at_rest_zeroes_filter_ringing_but_not_a_smooth_reversal():
    t = np.arange(20) * 0.01
    dq = np.zeros((20, 2))
    dq[:, 0] = [0, 0.001, -0.001, 0, 0, 0, 0, 0.002, 0.5, 1, 1, 1, 0.5, 0.003, 0, 0, 0, 0, 0, 0]
    dq[:, 1] = np.linspace(-1, 1, 20)
    ds = Dataset("x", t, np.zeros((20, 2)), dq, np.zeros((20, 2)), np.zeros((20, 2)))
    out = at_rest(ds).dq
    assert np.all(out[:8, 0] == 0) and np.all(out[13:, 0] == 0) and np.all(out[8:13, 0] == dq[8:13, 0])
    assert np.array_equal(out[:, 1], dq[:, 1])


def test_residual_evidence_reads_direction_and_pose(physical_problem):
    """A residual made of a direction-dependent step plus a gravity-like term shows in the right features."""
    from ident_opt.diagnosis.evidence import residual_evidence

    dt = 0.01
    t = np.arange(6000) * dt
    q = np.column_stack([0.8 * np.sin(0.5 * t), 0.6 * np.sin(1.3 * t + 1.0)])
    dq = np.gradient(q, dt, axis=0)
    tau_hat = np.column_stack([np.sin(t), np.cos(t)])
    step = np.where(dq > 0, 0.3, -0.1)  # +0.3 N m moving positive, −0.1 N m moving negative
    tau = tau_hat + step + np.column_stack([0.5 * np.sin(q[:, 0]), np.zeros(len(t))])
    ds = Dataset("x", t, q, dq, np.gradient(dq, dt, axis=0), tau)
    ev = residual_evidence(ds, tau_hat, dt)
    mm = ev["moving_mean"][1]
    assert mm["positive"] == pytest.approx(0.3, abs=1e-9) and mm["negative"] == pytest.approx(-0.1, abs=1e-9)
    assert ev["reversal_steps"][1]["negative_to_positive"] == pytest.approx(0.4, abs=0.02)
    assert ev["reversal_steps"][1]["positive_to_negative"] == pytest.approx(-0.4, abs=0.02)
    assert ev["pose_r2"][0] > 0.4 and ev["pose_r2"][1] < 0.2  # joint 1 carries the gravity-like part
    assert ev["lag_s"][1] == pytest.approx(0.0, abs=dt)


def test_forward_simulation_error_separates_right_from_wrong_parameters(physical_problem):
    """Driven by the measured torque, the true model tracks short windows; a 50 % inertia error does not."""
    from ident_opt.arm.datasheet import datasheet_pi
    from ident_opt.diagnosis.evidence import forward_error
    from ident_opt.diagnosis.planar.families import NOMINAL
    from ident_opt.simulator import simulate_trial

    robot = physical_problem.robot
    trial = simulate_trial(
        robot,
        trajectory="fourier",
        duration=20.0,
        seed=0,
        noise=False,
        rate_hz=1000.0,
        exact_derivatives=True,
        progress=False,
    )
    ds = trial.dataset()
    pi = NOMINAL.vector(datasheet_pi(robot))
    wrong = pi.copy()
    wrong[NOMINAL.names.index("a1")] *= 1.5
    good = forward_error(NOMINAL, pi, ds, 0.001, window_s=0.3)
    bad = forward_error(NOMINAL, wrong, ds, 0.001, window_s=0.3)
    assert good[0] < 0.2 * bad[0]


def test_trapezoid_step_is_the_deflection_filter_exactly():
    """The NLP's recursion (trapezoidal rule, pre-warped ω) is the bilinear filter the search uses, sample
    for sample, from the filter's zero-history initial state."""
    import math

    from ident_opt.numerics.damped_mode import trapezoid_step

    dt, f, zeta = 0.01, 4.3, 0.03
    u = np.random.default_rng(1).normal(size=600)
    step = trapezoid_step(dt, math.tan)
    a, w = dt / 2, 2 / dt * math.tan(math.pi * f * dt)
    det = 1 + zeta * w * dt + a * w * w * dt / 2
    e, ed = a * (-a * u[0]) / det, -a * u[0] / det
    out = []
    for k in range(len(u) - 1):
        e, ed, y = step(e, ed, u[k], u[k + 1], f, zeta)
        out.append(y)
    expected = signals.deflection_acceleration(u, f, zeta, dt)[:-1]
    np.testing.assert_allclose(out, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())


def _elastic_problem(n=3000, dt=0.01, f=5.0, zeta=0.04, seed=2):
    """Synthetic elastic-candidate data: a rigid column plus s·P·ë of a known mode, rest stretches included."""
    rng = np.random.default_rng(seed)
    u = np.convolve(rng.normal(size=n), np.ones(15) / 15, mode="same") * 20  # smooth drive [rad/s²]
    u[1000:1200] = 0.0
    P = np.column_stack([np.full(n, 0.05), 0.02 + 0.01 * np.cos(np.arange(n) * dt)])
    X_rigid = rng.normal(size=(n, 2, 2))
    beta = np.array([0.7, -0.3, 1.8])  # rigid coefficients, then the scale s
    edd = signals.deflection_acceleration(u, f, zeta, dt)
    target = X_rigid @ beta[:2] + beta[2] * P * edd[:, None]
    dq = np.ones((n, 2))
    dq[1050:1200, 0] = 0.0  # joint 1 rests for 1.5 s: compared about its mean there
    return u, P, target, X_rigid, signals.rest_runs(dq), beta, dt


def test_elastic_polish_recovers_the_mode_from_a_wrong_start():
    from ident_opt.numerics.damped_mode import polish

    u, P, target, X_rigid, labels, beta, dt = _elastic_problem()
    start = {"frequency_hz": 5.3, "damping": 0.07}  # 6 % and 75 % off: where a coarse grid could leave it
    bounds = {"frequency_hz": (1.5, 12.0), "damping": (0.005, 0.3)}
    theta, info = polish(u, P, target, X_rigid, labels, np.ones(2), dt, start, beta * 1.2, bounds)
    assert theta is not None, info
    assert theta["frequency_hz"] == pytest.approx(5.0, rel=1e-4)
    assert theta["damping"] == pytest.approx(0.04, rel=1e-3)
    assert info["max_gap"] < 1e-6  # the shooting segments join up


def test_offset_polish_recovers_both_offsets_jointly_with_pi(physical_problem):
    from ident_opt.arm.datasheet import datasheet_pi
    from ident_opt.diagnosis.planar.families import NOMINAL
    from ident_opt.effects.joint_offset import offsets

    rng = np.random.default_rng(3)
    n = 2000
    q = np.column_stack([1.5 + np.sin(np.linspace(0, 9, n)), 0.8 * np.sin(np.linspace(0, 13, n))])
    dq, ddq = rng.normal(size=(n, 2)), rng.normal(size=(n, 2))
    pi = NOMINAL.vector(datasheet_pi(physical_problem.robot, "physical"))
    delta = np.array([0.031, -0.047])
    tau = NOMINAL.predict(pi, q + delta, dq, ddq)
    labels = signals.rest_runs(np.ones((n, 2)))
    start = {"delta1": 0.02, "delta2": -0.03}
    theta, info = offsets(NOMINAL, q, dq, ddq, tau, labels, np.ones(2), None, pi * 0.9, start, (-0.1, 0.1))
    assert theta is not None, info
    np.testing.assert_allclose([theta["delta1"], theta["delta2"]], delta, atol=1e-6)


def test_an_auto_cutoff_filters_the_torque_at_the_cutoff_the_trial_was_read_with():
    """A problem with derivative_cutoff_hz = "auto" (DFKI's) hands "auto" to the diagnosis: each trial's own
    cut-off is used, as if it had been given as a number (this raised a TypeError before)."""
    from dataclasses import replace

    from ident_opt.diagnosis.split import prepare

    rng = np.random.default_rng(0)
    t = np.arange(2000) * 0.002
    q = np.column_stack([np.sin(t), np.cos(2 * t)])
    tau = q + 0.1 * rng.standard_normal((2000, 2))
    trial = Dataset("x", t, q, np.gradient(q, t, axis=0), np.zeros((2000, 2)), tau, cutoff_hz=8.0)
    auto, given = prepare(trial, "auto"), prepare(trial, 8.0)
    np.testing.assert_array_equal(auto.tau, given.tau)
    assert not np.allclose(auto.tau, trial.tau)  # it did filter
    np.testing.assert_array_equal(prepare(replace(trial, cutoff_hz=None), "auto").tau, tau)  # logged derivatives


def test_physical_units_undo_a_torque_scale_exactly_on_one_row_columns():
    """τ_logged = τ / s: a coefficient on joint j's row alone is fitted as β / s_j and read back as β; a
    column on both rows gets s averaged by its energy on each row."""
    from ident_opt.diagnosis.planar.families import physical_units

    rng = np.random.default_rng(0)
    n, s = 500, np.array([0.8, 1.25])
    X = np.zeros((n, 2, 3))
    X[:, 0, 0] = rng.normal(size=n)  # joint 1's row only
    X[:, 1, 1] = rng.normal(size=n)  # joint 2's row only
    X[:, 0, 2], X[:, 1, 2] = rng.normal(size=n), 3.0 * rng.normal(size=n)  # both rows, most energy on row 2
    fitted = {"a": 0.4 / s[0], "b": 0.04 / s[1], "m": 0.3, "c1": 1 / s[0], "c2": 1 / s[1]}
    se = dict.fromkeys(fitted, 0.01)
    p, e = physical_units((s, ("c1", "c2")), X, ["a", "b", "m"], fitted, se, np.ones(2))
    assert p["a"] == pytest.approx(0.4) and p["b"] == pytest.approx(0.04)
    assert e["a"] == pytest.approx(0.01 * s[0])
    share = np.array([1.0, 9.0]) / 10.0  # the energy shares of the two-row column (1 : 9 in expectation)
    assert p["m"] == pytest.approx(0.3 * (s @ share), rel=0.02)
    assert p["c1"] == fitted["c1"] and p["c2"] == fitted["c2"]  # the scale's own coefficients are left alone
    assert fitted["a"] == pytest.approx(0.4 / s[0])  # the input is not modified


def test_a_torque_scale_within_its_tolerance_of_one_is_not_named():
    """The resolution floor: a factor the diagnosis cannot tell from 1 (within SCALE_TOL on every joint) is not
    named, on either engine; on an arm the joints within it leave the candidate (`failed_joints`), the others stay."""
    from types import SimpleNamespace

    from ident_opt.effects.torque_scale import EFFECT, SCALE_TOL, _arm_estimate

    assert not EFFECT.resolved({"scale": [1.0 + 0.9 * SCALE_TOL, 1.0 - 0.9 * SCALE_TOL]}, 0.01)
    assert EFFECT.resolved({"scale": [1.0, 1.0 - 1.5 * SCALE_TOL]}, 0.01)
    ctx = SimpleNamespace(n=4)
    p = {"c2": 1.0 / 1.12, "c3": 1.0 / 1.006, "c4": 1.0 / 0.99}  # joint 1 not fitted (screened out)
    estimate, detail = _arm_estimate(p, {}, ctx)
    np.testing.assert_allclose(estimate["scale"], [1.0, 1.12, 1.006, 0.99])
    assert detail["failed_joints"] == [2, 3]  # 0-based: joints 3 and 4 are within the floor, joint 1 untouched
    assert _arm_estimate({"c2": 1.0 / 1.12}, {}, ctx)[1] == {}


def test_a_static_friction_beyond_the_logged_torque_is_not_an_estimate():
    """A joint that moved was driven past its static friction: a Stribeck static level above the largest torque
    logged on it is a hump extrapolated where there are no samples, and the candidate fails its own rule."""
    from types import SimpleNamespace

    from ident_opt.effects.stribeck import _estimate, beyond_logged

    tau = np.column_stack([np.linspace(-3.0, 3.0, 50), np.linspace(-0.5, 0.8, 50)])
    ctx = SimpleNamespace(
        train=SimpleNamespace(tau=tau),
        robot=SimpleNamespace(joint_names=("shoulder", "elbow")),
        datasheet={"fc1": 0.3, "fc2": 0.2},
    )
    assert beyond_logged([2.9, 0.7], ctx) == []
    assert beyond_logged([0.0, 9e8], ctx) == [1]
    p = {"fs1": 0.2, "fs2": 9e8, "vs1": 0.05, "vs2": 0.04}
    estimate, detail = _estimate(p, {"fs1": 0.01, "fs2": 1e7}, ctx)
    assert estimate["static"][1] > 1e8 and "elbow" in detail["unresolved"]
    assert "unresolved" not in _estimate({**p, "fs2": 0.3}, {"fs1": 0.01, "fs2": 0.01}, ctx)[1]


def test_an_arm_elastic_joint_is_judged_against_the_frequency_of_its_trial():
    """The spring is set at the centre pose; the trial runs elsewhere (`Elasticity.arm_truth`): the n-joint judge
    takes `frequency_trial_hz` where the truth has it, `frequency_hz` otherwise; the planar judge is unchanged."""
    from ident_opt.effects.elasticity import EFFECT

    truth = {"joint": 2, "frequency_hz": 5.88, "frequency_trial_hz": 8.47}
    assert all(ok for ok, _ in EFFECT.chain_judge({"joint": 2, "frequency_hz": 8.25}, truth))
    assert not all(ok for ok, _ in EFFECT.chain_judge({"joint": 2, "frequency_hz": 5.9}, truth))
    close = {"joint": 2, "frequency_hz": 5.88}
    assert all(ok for ok, _ in EFFECT.chain_judge({"joint": 2, "frequency_hz": 5.9}, close))
    assert not all(ok for ok, _ in EFFECT.judge({"joint": 2, "frequency_hz": 8.25}, truth))


def test_a_family_that_contains_another_cause_must_clear_the_margin_against_it_too():
    """An elastic joint's columns include an armature's (its motor inertia): named over the armature only if it
    also removes the margin of the armature fit's MSE; a cause it does not contain is not compared."""
    from types import SimpleNamespace

    from ident_opt.diagnosis.result import Fitted
    from ident_opt.diagnosis.rounds import _nested

    def fitted(cause: str, mse, common: float, nests=(), baseline="datasheet") -> Fitted:
        family = SimpleNamespace(cause=cause, nests=nests)
        return Fitted((cause,), baseline, SimpleNamespace(cause=cause), np.asarray(mse), None, common, family, {})

    var = np.array([100.0, 100.0])

    def rows_after(ranked):
        rows = [{"clears_margin": True, "needs_partner": False, "shortfall": None} for _ in ranked]
        _nested(ranked, rows, var, scoring.MARGIN_VARIANCE)
        return rows

    armature = fitted("armature", [1.0, 0.5], 40.0)
    # The same MSE as the armature's fit, a higher score: the mode rides on the motor column.
    rows = rows_after([fitted("elasticity", [0.99, 0.5], 41.0, ("armature",)), armature])
    assert not rows[0]["clears_margin"] and "`armature`" in rows[0]["shortfall"] and rows[1]["clears_margin"]
    # A mode that removes a tenth of the armature fit's MSE on a joint earns its place.
    rows = rows_after([fitted("elasticity", [0.9, 0.5], 60.0, ("armature",)), armature])
    assert rows[0]["clears_margin"] and rows[0]["shortfall"] is None
    # Against another baseline (no motor column there) or another cause, nothing is compared.
    rows = rows_after([fitted("elasticity", [0.99, 0.5], 41.0, ("armature",), "rigid_fit"), armature])
    assert rows[0]["clears_margin"]
    rows = rows_after([fitted("elasticity", [0.99, 0.5], 41.0), armature])
    assert rows[0]["clears_margin"]


def _elastic_trial(joint: int):
    """A short noise-free trial of tudor_sim with an elastic joint `joint` at 4 Hz, its dataset and a context."""
    from ident_opt.arm.datasheet import datasheet_pi, rigid_body
    from ident_opt.diagnosis.planar import families as cands
    from ident_opt.problem import load_problem
    from ident_opt.simulator import simulate_trial

    robot = load_problem("problems/tudor_sim.toml").robot
    sim = simulate_trial(
        robot,
        duration=4.0,
        seed=4,
        noise=False,
        exact_derivatives=True,
        progress=False,
        effects={"elasticity": {"joint": joint, "frequency_hz": 4.0, "damping": 0.03}},
    )
    ds = sim.dataset()
    dt = float(np.median(np.diff(ds.t)))
    pi = datasheet_pi(robot, "physical")
    armature = rigid_body(robot, "physical").armature
    return sim, ds, cands.Context(robot, ds, ds, np.ones(2), pi, dt, signals.rest_runs(ds.dq), armature)


def test_the_elastic_columns_stiffness_is_gravitys_slope_at_rest():
    """K = ∂τ_link/∂q_j of the planar elastic column against the closed form at rest: the link-side torque is
    gravity alone, G = (b1 cos q1 + b2 cos(q1 + q2), b2 cos(q1 + q2)), so K_j = ∂G/∂q_j."""
    from ident_opt.effects.elasticity import elastic_drive

    _, ds, ctx = _elastic_trial(2)
    rest = replace_motion(ds)
    b1, b2 = ctx.datasheet["b1"], ctx.datasheet["b2"]
    q1, q12 = rest.q[:, 0], rest.q[:, 0] + rest.q[:, 1]
    slope = {
        1: np.column_stack([-b1 * np.sin(q1) - b2 * np.sin(q12), -b2 * np.sin(q12)]),
        2: np.column_stack([-b2 * np.sin(q12), -b2 * np.sin(q12)]),
    }
    for joint in (1, 2):
        _, _, K = elastic_drive(joint, rest, ctx)
        np.testing.assert_allclose(K, slope[joint], rtol=1e-6, atol=1e-8 * abs(b1))


def replace_motion(ds: Dataset) -> Dataset:
    """`ds` at its poses with the joints held (dq = ddq = 0)."""
    from dataclasses import replace

    return replace(ds, dq=np.zeros_like(ds.dq), ddq=np.zeros_like(ds.ddq))


def test_the_elastic_columns_deflection_starts_at_the_simulated_spring_sag():
    """Independent reference: the simulator's elastic joint starts at rest with its spring holding the link against
    gravity (its own fixed point, k e = G_j). The column's deflection starts from the static sag of its drive,
    e = −τ_link,j / (M_jj ω²): the same number for joint 2 (whose link inertia is the spring's k / ω²), where an
    inertia-only drive would start at 0."""
    from ident_opt.effects.elasticity import elastic_drive

    sim, ds, ctx = _elastic_trial(2)
    u, _, K = elastic_drive(2, ds, ctx)
    e, _ = signals.deflection(u, 4.0, 0.03, ctx.dt)
    logged = -sim.frame["deflection2"].to_numpy()  # the log's θ − q; the column's e is q − θ
    k = sim.truth["effects"]["elasticity"]["stiffness"]
    assert abs(logged[0]) > 1e-2  # a sag worth checking [rad]
    assert abs(K[0, 1]) / k < 0.05  # where first order is first order
    assert abs(e[0] / logged[0] - 1) <= 0.1
