"""Physics sanity of the simulator: energy balance, tracking, torque range, and noise statistics."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from scipy import stats

from ident_opt.arm.datasheet import datasheet_pi
from ident_opt.arm.joints import Friction
from ident_opt.arm.planar import PlanarArm
from ident_opt.effects import normalise
from ident_opt.fitting.ols import solve_ols
from ident_opt.fitting.stats import Stats
from ident_opt.problem import load_problem
from ident_opt.simulator import simulate_trial
from ident_opt.simulator.closed_loop import MAX_TRACKING_ERROR
from ident_opt.simulator.flexible_link import datasheet_armature, lagrangian_terms
from ident_opt.simulator.trajectories import TAU_MAX
from ident_opt.simulator.truth import build_truth, coulomb_levels, plant

ROOT = Path(__file__).resolve().parents[1]
MODEL = PlanarArm(("armature",))
FRICTION_MASK = np.array([name.startswith(("fv", "fc")) for name in MODEL.names], dtype=float)


@pytest.fixture(scope="module")
def robot():
    return load_problem(ROOT / "problems" / "tudor_2dof.toml").robot


def without_friction(robot):
    still = Friction(0.0, 0.0)
    return replace(
        robot,
        joint1=replace(robot.joint1, viscous_friction=still, coulomb_friction=still),
        joint2=replace(robot.joint2, viscous_friction=still, coulomb_friction=still),
    )


def test_energy_balance_without_friction(robot):
    frictionless = without_friction(robot)
    trial = simulate_trial(
        frictionless,
        trajectory="fourier",
        duration=6.0,
        rate_hz=1000.0,
        noise=False,
        exact_derivatives=True,
        progress=False,
    )
    d, p = trial.dataset(), trial.truth["pi"]
    M = MODEL.mass_matrix(MODEL.vector(p), d.q[:, 1])
    # E = ½ dqᵀ M(q) dq + V(q), with V = b1 sin q1 + b2 sin(q1 + q2) (so that G = ∂V/∂q).
    energy = 0.5 * np.einsum("ki,kij,kj->k", d.dq, M, d.dq) + p["b1"] * np.sin(d.q[:, 0]) + p["b2"] * np.sin(d.q.sum(1))
    # The torque is held over each 1 ms tick, so the work over a tick is exactly τ_k · (q_{k+1} − q_k).
    work = np.concatenate([[0.0], np.cumsum(np.einsum("kj,kj->k", d.tau[:-1], np.diff(d.q, axis=0)))])
    assert np.ptp(energy) > 1.0  # J: a real exchange of energy took place
    assert np.abs((energy - energy[0]) - work).max() < 1e-8 * np.ptp(energy)


SIM_DEFAULT = load_problem(ROOT / "problems" / "tudor_sim.toml").simulate.effects


@pytest.mark.parametrize(
    "effects", [(), ("elasticity", "asymmetric_coulomb", "stribeck", "payload", "armature"), SIM_DEFAULT]
)
@pytest.mark.parametrize("trajectory", ["tud01", "fourier"])
def test_tracking_error_and_torques_within_stated_limits(robot, effects, trajectory):
    trial = simulate_trial(robot, trajectory=trajectory, duration=30.0, effects=list(effects), progress=False)
    limit = MAX_TRACKING_ERROR["effects" if effects else "clean"]
    assert max(trial.truth["tracking"]["max_error"]) < limit
    tau = trial.dataset().tau
    assert np.all(np.abs(tau).max(0) < TAU_MAX)
    q = trial.dataset().q
    assert q[:, 0].min() > 0.2 and q[:, 0].max() < 3.2 and np.abs(q[:, 1]).max() < 1.45


def test_noisy_ols_scatters_as_its_standard_errors_say(robot):
    """Over several seeds, Σ_s (π̂_s − π)ᵀ Cov⁻¹ (π̂_s − π) follows χ² with S·P degrees of freedom."""
    total, dof = 0.0, 0
    for seed in range(16):
        trial = simulate_trial(
            robot, trajectory="fourier", duration=6.0, seed=seed, exact_derivatives=True, progress=False
        )
        d = trial.dataset()
        s = Stats.from_data(MODEL, d.q, d.dq, d.ddq, d.tau)
        pi_hat = solve_ols(s)
        # Per-joint noise variance from the residuals; OLS covariance (sandwich, the joints' σ differ):
        # Cov = G⁻¹ (Σ_j σ_j² G_j) G⁻¹ with G = Σ_j G_j = Σ_j Y_jᵀ Y_j.
        sigma2 = s.rss(pi_hat) / (s.n - MODEL.n_params / 2)
        G_inv = np.linalg.inv(s.G.sum(0))
        cov = G_inv @ np.tensordot(sigma2, s.G, 1) @ G_inv
        e = pi_hat - MODEL.vector(trial.truth["pi"])
        total += e @ np.linalg.solve(cov, e)
        dof += MODEL.n_params
    assert stats.chi2.ppf(0.001, dof) < total < stats.chi2.ppf(0.999, dof)


@pytest.mark.parametrize("joint", [1, 2])
def test_elastic_joint_exchanges_energy_only_through_the_motor_torque(robot, joint):
    """Without friction and damping, dE/dt = τ_j dθ + τ_i dq_i for the two-mass model, at any state."""
    frictionless = without_friction(robot)
    effects = normalise(
        {"elasticity": {"joint": joint, "frequency_hz": 6.0, "damping": 0.0}}, coulomb_levels(frictionless)
    )
    truth = build_truth(frictionless, effects)
    e, f = truth.elastic, plant(truth)
    p = truth.pi_rigid
    j = joint - 1

    def energy(x):
        q, theta, dq, dtheta = x[:2], x[2], x[3:5], x[5]
        M_link = MODEL.mass_matrix(MODEL.vector(p), q[1])
        M_link[j, j] -= e.B  # the motor's inertia moves with θ, not with the link
        potential = p["b1"] * np.sin(q[0]) + p["b2"] * np.sin(q[0] + q[1]) + 0.5 * e.k * (theta - q[j]) ** 2
        return 0.5 * dq @ M_link @ dq + 0.5 * e.B * dtheta**2 + potential

    rng = np.random.default_rng(joint)
    for _ in range(5):
        q = rng.uniform([0.3, -1.3], [3.0, 1.3])
        x = np.concatenate([q, [q[j] + rng.normal(scale=0.02)], rng.normal(size=3)])
        tau = rng.normal(size=2)
        xdot = np.asarray(f(x, tau)[0]).ravel()
        eps = 1e-6
        rate = (energy(x + eps * xdot) - energy(x - eps * xdot)) / (2 * eps)
        velocities = [x[5], x[4]] if j == 0 else [x[3], x[5]]
        assert rate == pytest.approx(tau @ velocities, rel=1e-6, abs=1e-8)


@pytest.mark.parametrize("flexible", [0, 1])
def test_flexible_link_chain_unbent_is_the_datasheet_rigid_arm(robot, flexible):
    """The Lagrangian of the three-segment chain at φ = 0, dφ = 0 gives the rigid model's M and C dq + G."""
    armature = datasheet_armature(robot)
    z, dz, M, h = lagrangian_terms(robot, flexible, armature)
    f = ca.Function("f", [z, dz], [M, h])
    pi = MODEL.vector(datasheet_pi(robot, "physical"))
    rng = np.random.default_rng(flexible)
    for _ in range(5):
        q, dq = rng.uniform(-3, 3, 2), rng.normal(size=2)
        M_chain, h_chain = (np.array(v) for v in f([*q, 0.0], [*dq, 0.0]))
        M_rigid = MODEL.mass_matrix(pi, q[1])
        h_rigid = (
            MODEL.predict(pi, q[None], dq[None], np.zeros((1, 2)))[0]
            - MODEL.predict(pi * FRICTION_MASK, q[None], dq[None], np.zeros((1, 2)))[0]
        )
        np.testing.assert_allclose(M_chain[:2, :2], M_rigid, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(h_chain[:2, 0], h_rigid, rtol=1e-12, atol=1e-12)
