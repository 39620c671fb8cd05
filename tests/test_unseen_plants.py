"""Plants the diagnosis was not tuned on (`simulate/unseen.py`): their mechanics checked against the rigid model and
their own definitions, and a lean subset of `benchmarks/unseen_plants.py` (the issue-30 test matrix)."""

from __future__ import annotations

import math
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from ident_opt.arm.datasheet import datasheet_pi
from ident_opt.effects import normalise
from ident_opt.problem import load_problem
from ident_opt.simulator import unseen
from ident_opt.simulator.planar_dynamics import TRUTH_MODEL
from ident_opt.simulator.truth import build_truth, coulomb_levels

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def robot():
    return load_problem(ROOT / "problems" / "tudor_2dof.toml").robot


def _truth(robot, **elastic):
    effects = normalise({"elasticity": elastic}, coulomb_levels(robot)) if elastic else {}
    return build_truth(robot, effects)


@pytest.mark.parametrize("j", [0, 1])
def test_an_undeflected_beam_has_the_rigid_arms_mass_matrix_and_gravity(robot, j):
    """The assumed-modes Lagrangian (point masses, tip bodies, rotor inertias) against the closed-form rigid model."""
    truth = _truth(robot)
    z, dz, M, h, _, _ = unseen.beam_lagrangian(robot, j, 3, truth.armature)
    f = ca.Function("f", [z, dz], [M, h])
    pi = TRUTH_MODEL.vector(datasheet_pi(robot, "physical"))
    G = TRUTH_MODEL.function("G")
    for q in ([0.3, 0.0], [1.2, 0.9], [2.5, -1.3]):
        Mb, hb = (np.array(v) for v in f(np.r_[q, 0, 0, 0], np.zeros(5)))
        np.testing.assert_allclose(Mb[:2, :2], TRUTH_MODEL.mass_matrix(pi, q[1]), rtol=2e-3)
        np.testing.assert_allclose(hb[:2, 0], np.array(G(q, [0, 0], [0, 0], pi)).ravel(), rtol=1e-3, atol=1e-9)


@pytest.mark.parametrize("j", [0, 1])
def test_a_beams_first_held_mode_is_where_asked_and_the_others_lie_above(robot, j):
    b = unseen.beam(_truth(robot), j, 4.5, 0.01, 3)
    assert b.mode_frequencies_hz[0] == pytest.approx(4.5, rel=1e-9)
    assert b.mode_frequencies_hz[1] > 4 * 4.5 and b.mode_frequencies_hz[2] > b.mode_frequencies_hz[1]
    # Modal damping: every mode's ratio is ζ (D = M Φ diag(2ζω) Φᵀ M with Φ mass-normalised).
    z, _, M, _, K, _ = unseen.beam_lagrangian(robot, j, 3, _truth(robot).armature)
    Md = np.array(ca.Function("M", [z], [M])(np.zeros(5)))[2:, 2:]
    w2, V = unseen._generalised_eig(b.EI * np.diag(K), Md)
    zeta = np.diag(V.T @ b.D @ V) / (2 * np.sqrt(w2))
    np.testing.assert_allclose(zeta, 0.01, rtol=1e-9)


@pytest.mark.parametrize(("shape", "size"), [("hardening", 1.0), ("backlash", 0.2)])
def test_a_nonlinear_spring_is_what_it_says(robot, shape, size):
    truth = _truth(robot, joint=2, frequency_hz=4.0, kind="joint")
    mech = unseen.nonlinear_joint(truth, shape, size)
    e_g = unseen.gravity_deflection(truth, 1, mech.k)
    e = ca.SX.sym("e")
    tangent = ca.Function("kt", [e], [ca.jacobian(mech.spring(e, 0.0), e)])
    if shape == "hardening":  # tangent k (1 + size) at the largest gravity deflection, k at rest
        assert float(tangent(e_g)) == pytest.approx(mech.k * (1 + size), rel=1e-9)
    else:  # a play: no stiffness at e = 0, k far from it
        assert float(tangent(0.0)) == pytest.approx(0.0, abs=1e-12)
        assert float(tangent(20 * mech.a)) == pytest.approx(mech.k, rel=1e-6)
    for torque in (-0.3, 0.05, 0.4):
        assert float(mech.spring(mech.static_deflection(torque), 0.0)) == pytest.approx(torque, abs=1e-9)


def test_savitzky_golay_derivatives_are_exact_on_a_cubic():
    t = np.arange(0, 2, 0.01)
    q = np.column_stack([t**3, 1 - t**2])
    dq, ddq = unseen.savgol(t, q, 15)
    np.testing.assert_allclose(dq, np.column_stack([3 * t**2, -2 * t]), atol=1e-8)
    np.testing.assert_allclose(ddq, np.column_stack([6 * t, -2 + 0 * t]), atol=1e-6)
    assert math.isfinite(float(ddq.sum()))


# ------------------------------------------------------------------------------------- diagnosis (lean subset)
def _diagnosed(robot, effects, mechanism, pipeline, duration=40.0, seed=3):
    from ident_opt.diagnosis import diagnose_trial
    from ident_opt.simulator import simulate_trial

    sim = simulate_trial(robot, duration=duration, seed=seed, effects=effects, progress=False, mechanism=mechanism)
    return sim, diagnose_trial(robot, unseen.derived(sim, pipeline, robot), progress=False, torque_filter_hz="auto")


def test_a_hardening_joints_mode_is_named_at_its_effective_frequency(robot):
    """An elastic joint 2 whose spring stiffens (tangent 2 × k at the largest gravity deflection), logged with
    Savitzky–Golay derivatives (15 samples): `elasticity` on joint 2 alone, within 20 % of the frequency of the
    spring's mean tangent stiffness."""
    effects = {"elasticity": {"joint": 2, "frequency_hz": 4.0, "damping": 0.02, "kind": "joint"}}
    sim, d = _diagnosed(robot, effects, lambda truth: unseen.nonlinear_joint(truth, "hardening", 1.0), "savgol15")
    truth = unseen.nonlinear_joint(_truth(robot, **effects["elasticity"]), "hardening", 1.0)
    f = unseen.effective_frequency_hz(truth, sim.frame["deflection2"].to_numpy())
    assert [c["cause"] for c in d.causes] == ["elasticity"]
    assert d.estimate["joint"] == 2 and d.estimate["frequency_hz"] == pytest.approx(f, rel=0.2)


def test_a_distributed_links_first_mode_is_named(robot):
    """Link 1 as a beam (two modes, first at 3.5 Hz, 1 % damping on each), logged without derivatives: the first
    mode is `elasticity` on joint 1 within 20 %, and nothing else is named."""
    effects = {"elasticity": {"joint": 1, "frequency_hz": 3.5, "damping": 0.01, "kind": "link"}}
    _, d = _diagnosed(robot, effects, lambda truth: unseen.beam(truth, 0, 3.5, 0.01, 2, points=6), "no_derivatives")
    assert [c["cause"] for c in d.causes] == ["elasticity"]
    assert d.estimate["joint"] == 1 and d.estimate["frequency_hz"] == pytest.approx(3.5, rel=0.2)


def test_a_clean_trial_logged_with_savitzky_golay_derivatives_names_nothing(robot):
    """The torque is filtered to the logged accelerations' bandwidth (`signals.matched_cutoff`), so the filters'
    mismatch poses as no cause."""
    _, d = _diagnosed(robot, {}, None, "savgol21")
    assert d.causes == [] and d.cause == "none"


def test_a_loggers_bandwidth_is_read_from_its_accelerations():
    """`matched_cutoff`: a Savitzky–Golay logger's accelerations are imitated by a Butterworth of about its
    bandwidth (narrower for a longer window); exact accelerations by none, or by one far above the motion."""
    from ident_opt.numerics.signals import matched_cutoff

    t = np.arange(0, 60, 0.01)
    w = 2 * np.pi * np.array([0.3, 1.1, 2.3, 4.1, 6.7])
    q = np.column_stack([np.sin(np.outer(t, w) + k).sum(1) / len(w) for k in (0, 1)])
    ddq = np.column_stack([-(w**2 * np.sin(np.outer(t, w) + k)).sum(1) / len(w) for k in (0, 1)])
    cutoffs = [matched_cutoff(t, q, unseen.savgol(t, q, window)[1]) for window in (11, 15, 21)]
    assert cutoffs[0] > cutoffs[1] > cutoffs[2] > 3.0 and cutoffs[0] < 12.0
    exact = matched_cutoff(t, q, ddq)
    assert exact is None or exact > 25.0
    assert matched_cutoff(t, q, np.zeros_like(q)) is None  # no low-passed second derivative at all
