"""The true plant of an arm with n joints as CasADi expressions (`chain_plant.ArmPlant` gives its values): the rigid
dynamics with the hidden effects' extra inertia and friction terms, the gears' load-dependent friction solved to a
fixed point, an elastic joint's motor side; the plant function the loop integrates, its state and its initial state
at rest."""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ident_opt.arm.base import Arm
from ident_opt.simulator.chain_plant import ArmPlant, joint_terms_of, link_pi


# ---------------------------------------------------------------------------------------------- CasADi
@dataclass
class Symbols:
    """The plant's parameters as CasADi symbols, in `ArmPlant.parameters` order."""

    pi: ca.SX
    inertia: ca.SX
    up: ca.SX  # the positive level's excess over the datasheet's mean
    down: ca.SX
    excess: ca.SX
    velocity: ca.SX
    mu: ca.SX
    offset: ca.SX
    eps: ca.SX  # the friction sign's regularisation per joint [rad/s]
    spring: ca.SX  # k, d, B (elastic joint) or empty

    @classmethod
    def of(cls, plant: ArmPlant) -> Symbols:
        n, P = plant.n, len(plant.pi)
        sizes = [P, n, n, n, n, n, n, n, n, 3 if plant.elastic is not None else 0]
        names = ("pi", "inertia", "up", "down", "excess", "velocity", "mu", "offset", "eps", "spring")
        return cls(*(ca.SX.sym(name, size) for name, size in zip(names, sizes)))

    def vector(self) -> ca.SX:
        """All of them, stacked (the functions' parameter input)."""
        return ca.vertcat(
            self.pi,
            self.inertia,
            self.up,
            self.down,
            self.excess,
            self.velocity,
            self.mu,
            self.offset,
            self.eps,
            self.spring,
        )


def smooth_sign(v, eps) -> ca.SX:
    """tanh(v/ε): the sign of the effects' friction, regularised over ε [rad/s] (`ArmPlant.regularisation`)."""
    return ca.tanh(v / eps)


def extra_friction(s: Symbols, v) -> ca.SX:
    """The effects' friction at joint rates v (n,) [N m]: the per-direction levels' departure from the datasheet's
    mean and the Stribeck excess fs sgn(v) exp(−(v/vs)²), the sign regularised (`smooth_sign`)."""
    sign = smooth_sign(v, s.eps)
    positive, negative = 0.5 * (1 + sign), 0.5 * (1 - sign)
    stribeck = s.excess * sign * ca.exp(-((v / s.velocity) ** 2))
    return s.up * positive - s.down * negative + stribeck


def dynamics(arm: Arm, pi, q, dq, inertia=None) -> tuple[ca.SX, ca.SX]:
    """(M(q), h(q, dq)) of the arm's inverse dynamics τ = M ddq + h (+ diag(inertia) ddq): M = ∂τ/∂ddq, h = τ at
    ddq = 0 (`Arm.tau_expression`, one source of truth)."""
    a = ca.SX.sym("a", arm.n_joints)
    expr = arm.tau_expression(q, dq, a, pi)
    if inertia is not None:
        expr = expr + inertia * a
    return ca.jacobian(expr, a), ca.substitute(expr, a, ca.DM.zeros(arm.n_joints))


def forward(arm: Arm, pi, q, dq, tau, inertia=None) -> ca.SX:
    """ddq = M(q)⁻¹ (τ − h(q, dq)) from the arm's inverse dynamics (`dynamics`)."""
    M, h = dynamics(arm, pi, q, dq, inertia)
    return ca.solve(M, tau - h)


def loaded_forward(M, b, mu, rates, link_M, link_h, eps) -> ca.SX:
    """Accelerations of M a = b − μ ∘ sgn(v) ∘ |τ_load(a)|, the gears' load-dependent friction, with τ_load(a) =
    link_M a + link_h the link-side rigid torque (inertial without the rotors, Coriolis, gravity). |τ_load| =
    S τ_load with S the signs of τ_load at the load-free answer a₀ = M⁻¹ b, which makes the equation linear in a:
    (M + D S link_M) a = b − D S link_h, D = diag(μ sgn v) — exact wherever τ_load keeps its sign between a₀ and
    a (everywhere but the instants it crosses zero, where |τ_load| is small anyway)."""
    a0 = ca.solve(M, b)
    S = ca.sign(ca.mtimes(link_M, a0) + link_h)
    D = mu * smooth_sign(rates, eps) * S
    return ca.solve(M + ca.diag(D) @ link_M, b - D * link_h)


def plant_function(plant: ArmPlant) -> ca.Function:
    """The plant as a CasADi Function (x, τ, p) -> (ẋ, y), y = [q_enc (n), dq_enc (n), ddq_enc (n), deflection]:
    encoder angles (true − δ), their rates and the accelerations the dynamics produce; p = `ArmPlant.parameters`."""
    s = Symbols.of(plant)
    if plant.elastic is not None:
        return _elastic_function(plant, s)
    n, arm = plant.n, plant.arm
    x, tau = ca.SX.sym("x", 2 * n), ca.SX.sym("tau", n)
    q, dq = x[:n], x[n:]
    friction = extra_friction(s, dq)
    M, h = dynamics(arm, s.pi, q, dq, s.inertia)
    b = tau - friction - h
    if np.any(plant.load_friction):
        link_M, link_h = dynamics(arm, link_pi(arm, s.pi), q, dq)
        ddq = loaded_forward(M, b, s.mu, dq, link_M, link_h, s.eps)
    else:
        ddq = ca.solve(M, b)
    y = ca.vertcat(q - s.offset, dq, ddq, 0)
    return ca.Function("plant", [x, tau, s.vector()], [ca.vertcat(dq, ddq), y], ["x", "tau", "p"], ["xdot", "y"])


def _elastic_function(plant: ArmPlant, s: Symbols) -> ca.Function:
    """The plant with an elastic joint j: x = [q (n), θ, dq (n), dθ]; the link side is the rigid arm without joint
    j's own friction and armature, driven at joint j by the spring τ_s = k (θ − q_j) + d (dθ − dq_j); the motor,
    B θ̈ = τ_j − τ_s − F_j(dθ) (its gear friction, on the motor side), is what the encoder and the controller see."""
    n, arm, e = plant.n, plant.arm, plant.elastic
    j = e.index
    k, d, B = s.spring[0], s.spring[1], s.spring[2]
    x, tau = ca.SX.sym("x", 2 * n + 2), ca.SX.sym("tau", n)
    q, theta, dq, dtheta = x[:n], x[n], x[n + 1 : 2 * n + 1], x[2 * n + 1]
    motor = ca.DM(joint_terms_of(arm, j))
    link_side = s.pi * (1 - motor)
    spring = k * (theta - q[j]) + d * (dtheta - dq[j])
    unit = ca.DM.zeros(n)
    unit[j] = 1
    rates = ca.vertcat(*[dtheta if i == j else dq[i] for i in range(n)])  # the gears turn at the motor's rate
    friction = extra_friction(s, rates)
    v = unit * dtheta
    # joint j's own friction (and its share of the effects' friction) acts on the motor, before the spring
    motor_friction = arm.tau_expression(q, v, ca.DM.zeros(n), s.pi * motor)[j] + friction[j]
    others = ca.DM.ones(n) - unit
    link_inertia = s.inertia * others
    # The state's accelerations [ddq (n), ddθ] solve one linear system: the link side, M_l ddq + h_l = the joint
    # torques with the spring at joint j, and the motor, B ddθ = τ_j − τ_s − its friction.
    M_l, h_l = dynamics(arm, link_side, q, dq, link_inertia)
    M = ca.blockcat([[M_l, ca.SX.zeros(n, 1)], [ca.SX.zeros(1, n), B]])
    b = ca.vertcat(tau * others + unit * spring - friction * others - h_l, tau[j] - spring - motor_friction)
    if np.any(plant.load_friction):
        # joint j's gears carry the spring torque (no acceleration term); the others their link-side torque
        link_M, link_h = dynamics(arm, link_pi(arm, s.pi), q, dq)
        select = ca.diag(others)
        load_M = ca.horzcat(select @ link_M, ca.SX.zeros(n, 1))
        load_h = select @ link_h + unit * spring
        moving = ca.vertcat(rates, dtheta)
        acc = loaded_forward(
            M,
            b,
            ca.vertcat(s.mu * others, s.mu[j]),
            moving,
            ca.vertcat(load_M, ca.SX.zeros(1, n + 1)),
            ca.vertcat(load_h, spring),
            ca.vertcat(s.eps, s.eps[j]),
        )
    else:
        acc = ca.solve(M, b)
    ddq, ddtheta = acc[:n], acc[n]
    xdot = ca.vertcat(dq, dtheta, ddq, ddtheta)
    encoder = ca.vertcat(*[theta if i == j else q[i] for i in range(n)])
    y = ca.vertcat(
        encoder - s.offset, rates, ca.vertcat(*[ddtheta if i == j else ddq[i] for i in range(n)]), theta - q[j]
    )
    return ca.Function("plant", [x, tau, s.vector()], [xdot, y], ["x", "tau", "p"], ["xdot", "y"])


def state_size(plant: ArmPlant) -> int:
    """Length of the state x: [q (n), dq (n)], or [q (n), θ, dq (n), dθ] with an elastic joint."""
    return 2 * plant.n + (2 if plant.elastic is not None else 0)


def initial_state(plant: ArmPlant, q_enc: np.ndarray) -> np.ndarray:
    """A state at rest whose encoders read `q_enc` [rad]; behind an elastic joint the link hangs at the spring's
    static deflection, k (θ − q_j) = G_j(q)."""
    q = np.asarray(q_enc, dtype=float) + plant.offset
    n = plant.n
    if plant.elastic is None:
        return np.concatenate([q, np.zeros(n)])
    e = plant.elastic
    theta = q[e.index]
    gravity = plant.arm.function("G")
    rigid = link_pi(plant.arm, plant.pi)
    zero = np.zeros(n)
    for _ in range(30):  # fixed point of k (θ − q_j) = G_j(q): the spring holds the link against gravity
        q[e.index] = theta - float(gravity(q, zero, zero, rigid)[e.index]) / e.k
    return np.concatenate([q, [theta], zero, [0.0]])
