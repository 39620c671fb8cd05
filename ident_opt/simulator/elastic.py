"""The planar two-link arm's elastic mechanisms as plants: a two-mass elastic joint (the motor angle logged) or a
flexible link (`flexible_link`: a link cut in two halves joined by a spring), built from what the `elasticity`
effect describes (`Effect.mechanism`: kind, joint, frequency, damping) on the true plant (`truth.PlantSpec`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from ident_opt.effects.elasticity import Q2_RANGE, Mode, natural_hz, spring_for
from ident_opt.simulator import flexible_link
from ident_opt.simulator.planar_dynamics import TRUTH_MODEL, friction_only, link_pi, solve_forward, with_load_friction


@dataclass(frozen=True)
class Elastic(Mode):
    """The planar arm's elastic joint (two-mass, `kind` "joint") or flexible link ("link", `flexible_link`), with
    its frequency's range over the workspace [Hz] (joint 1's link inertia depends on q2)."""

    frequency_range_hz: tuple[float, float] = field(kw_only=True)
    kind: str = field(default="joint", kw_only=True)

    #: The state: [q (2), θ, dq (2), dθ] (elastic joint) or [q (2), φ, dq (2), dφ] (flexible link).
    state_size = 6

    def rates(self, kd: tuple[float, float]) -> list[float]:
        """The fastest closed-loop rate [1/s] the mode adds under PD damping gains kd [N m s/rad]."""
        return [self.fastest_rate + kd[self.index] / self.B]

    def spring(self, e, de):
        """The joint's spring and damper torque [N m] at deflection e = θ − q_j [rad] and its rate [rad/s] (linear
        here; `simulator.unseen.NonlinearJoint` shapes it)."""
        return self.k * e + self.d * de

    def static_deflection(self, torque: float) -> float:
        """The deflection [rad] at which the spring holds `torque` [N m] at rest."""
        return torque / self.k

    def plant(self, truth) -> ca.Function:
        """(x, τ) -> (ẋ, y) as `simulator.truth.plant`, y's deflection θ − q_j (joint) or φ (link)."""
        x, tau = ca.SX.sym("x", self.state_size), ca.SX.sym("tau", 2)
        delta = ca.DM(truth.offset)
        if self.kind == "link":
            return self._link_plant(truth, x, tau, delta)
        model, pi, j = truth.model, truth.pi, self.index
        q, theta, dq, dtheta = x[:2], x[2], x[3:5], x[5]
        link = pi - friction_only(model, pi, j)  # the link side: no friction and no motor inertia at j
        link[model.names.index("a1" if j == 0 else "ia2")] -= self.B
        spring = self.spring(theta - q[j], dtheta - dq[j])
        v = ca.vertcat(dtheta, 0) if j == 0 else ca.vertcat(0, dtheta)
        motor_friction = model.tau_expression(q, v, ca.DM.zeros(2), ca.DM(friction_only(model, pi, j)))[j]
        other = 1 - j
        rigid_side = ca.DM(link_pi(model, pi, truth.armature))

        def solve(extra):  # [ddq (2), ddθ]; the gear friction of joint j acts on its motor, before the spring
            tau_link = ca.vertcat(spring, tau[1] - extra[1]) if j == 0 else ca.vertcat(tau[0] - extra[0], spring)
            ddq = solve_forward(model, ca.DM(link), q, dq, tau_link)
            return ca.vertcat(ddq, (tau[j] - spring - motor_friction - extra[j]) / self.B)

        def load(a):  # joint j's gears transmit the spring torque; the other joint's, its link-side torque
            rows = [None, None]
            rows[j], rows[other] = spring, model.tau_expression(q, dq, a[:2], rigid_side)[other]
            return ca.vertcat(*rows)

        rates = ca.vertcat(dtheta, dq[1]) if j == 0 else ca.vertcat(dq[0], dtheta)
        acc = with_load_friction(truth, rates, solve, load)
        ddq, ddtheta = acc[:2], acc[2]
        xdot = ca.vertcat(dq, dtheta, ddq, ddtheta)
        q_enc = ca.vertcat(theta, q[1]) if j == 0 else ca.vertcat(q[0], theta)
        dq_enc = ca.vertcat(dtheta, dq[1]) if j == 0 else ca.vertcat(dq[0], dtheta)
        ddq_enc = ca.vertcat(ddtheta, ddq[1]) if j == 0 else ca.vertcat(ddq[0], ddtheta)
        y = ca.vertcat(q_enc - delta, dq_enc, ddq_enc, theta - q[j])
        return ca.Function("plant", [x, tau], [xdot, y], ["x", "tau"], ["xdot", "y"])

    def _link_plant(self, truth, x, tau, delta) -> ca.Function:
        """The flexible-link plant (see flexible_link.py): x = [q1, q2, φ, dq1, dq2, dφ]."""
        model, pi = truth.model, truth.pi
        z, dz, M, h = flexible_link.lagrangian_terms(truth.robot, self.index, truth.armature)
        friction_pi = friction_only(model, pi, 0) + friction_only(model, pi, 1)
        F = model.tau_expression(z[:2], dz[:2], ca.DM.zeros(2), ca.DM(friction_pi))
        B = ca.DM(truth.armature)

        def solve(extra):  # ddz; the gears' load friction reduces the joint torques
            return ca.solve(M, ca.vertcat(tau - F - extra, -self.k * z[2] - self.d * dz[2]) - h)

        def load(a):  # the link-side torque at the joints: M a + h without the rotors' B ddq
            return (ca.mtimes(M, a) + h)[:2] - B * a[:2]

        ddz = with_load_friction(truth, dz[:2], solve, load)
        motion = ca.Function("motion", [z, dz, tau], [ddz])
        ddz_x = motion(x[:3], x[3:], tau)
        xdot = ca.vertcat(x[3:], ddz_x)
        y = ca.vertcat(x[:2] - delta, x[3:5], ddz_x[:2], x[2])
        return ca.Function("plant", [x, tau], [xdot, y], ["x", "tau"], ["xdot", "y"])

    def initial_state(self, truth, q: np.ndarray) -> np.ndarray:
        """A state at rest with true joint angles `q` [rad], the spring at its static deflection."""
        if self.kind == "link":  # the static bend: k φ = −∂V/∂φ
            z, dz, _, h = flexible_link.lagrangian_terms(truth.robot, self.index, truth.armature)
            dV = ca.Function("dV", [z], [ca.substitute(h, dz, ca.DM.zeros(3))[2]])
            phi = 0.0
            for _ in range(20):
                phi = -float(dV([q[0], q[1], phi])) / self.k
            return np.array([q[0], q[1], phi, 0.0, 0.0, 0.0])
        theta = q[self.index]
        gravity = TRUTH_MODEL.function("G")
        link_pi = TRUTH_MODEL.vector(truth.pi_rigid)
        for _ in range(20):  # fixed point of k (θ − q_j) = G_j(q): the spring holds the link against gravity
            q[self.index] = theta - self.static_deflection(float(gravity(q, [0, 0], [0, 0], link_pi)[self.index]))
        return np.concatenate([q, [theta], [0.0, 0.0, 0.0]])


def elastic_joint(plant, j: int, f: float, zeta: float) -> Elastic:
    """Joint j (0-based) elastic at f [Hz] with damping ratio ζ, on the true plant `plant` (a `PlantSpec`)."""
    pi = plant.pi
    B = plant.armature[j]  # the motor side: reflected rotor inertia
    J_link = (pi["a1"] - B + 2 * pi["a2"]) if j == 0 else pi["a3"]
    k, d = spring_for(J_link, f, zeta)
    if j == 0:  # J_l(q2) = a1 − B + 2 a2 cos q2 over the trajectories' range of q2
        inertias = [pi["a1"] - B + 2 * pi["a2"] * math.cos(q2) for q2 in Q2_RANGE]
    else:
        inertias = [J_link, J_link]
    band = tuple(natural_hz(k, J) for J in inertias)
    w_free = math.sqrt(k * (1 / B + 1 / min(inertias)))
    rate = w_free + d * (1 / B + 1 / min(inertias))
    return Elastic(j, k, d, B, J_link, f, zeta, rate, frequency_range_hz=band, kind="joint")


def flexible(plant, j: int, f: float, zeta: float) -> Elastic:
    """Link j (0-based) flexible at f [Hz] with damping ratio ζ, on the true plant `plant` (a `PlantSpec`)."""
    robot, armature = plant.robot, tuple(plant.armature)
    J = flexible_link.mode_inertia(robot, j, armature, 0.0)
    k, d = spring_for(J, f, zeta)
    inertias = [flexible_link.mode_inertia(robot, j, armature, q2) for q2 in Q2_RANGE]
    band = tuple(natural_hz(k, Jq) for Jq in inertias)
    w_free = flexible_link.free_rate(robot, j, armature, k)
    rate = w_free + d * w_free**2 / k  # d (M⁻¹)_φφ, with (M⁻¹)_φφ = ω²/k
    return Elastic(j, k, d, armature[j], J, f, zeta, rate, frequency_range_hz=band, kind="link")


def build(plant, kind: str, joint: int, frequency_hz: float, damping: float) -> Elastic:
    """The mechanism of `kind` ("joint": an elastic joint; "link": a flexible link) at `joint` (0-based), of
    `frequency_hz` [Hz] and damping ratio `damping`, on the true plant `plant` (a `truth.PlantSpec`)."""
    make = elastic_joint if kind == "joint" else flexible
    return make(plant, joint, frequency_hz, damping)
