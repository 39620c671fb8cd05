"""The planar two-link arm's true rigid dynamics, as the simulator's plants use them (the rigid arm of `truth`, the
elastic joint and flexible link of `elastic`): forward dynamics from the one model of the arm (`TRUTH_MODEL`),
and the gears' load-dependent friction solved to a fixed point."""

from __future__ import annotations

import casadi as ca
import numpy as np

from ident_opt.arm.planar import PHYSICAL, PlanarArm

#: The structure of `SimTrial.truth["pi"]`: the nominal physical-convention arm.
TRUTH_MODEL = PHYSICAL


def solve_forward(model: PlanarArm, pi, q, dq, tau) -> ca.SX:
    """ddq = M(q)⁻¹ (τ − h(q, dq)) from the model's inverse dynamics τ = M ddq + h (one source of truth)."""
    a = ca.SX.sym("a", 2)
    expr = model.tau_expression(q, dq, a, pi)
    M = ca.jacobian(expr, a)
    h = ca.substitute(expr, a, ca.DM.zeros(2))
    return ca.solve(M, tau - h)


def link_pi(model: PlanarArm, pi: np.ndarray, armature) -> np.ndarray:
    """π of the link side (`PlanarArm.link_side`)."""
    return model.link_side(pi, armature)


#: Fixed-point passes that solve the load-dependent friction's implicit dependence on the acceleration.
LOAD_FRICTION_PASSES = 4


def with_load_friction(truth, rates, solve, load) -> ca.SX:
    """Accelerations of a plant whose gears add load-dependent friction μ_j sgn(v_j) |τ_load,j| (`load_friction`;
    one home for every plant: rigid, elastic joint, flexible link).

    `solve(extra)`: the plant's accelerations with the joint torques reduced by `extra` (2,) [N m]; `load(a)`:
    the link-side rigid torque τ_load (2,) [N m] at accelerations `a` (inertial without the rotors, Coriolis,
    gravity; it depends on a, hence the fixed-point passes from the load-free answer, a contraction for
    μ·(link inertia ÷ joint inertia) < 1); `rates` (2,) [rad/s]: the gear-side joint rates the friction opposes.
    """
    a = solve(ca.DM.zeros(2))
    if not any(truth.load_friction):
        return a
    mu = ca.DM(truth.load_friction)
    for _ in range(LOAD_FRICTION_PASSES):
        a = solve(mu * ca.sign(rates) * ca.fabs(load(a)))
    return a


def friction_only(model: PlanarArm, pi: np.ndarray, joint: int) -> np.ndarray:
    """π of `joint`'s friction alone (`PlanarArm.friction_of`)."""
    return model.friction_of(pi, joint)
