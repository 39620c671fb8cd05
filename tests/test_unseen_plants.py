"""Plants the diagnosis was not tuned on (`simulate/unseen.py`): their mechanics checked against the rigid model and
their own definitions, and a lean subset of `benchmarks/unseen_plants.py` (the issue-30 test matrix)."""

from __future__ import annotations

import math
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from ident_opt.arm.datasheet import datasheet_pi
from ident_opt.simulate import unseen
from ident_opt.simulate.truth import TRUTH_MODEL, build_truth, coulomb_levels
from ident_opt.effects import normalise
from ident_opt.problem import load_problem

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
