"""Each hidden effect leaves its own signature (and nothing else), and magnitude 0 is the clean trial."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import signal

from ident_opt.arm.planar import PlanarArm
from ident_opt.fitting.ols import solve_ols
from ident_opt.fitting.stats import Stats
from ident_opt.problem import load_problem
from ident_opt.simulator import simulate_trial

ROOT = Path(__file__).resolve().parents[1]
MODEL = PlanarArm(("armature",))
SHORT = {"duration": 6.0, "trajectory": "fourier", "progress": False}
EXACT = {**SHORT, "noise": False, "exact_derivatives": True}


@pytest.fixture(scope="module")
def robot():
    return load_problem(ROOT / "problems" / "tudor_2dof.toml").robot


@pytest.fixture(scope="module")
def clean(robot):
    return simulate_trial(robot, **EXACT)


def fit(trial, model=MODEL):
    d = trial.dataset()
    return model.as_dict(solve_ols(Stats.from_data(model, d.q, d.dq, d.ddq, d.tau)))


@pytest.mark.parametrize(
    "effect",
    [
        "armature:scale=0",
        "armature:inertia=[0,0]",
        "asymmetric_coulomb:scale=0",
        "stribeck:scale=0",
        "elasticity:scale=0",
        "payload:mass=0",
        "delay:seconds=0",
        "joint_offset:offset=[0,0]",
        "load_friction:coefficient=[0,0]",
        "load_friction:scale=0",
    ],
)
def test_magnitude_zero_reproduces_the_clean_trial_exactly(robot, effect):
    base = simulate_trial(robot, duration=3.0, seed=2, progress=False)
    trial = simulate_trial(robot, duration=3.0, seed=2, effects=[effect], progress=False)
    pd.testing.assert_frame_equal(trial.frame, base.frame, check_exact=True)
    assert trial.truth["effects"] == {} and trial.truth["pi"] == base.truth["pi"]


def test_payload_moves_pi_along_the_payload_direction_only(robot, clean):
    m = 0.3
    trial = simulate_trial(robot, effects={"payload": {"mass": m}}, **EXACT)
    l1, l2, g = robot.link1.length, robot.link2.length, robot.gravity
    # A point mass m at the tip of link 2 adds m (l1² + l2²), m l1 l2, m l2², m l1 g, m l2 g to a1..b2.
    direction = {"a1": l1**2 + l2**2, "a2": l1 * l2, "a3": l2**2, "b1": l1 * g, "b2": l2 * g}
    before, after = fit(clean), fit(trial)
    for name in MODEL.names:
        expected = before[name] + m * direction.get(name, 0.0)
        assert after[name] == pytest.approx(expected, rel=1e-6, abs=1e-9), name
        assert after[name] == pytest.approx(trial.truth["pi"][name], rel=1e-6, abs=1e-9)
    assert trial.truth["effects"]["payload"] == {"mass": m}


def test_armature_adds_inertia_on_the_diagonal_only(robot, clean):
    J = (0.1, 0.02)
    trial = simulate_trial(robot, effects=[f"armature:inertia=[{J[0]},{J[1]}]"], **EXACT)
    before, after = fit(clean), fit(trial)
    for name in MODEL.names:
        extra = {"a1": J[0], "ia2": J[1]}.get(name, 0.0)
        assert after[name] == pytest.approx(before[name] + extra, rel=1e-6, abs=1e-9), name
    assert trial.truth["effects"]["armature"] == {"inertia": list(J)}


def test_asymmetric_coulomb_is_recovered_by_the_asymmetric_model(robot):
    trial = simulate_trial(robot, effects=["asymmetric_coulomb:positive=[0.9,0.3],negative=[0.4,0.6]"], **EXACT)
    got = fit(trial, PlanarArm(("armature", "asymmetric_coulomb")))
    assert [got["fc1p"], got["fc2p"]] == pytest.approx([0.9, 0.3], rel=1e-6)
    assert [got["fc1n"], got["fc2n"]] == pytest.approx([0.4, 0.6], rel=1e-6)
    assert trial.truth["effects"]["asymmetric_coulomb"] == {"positive": [0.9, 0.3], "negative": [0.4, 0.6]}
    assert trial.truth["pi"]["fc1"] == pytest.approx(0.65) and trial.truth["pi"]["fc2"] == pytest.approx(0.45)


def test_stribeck_is_recovered_by_the_stribeck_model(robot):
    """`static` is the breakaway level fs itself; the model's fs1 fs2 are its excess over the Coulomb level."""
    trial = simulate_trial(robot, effects=["stribeck:static=[0.9,0.65],velocity=[0.1,0.08]"], **EXACT)
    got = fit(trial, PlanarArm(("armature", "stribeck"), stribeck_velocity=(0.1, 0.08)))
    fc = [trial.truth["pi"]["fc1"], trial.truth["pi"]["fc2"]]
    assert [got["fs1"], got["fs2"]] == pytest.approx([0.9 - fc[0], 0.65 - fc[1]], rel=1e-6)
    assert [got["fc1"] + got["fs1"], got["fc2"] + got["fs2"]] == pytest.approx([0.9, 0.65], rel=1e-6)
    assert trial.truth["effects"]["stribeck"]["static"] == [0.9, 0.65]
    assert trial.truth["effects"]["stribeck"]["velocity"] == [0.1, 0.08]


def test_joint_offset_rotates_gravity_by_the_offset(robot, clean):
    delta = 0.03
    trial = simulate_trial(robot, effects=[f"joint_offset:offset=[{delta},0]"], **EXACT)
    got = fit(trial, PlanarArm(("armature", "offset")))
    # Gravity at the true angle q + δ: b1 cos(q1 + δ) = b1 cos δ cos q1 − b1 sin δ sin q1 (same for b2).
    assert np.arctan2(-got["b1s"], got["b1"]) == pytest.approx(delta, rel=1e-6)
    assert np.arctan2(-got["b2s"], got["b2"]) == pytest.approx(delta, rel=1e-6)
    assert np.hypot(got["b1"], got["b1s"]) == pytest.approx(clean.truth["pi"]["b1"], rel=1e-6)
    assert trial.truth["effects"]["joint_offset"] == {"offset": [delta, 0.0]}


def test_delay_is_recovered_by_cross_correlation(robot):
    seconds = 0.023
    kwargs = {**EXACT, "rate_hz": 1000.0, "duration": 8.0}
    trial = simulate_trial(robot, effects={"delay": {"seconds": seconds}}, **kwargs)
    d = trial.dataset()
    predicted = MODEL.predict(MODEL.vector(trial.truth["pi"]), d.q, d.dq, d.ddq)
    lags = np.arange(0, 60)
    for j in range(2):
        # Differences whiten the (mostly slow) torques, so the correlation peak is sharp.
        x, y = np.diff(predicted[:, j]), np.diff(d.tau[:, j])
        score = [np.corrcoef(x[: len(x) - k], y[k:])[0, 1] for k in lags]
        assert lags[int(np.argmax(score))] / 1000.0 == pytest.approx(seconds, abs=1.5e-3)
    assert trial.truth["effects"]["delay"] == {"seconds": seconds}


@pytest.mark.parametrize(
    "kind, joint, frequency", [("joint", 2, 8.0), ("joint", 1, 5.0), ("link", 2, 8.0), ("link", 1, 3.0)]
)
def test_elasticity_puts_residual_power_at_the_stated_frequency(robot, kind, joint, frequency):
    kwargs = {"duration": 20.0, "seed": 1, "noise": False, "progress": False}
    clean = simulate_trial(robot, **kwargs)
    effect = {"elasticity": {"joint": joint, "frequency_hz": frequency, "kind": kind}}
    trial = simulate_trial(robot, effects=effect, **kwargs)
    spectra = []
    for t in (clean, trial):
        d = t.dataset()
        residual = d.tau - MODEL.predict(MODEL.vector(t.truth["pi"]), d.q, d.dq, d.ddq)
        f, P = signal.welch(residual[:, joint - 1], fs=100.0, nperseg=512)
        spectra.append(P)
    band = (f > 1.0) & (f < 30.0)
    peak = f[band][np.argmax(spectra[1][band])]
    assert peak == pytest.approx(frequency, rel=0.1)
    near = np.abs(f - frequency) < 0.5
    assert spectra[1][near].sum() > 10 * spectra[0][near].sum()
    e = trial.truth["effects"]["elasticity"]
    assert e["joint"] == joint and e["frequency_hz"] == frequency and e["kind"] == kind
    assert f"deflection{joint}" in trial.frame


def test_torque_scale_divides_the_logged_torque_by_the_factor(robot, clean):
    """The true joint torque is s × the logged one; the motion is the clean trial's (the loop never sees it)."""
    trial = simulate_trial(robot, effects=["torque_scale:scale=[1.2,0.9]"], **EXACT)
    tau, true = trial.dataset().tau, clean.dataset().tau
    np.testing.assert_allclose(tau * np.array([1.2, 0.9]), true, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(trial.dataset().q, clean.dataset().q)
    assert trial.truth["effects"]["torque_scale"] == {"scale": [1.2, 0.9]}
    untouched = simulate_trial(robot, effects=["torque_scale:scale=[1,1]"], **EXACT)
    pd.testing.assert_frame_equal(untouched.frame, clean.frame, check_exact=True)


def test_load_friction_adds_mu_times_the_link_torque_to_the_coulomb_level(robot):
    """Exact data: τ − Y π_true = μ_j sgn(dq_j) |τ_load,j| with τ_load the link-side rigid torque (inertial
    without the rotor inertia, Coriolis, gravity), so regressing the residual on that column gives back μ."""
    from ident_opt.arm.datasheet import datasheet_pi, rigid_body
    from ident_opt.simulator.planar_dynamics import link_pi

    trial = simulate_trial(robot, effects=["load_friction:coefficient=[0.15,0.05]"], **EXACT)
    d = trial.dataset()
    pi = MODEL.vector(datasheet_pi(robot, "physical"))
    residual = d.tau - MODEL.predict(pi, d.q, d.dq, d.ddq)
    load = MODEL.predict(link_pi(MODEL, pi, rigid_body(robot, "physical").armature), d.q, d.dq, d.ddq)
    column = np.sign(d.dq) * np.abs(load)
    moving = np.abs(d.dq) > 1e-3
    for j, mu in enumerate((0.15, 0.05)):
        x, r = column[moving[:, j], j], residual[moving[:, j], j]
        assert float(x @ r / (x @ x)) == pytest.approx(mu, rel=0.02)
    assert trial.truth["effects"]["load_friction"] == {"coefficient": [0.15, 0.05]}


@pytest.mark.parametrize("kind", ["joint", "link"])
def test_load_friction_acts_in_the_elastic_plants_too(robot, kind):
    """An elastic joint or flexible link replaces the rigid plant; the gears' load friction must stay in it
    (it used to vanish): at a moving state, the generalised forces change by exactly −μ_j sgn(v_j)|τ_load,j|,
    with τ_load the torque the gears transmit (the spring torque at an elastic joint, the link-side torque at
    a rigid one), evaluated at the accelerations the plant returns."""
    import casadi as ca

    from ident_opt.effects import is_active, normalise
    from ident_opt.simulator import flexible_link
    from ident_opt.simulator.planar_dynamics import friction_only, link_pi
    from ident_opt.simulator.truth import build_truth, coulomb_levels, plant

    mu = (0.2, 0.15)
    elastic = {"elasticity": {"joint": 1, "frequency_hz": 5.0, "kind": kind}}
    coulomb = coulomb_levels(robot)
    truths = [
        build_truth(robot, {n: p for n, p in normalise(e, coulomb).items() if is_active(n, p, coulomb)})
        for e in (elastic, {**elastic, "load_friction": {"coefficient": mu}})
    ]
    x = np.array([0.4, -0.7, 0.41 if kind == "joint" else 0.01, 0.8, -1.1, 0.6])
    tau = np.array([3.0, -1.0])
    xdot = [np.asarray(plant(t)(x, tau)[0]).ravel() for t in truths]
    e = truths[1].elastic
    if kind == "joint":  # state [q1, q2, θ, dq1, dq2, dθ]; joint 1's gears sit before the spring
        spring = e.k * (x[2] - x[0]) + e.d * (x[5] - x[3])
        assert e.B * (xdot[0][5] - xdot[1][5]) == pytest.approx(mu[0] * np.sign(x[5]) * abs(spring), rel=1e-9)
        # joint 2 is rigid: its link side (joint 1's motor and friction removed) feels −μ2 sgn(dq2)|τ_load,2|
        model, pi = truths[1].model, np.array(truths[1].pi, dtype=float)
        link = pi - friction_only(model, pi, 0)
        link[model.names.index("a1")] -= e.B
        q, dq = x[None, :2], x[None, 3:5]

        def tau_link(ddq, p=link):
            return model.predict(p, q, dq, np.asarray(ddq, dtype=float)[None, :])[0]

        M = np.column_stack([tau_link(u) - tau_link([0.0, 0.0]) for u in np.eye(2)])
        load = tau_link(xdot[1][3:5], link_pi(model, pi, truths[1].armature))[1]
        expected = [0.0, -mu[1] * np.sign(x[4]) * abs(load)]
        np.testing.assert_allclose(M @ (xdot[1][3:5] - xdot[0][3:5]), expected, rtol=2e-3, atol=1e-9)
    else:  # state [q1, q2, φ, dq1, dq2, dφ]: M(ddz_μ − ddz_0) = −[μ sgn(dq) |τ_load|, 0]
        z, dz, M, h = flexible_link.lagrangian_terms(truths[1].robot, 0, truths[1].armature)
        Mh = ca.Function("Mh", [z, dz], [M, h])
        M_x, h_x = (np.asarray(v, dtype=float) for v in Mh(x[:3], x[3:]))
        a = xdot[1][3:]
        load = (M_x @ a + h_x.ravel())[:2] - np.asarray(truths[1].armature) * a[:2]
        expected = -np.array([*(np.asarray(mu) * np.sign(x[3:5]) * np.abs(load)), 0.0])
        np.testing.assert_allclose(M_x @ (xdot[1][3:] - xdot[0][3:]), expected, rtol=2e-3, atol=1e-6)
