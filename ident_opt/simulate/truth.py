"""The truth plant: the physical-convention datasheet arm plus the hidden effects, as CasADi expressions.

Without effects the plant is exactly `ArmModel(("armature",))` with `datasheet_pi(robot, "physical")`:
M(q) ddq + C(q, dq) dq + G(q) + F(dq) = τ. Effects change it as follows (values in SI units):

- ``payload``: the datasheet robot with a point mass at the tip of link 2 (π changes along that direction);
- ``armature``: extra reflected inertia J1 on a1 and J2 on ia2 (the diagonal of M);
- ``asymmetric_coulomb`` / ``stribeck``: the friction F(dq) of the model extensions of the same names;
- ``elasticity``: joint j becomes a two-mass (Spong) model. The motor (inertia B = the joint's armature,
  its friction F_j) drives the link through a spring k and damper d: τ_s = k (θ − q_j) + d (dθ − dq_j),
  B ddθ + F_j(dθ) = τ_j − τ_s, and the link side is the rigid model without that armature and friction,
  driven by τ_s at joint j. k = J_l (2π f)², d = 2 ζ √(k J_l), with J_l the link-side inertia at joint j
  (joint 1: at q2 = 0 with joint 2 held). The logged angle of joint j is the motor's θ.
- ``elasticity`` with ``kind=link``: link j is cut at mid-length into two rigid halves joined by a
  torsional spring (see flexible_link.py); the joints stay rigid and their angles are logged.
- ``joint_offset`` and ``delay`` act on the measurements (see measurement.py); the true angle is the logged
  (encoder) angle + δ.

Background terms (effects.BACKGROUND: stiction, drift, ripple) are kept apart in `Truth.background` and
wrapped around this plant by background.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np

from ident_opt.datasheet import datasheet_pi, rigid_body
from ident_opt.effects import BACKGROUND
from ident_opt.problem import Robot
from ident_opt.robot import ArmModel
from ident_opt.simulate import flexible_link

#: The structure of `SimTrial.truth["pi"]`.
TRUTH_MODEL = ArmModel(("armature",))


@dataclass(frozen=True)
class Elastic:
    """An elastic joint or flexible link: which (0-based), stiffness k [N m/rad], damping d [N m s/rad],
    motor inertia B [kg m²], the inertia J [kg m²] used for k, and the natural frequency f [Hz]."""

    index: int
    k: float
    d: float
    B: float
    J_link: float
    frequency_hz: float
    damping: float
    frequency_range_hz: tuple[float, float]  # over the workspace (joint 1: J_l depends on q2)
    kind: str = "joint"  # "joint" (two-mass) or "link" (flexible link, see flexible_link.py)
    fastest_rate: float = 0.0  # rad/s, a bound of the mode's rate with free joints (sizes the RK4 step)


@dataclass(frozen=True)
class Truth:
    """The true plant: its model structure, π (vector in `model.names` order), and effects."""

    robot: Robot  # the datasheet robot with any hidden payload
    model: ArmModel
    pi: np.ndarray
    elastic: Elastic | None
    offset: tuple[float, float]
    delay: float
    effects: dict
    background: dict = field(default_factory=dict)  # background realism terms (effects.BACKGROUND)

    @property
    def pi_rigid(self) -> dict[str, float]:
        """π in `TRUTH_MODEL`'s names (Coulomb as the mean of the per-direction levels)."""
        p = self.model.as_dict(self.pi)
        out = {name: p[name] for name in TRUTH_MODEL.names if name in p}
        for j in ("1", "2"):
            if "fc" + j not in out:
                out["fc" + j] = 0.5 * (p["fc" + j + "p"] + p["fc" + j + "n"])
        return {name: out[name] for name in TRUTH_MODEL.names}


def coulomb_levels(robot: Robot) -> tuple[tuple, tuple]:
    """The datasheet's per-direction Coulomb levels reflected to the joint [N m]: (positive, negative)."""
    body = rigid_body(robot, "physical")
    return tuple(body.fc_positive), tuple(body.fc_negative)


def build_truth(robot: Robot, effects: dict[str, dict]) -> Truth:
    """The true plant for the (normalised, active) `effects`; background terms go to `Truth.background`."""
    background = {name: p for name, p in effects.items() if name in BACKGROUND}
    effects = {name: p for name, p in effects.items() if name not in BACKGROUND}
    true_robot = robot
    if "payload" in effects:
        true_robot = replace(robot, payload_mass=robot.payload_mass + effects["payload"]["mass"])
    pi = datasheet_pi(true_robot, "physical")
    extensions = ["armature"]
    stribeck_velocity = (0.05, 0.05)
    if "armature" in effects:
        J1, J2 = effects["armature"]["inertia"]
        pi["a1"] += J1
        pi["ia2"] += J2
    if "asymmetric_coulomb" in effects:
        extensions.append("asymmetric_coulomb")
        for j, (p, n) in enumerate(
            zip(effects["asymmetric_coulomb"]["positive"], effects["asymmetric_coulomb"]["negative"]), start=1
        ):
            pi[f"fc{j}p"], pi[f"fc{j}n"] = p, n
    if "stribeck" in effects:
        extensions.append("stribeck")
        pi["fs1"], pi["fs2"] = effects["stribeck"]["static"]
        stribeck_velocity = tuple(effects["stribeck"]["velocity"])
    model = ArmModel(tuple(extensions), stribeck_velocity=stribeck_velocity)
    vector = model.vector(pi)
    elastic = None
    if "elasticity" in effects:
        e = effects["elasticity"]
        make = _elastic if e["kind"] == "joint" else _flexible_link
        elastic = make(true_robot, effects, pi, e["joint"] - 1, e["frequency_hz"], e["damping"])
    offset = tuple(effects["joint_offset"]["offset"]) if "joint_offset" in effects else (0.0, 0.0)
    delay = effects["delay"]["seconds"] if "delay" in effects else 0.0
    return Truth(true_robot, model, vector, elastic, offset, delay, effects, background)


def _elastic(robot: Robot, effects: dict, pi: dict, j: int, f: float, zeta: float) -> Elastic:
    B = _armature(robot, effects)[j]  # the motor side: reflected rotor inertia
    J_link = (pi["a1"] - B + 2 * pi["a2"]) if j == 0 else pi["a3"]
    k = J_link * (2 * math.pi * f) ** 2
    if j == 0:  # J_l(q2) = a1 − B + 2 a2 cos q2 over |q2| ≤ 1.4 rad (the trajectories' range)
        inertias = [pi["a1"] - B + 2 * pi["a2"] * math.cos(q2) for q2 in (0.0, 1.4)]
    else:
        inertias = [J_link, J_link]
    band = tuple(math.sqrt(k / J) / (2 * math.pi) for J in inertias)
    d = 2 * zeta * math.sqrt(k * J_link)
    w_free = math.sqrt(k * (1 / B + 1 / min(inertias)))
    rate = w_free + d * (1 / B + 1 / min(inertias))
    return Elastic(j, k, d, B, J_link, f, zeta, band, "joint", rate)


def _flexible_link(robot: Robot, effects: dict, pi: dict, j: int, f: float, zeta: float) -> Elastic:
    armature = _armature(robot, effects)
    J = flexible_link.mode_inertia(robot, j, armature, 0.0)
    k = J * (2 * math.pi * f) ** 2
    inertias = [flexible_link.mode_inertia(robot, j, armature, q2) for q2 in (0.0, 1.4)]
    band = tuple(math.sqrt(k / Jq) / (2 * math.pi) for Jq in inertias)
    d = 2 * zeta * math.sqrt(k * J)
    w_free = flexible_link.free_rate(robot, j, armature, k)
    rate = w_free + d * w_free**2 / k  # d (M⁻¹)_φφ, with (M⁻¹)_φφ = ω²/k
    return Elastic(j, k, d, armature[j], J, f, zeta, band, "link", rate)


def _armature(robot: Robot, effects: dict) -> tuple[float, float]:
    """Reflected rotor inertia per joint, datasheet plus any hidden extra [kg m²]."""
    extra = effects["armature"]["inertia"] if "armature" in effects else (0.0, 0.0)
    return tuple(a + x for a, x in zip(rigid_body(robot, "physical").armature, extra))


# ---------------------------------------------------------------------------------------------- dynamics
def _solve_forward(model: ArmModel, pi, q, dq, tau) -> ca.SX:
    """ddq = M(q)⁻¹ (τ − h(q, dq)) from the model's inverse dynamics τ = M ddq + h (one source of truth)."""
    a = ca.SX.sym("a", 2)
    expr = model.tau_expression(q, dq, a, pi)
    M = ca.jacobian(expr, a)
    h = ca.substitute(expr, a, ca.DM.zeros(2))
    return ca.solve(M, tau - h)


def _friction_only(model: ArmModel, pi: np.ndarray, joint: int) -> np.ndarray:
    """π with everything zeroed except the friction parameters of `joint` (0-based)."""
    keep = {f"fv{joint + 1}", f"fc{joint + 1}", f"fc{joint + 1}p", f"fc{joint + 1}n", f"fs{joint + 1}"}
    return np.array([v if n in keep else 0.0 for n, v in zip(model.names, pi)])


def state_size(truth: Truth) -> int:
    """Length of the state x: [q (2), dq (2)], or [q (2), θ, dq (2), dθ] with an elastic joint, or
    [q (2), φ, dq (2), dφ] with a flexible link."""
    return 4 if truth.elastic is None else 6


def plant(truth: Truth) -> ca.Function:
    """The plant as a CasADi Function (x, τ) -> (ẋ, y) with y = [q_enc (2), dq_enc (2), ddq_enc (2), θ − q_j]:
    encoder angle (true angle − δ, motor side at an elastic joint), its rate and the acceleration the
    dynamics produce [rad, rad/s, rad/s²], and the spring deflection [rad] (0 when rigid)."""
    nx = state_size(truth)
    x, tau = ca.SX.sym("x", nx), ca.SX.sym("tau", 2)
    model, pi, e = truth.model, truth.pi, truth.elastic
    delta = ca.DM(truth.offset)
    if e is not None and e.kind == "link":
        return _link_plant(truth, x, tau, delta)
    if e is None:
        q, dq = x[:2], x[2:]
        ddq = _solve_forward(model, ca.DM(pi), q, dq, tau)
        xdot = ca.vertcat(dq, ddq)
        y = ca.vertcat(q - delta, dq, ddq, 0)
    else:
        j = e.index
        q, theta, dq, dtheta = x[:2], x[2], x[3:5], x[5]
        link = _friction_only(model, pi, j)
        link = pi - link  # the link side: no friction and no motor inertia at joint j
        names = model.names
        if j == 0:
            link[names.index("a1")] -= e.B
        else:
            link[names.index("ia2")] -= e.B
        spring = e.k * (theta - q[j]) + e.d * (dtheta - dq[j])
        tau_link = ca.vertcat(spring, tau[1]) if j == 0 else ca.vertcat(tau[0], spring)
        ddq = _solve_forward(model, ca.DM(link), q, dq, tau_link)
        v = ca.vertcat(dtheta, 0) if j == 0 else ca.vertcat(0, dtheta)
        motor_friction = model.tau_expression(q, v, ca.DM.zeros(2), ca.DM(_friction_only(model, pi, j)))[j]
        ddtheta = (tau[j] - spring - motor_friction) / e.B
        xdot = ca.vertcat(dq, dtheta, ddq, ddtheta)
        q_enc = ca.vertcat(theta, q[1]) if j == 0 else ca.vertcat(q[0], theta)
        dq_enc = ca.vertcat(dtheta, dq[1]) if j == 0 else ca.vertcat(dq[0], dtheta)
        ddq_enc = ca.vertcat(ddtheta, ddq[1]) if j == 0 else ca.vertcat(ddq[0], ddtheta)
        y = ca.vertcat(q_enc - delta, dq_enc, ddq_enc, theta - q[j])
    return ca.Function("plant", [x, tau], [xdot, y], ["x", "tau"], ["xdot", "y"])


def _link_plant(truth: Truth, x, tau, delta) -> ca.Function:
    """The flexible-link plant (see flexible_link.py): x = [q1, q2, φ, dq1, dq2, dφ]."""
    e, model, pi = truth.elastic, truth.model, truth.pi
    z, dz, M, h = flexible_link.lagrangian_terms(truth.robot, e.index, _armature_of(truth))
    friction_pi = _friction_only(model, pi, 0) + _friction_only(model, pi, 1)
    F = model.tau_expression(z[:2], dz[:2], ca.DM.zeros(2), ca.DM(friction_pi))
    Q = ca.vertcat(tau - F, -e.k * z[2] - e.d * dz[2])
    ddz = ca.solve(M, Q - h)
    motion = ca.Function("motion", [z, dz, tau], [ddz])
    ddz_x = motion(x[:3], x[3:], tau)
    xdot = ca.vertcat(x[3:], ddz_x)
    y = ca.vertcat(x[:2] - delta, x[3:5], ddz_x[:2], x[2])
    return ca.Function("plant", [x, tau], [xdot, y], ["x", "tau"], ["xdot", "y"])


def _armature_of(truth: Truth) -> tuple[float, float]:
    """The true plant's reflected rotor inertia per joint [kg m²] (a1 holds joint 1's; ia2 is joint 2's)."""
    return _armature(truth.robot, truth.effects)


def initial_state(truth: Truth, q_enc: np.ndarray) -> np.ndarray:
    """A state at rest whose encoders read `q_enc` [rad]; an elastic joint starts at its static deflection."""
    q = np.asarray(q_enc, dtype=float) + np.asarray(truth.offset)
    if truth.elastic is None:
        return np.concatenate([q, [0.0, 0.0]])
    e = truth.elastic
    if e.kind == "link":  # the static bend: k φ = −∂V/∂φ
        z, dz, _, h = flexible_link.lagrangian_terms(truth.robot, e.index, _armature_of(truth))
        dV = ca.Function("dV", [z], [ca.substitute(h, dz, ca.DM.zeros(3))[2]])
        phi = 0.0
        for _ in range(20):
            phi = -float(dV([q[0], q[1], phi])) / e.k
        return np.array([q[0], q[1], phi, 0.0, 0.0, 0.0])
    theta = q[e.index]
    gravity = TRUTH_MODEL.function("G")
    link_pi = TRUTH_MODEL.vector(truth.pi_rigid)
    for _ in range(20):  # fixed point of k (θ − q_j) = G_j(q): the spring holds the link against gravity
        q[e.index] = theta - float(gravity(q, [0, 0], [0, 0], link_pi)[e.index]) / e.k
    return np.concatenate([q, [theta], [0.0, 0.0, 0.0]])
