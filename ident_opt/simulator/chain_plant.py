"""The true plant of an arm with n joints, through the `Arm` and `Robot` interfaces alone.

Without effects the plant is the robot's nominal model (`Robot.datasheets()[Robot.datasheet]`: the URDF's
inertials with the problem's joint values) as τ = Y(q, dq, ddq) π = M(q) ddq + h(q, dq): its inverse dynamics
is the arm's own CasADi expression (`Arm.tau_expression`), and its forward dynamics solves it for ddq,

    M(q) = ∂τ/∂ddq,   h(q, dq) = τ(q, dq, 0),   ddq = M(q)⁻¹ (τ_applied − h(q, dq)),

which `tests/test_simulate_arm.py` checks against Pinocchio's ABA. Each hidden effect of
`ident_opt.effects.CATALOGUE` shapes it through its hook `Effect.chain_plant` (applied in catalogue order), on any
joint: extra diagonal inertia (armature), per-direction Coulomb levels and a Stribeck excess on the joint's
velocity, load-dependent friction, a point mass on the last link (π changes), encoder zero offsets, the logged
torque channel (a delay, a scale), and `Effect.chain_mechanism`: an elastic joint (`ElasticJoint`), whose motor
side is logged and driven and whose link side sits behind a spring.

Every number that sizes the plant (π, the extra terms, the spring) is an input of the CasADi functions, not a
constant in them, so the compiled closed loop (`chain_loop`) is built once per arm and structure.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from ident_opt.arm.base import Arm, Robot
from ident_opt.effects import CATALOGUE
from ident_opt.effects.elasticity import Mode, spring_for
from ident_opt.effects.keys import ArmScale, Joints
from ident_opt.errors import InputError

#: The fastest rate [1/s] the regularised friction of the effects may add (`ArmPlant.regularisation`): 32 RK4 steps
#: per 1 ms tick near a reversal (`chain_loop.tick`), and its narrowest regularisation [rad/s].
FRICTION_RATE, MIN_EPS = 8000.0, 1e-4
#: An elastic joint whose nominal motor inertia (reflected rotor inertia) is 0 gets this share of its link-side
#: inertia as a motor: a two-mass joint needs a motor side (`ElasticJoint`).
MOTOR_SHARE = 0.5
#: Parameter kinds that are not the link-side rigid body (`link_pi`).
JOINT_KINDS = ("friction", "armature", "other")


@dataclass(frozen=True)
class ElasticJoint(Mode):
    """Joint `index` (0-based) elastic (`Mode`): the motor side B is logged and driven, J_link is the link-side
    inertia at the centre pose (the frequency with the other joints held); `motor_added`: B was not in the datasheet
    (`MOTOR_SHARE`)."""

    motor_added: bool = field(kw_only=True)
    #: The link-side inertia over the trial's motion (mean, least, largest) [kg m²] (`link_inertia`), once run: the
    #: spring's frequency moves with the other joints' angles (the Panda's shoulder: 5.9–12 Hz over one trial).
    trial_inertia: tuple[float, float, float] | None = field(default=None, kw_only=True)


@dataclass
class ArmPlant:
    """The true plant while the hidden effects shape it (`Effect.chain_plant` changes it in place). Arrays are per
    joint (n,) unless said."""

    robot: Robot
    arm: Arm
    pi: np.ndarray  # true π (P,) in the arm's order
    nominal: np.ndarray  # the datasheet's π (P,): the controller's model
    scale: ArmScale
    joints: Joints  # the datasheet's per-direction Coulomb levels, names, reference magnitudes
    inertia: np.ndarray  # extra diagonal inertia [kg m²] beyond π's (armature)
    positive: np.ndarray  # true Coulomb level for dq > 0 [N m] (the datasheet's mean unless an effect changes it)
    negative: np.ndarray  # true Coulomb level for dq < 0 [N m]
    excess: np.ndarray  # Stribeck excess over the Coulomb level [N m]
    velocity: np.ndarray  # Stribeck velocity [rad/s] (> 0)
    load_friction: np.ndarray  # μ: Coulomb level grows by μ |τ_load|
    offset: np.ndarray  # encoder zero offsets δ [rad]: the true angle is the logged one + δ
    channel: list[Callable] = field(default_factory=list)  # the logged torque: (t [s], τ (N, n)) -> logged τ
    elastic: ElasticJoint | None = None
    effects: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        """The number of joints."""
        return self.arm.n_joints

    @property
    def mean_coulomb(self) -> np.ndarray:
        """The datasheet's symmetric Coulomb level per joint [N m] (what π holds)."""
        return np.array([0.5 * (a + b) for a, b in zip(*self.joints)])

    def logged_torque(self, t: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The torque channel as logged at the ticks t [s]: τ (N, n) [N m] through the channel's effects, in order."""
        for transform in self.channel:
            tau = transform(t, tau)
        return tau

    def parameters(self) -> np.ndarray:
        """Every number the plant's functions take (`Symbols`), in their order."""
        e = self.elastic
        spring = [e.k, e.d, e.B] if e is not None else []
        velocity = np.where(self.excess != 0, self.velocity, 1.0)  # any vs > 0 where there is no excess
        return np.concatenate(
            [
                self.pi,
                self.inertia,
                self.positive - self.mean_coulomb,
                self.negative - self.mean_coulomb,
                self.excess,
                velocity,
                self.load_friction,
                self.offset,
                self.regularisation,
                spring,
            ]
        )

    @property
    def regularisation(self) -> np.ndarray:
        """ε (n,) [rad/s]: the speed over which the effects' friction changes sign (`smooth_sign`). With a sharp
        sign a friction step on a light joint (a wrist without its rotor) chatters at the control rate instead of
        sticking; ε is the narrowest the integration resolves at `FRICTION_RATE` [1/s] (the step over half the
        joint's nominal inertia), at least `MIN_EPS`: far below the Stribeck velocities drawn (3–8 % of the
        cruise speed)."""
        step, inertia = self._friction_step()
        return np.where(step > 0, np.maximum(step / (inertia * FRICTION_RATE), MIN_EPS), 1.0)

    @property
    def friction_rate(self) -> float:
        """The fastest rate [1/s] the regularised friction adds (the substeps' sizing, `chain_loop.substeps`)."""
        step, inertia = self._friction_step()
        return float(np.max(step / (inertia * self.regularisation)))

    def stiff_band(self, rate: float) -> np.ndarray:
        """(n,) [rad/s]: per joint, the speed below which the effects' friction changes faster than `rate` [1/s]
        (|∂F/∂v| / inertia, the sign's `smooth_sign` and the Stribeck fall-off together; `_friction_step`'s
        inertia), 0 where it never does. Away from a reversal an explicit step sized for the rest of the loop
        integrates it; inside the band the loop takes the fine step (`chain_loop.tick`)."""
        step, inertia = self._friction_step()
        eps, excess, vs = self.regularisation, np.abs(self.excess), np.where(self.excess != 0, self.velocity, 1.0)
        v = np.geomspace(1e-7, 1e2, 2000)[:, None]  # a grid fine enough for the band's edge within 1 %
        sech2 = 1.0 / np.cosh(np.minimum(v / eps, 350.0)) ** 2
        slope = step / eps * sech2 + excess * 2 * v / vs**2 * np.exp(-((v / vs) ** 2))
        fast = slope / inertia > rate
        edge = np.where(fast.any(0), v[::-1][np.argmax(fast[::-1], axis=0), 0], 0.0)
        return np.where(step > 0, edge, 0.0)

    def _friction_step(self) -> tuple[np.ndarray, np.ndarray]:
        """The effects' friction step across zero speed per joint [N m] (per-direction departures, the Stribeck
        excess, the load friction at the reference torque) and the inertia it acts on [kg m²] (half the joint's
        nominal one plus the armature: the light side of an elastic joint)."""
        step = (
            np.abs(self.positive - self.mean_coulomb) + np.abs(self.negative - self.mean_coulomb) + np.abs(self.excess)
        )
        step = step + self.load_friction * np.asarray(self.scale.torque)
        return step, 0.5 * np.maximum(np.asarray(self.scale.inertia) + self.inertia, 1e-9)


def link_pi(arm: Arm, pi):
    """π of the link side: the joint terms (friction, armature, offsets: `JOINT_KINDS`) zeroed, so that Y π is the
    link-side rigid-body torque (inertial, Coriolis/centrifugal, gravity). Works on NumPy and CasADi vectors."""
    mask = np.array([p.kind not in JOINT_KINDS for p in arm.parameters], dtype=float)
    return pi * (ca.DM(mask) if isinstance(pi, ca.SX | ca.MX) else mask)


def joint_terms_of(arm: Arm, joint: int) -> np.ndarray:
    """(P,) 0/1: the joint terms (friction, armature) that act on joint `joint` (0-based) alone (a structural
    non-zero of the symbolic Y on its row only): its motor side, behind an elastic joint's spring."""
    Y = arm.symbols["Y"].sparsity()
    rows = range(arm.n_joints)
    return np.array(
        [
            float(
                p.kind in ("friction", "armature")
                and Y.has_nz(joint, i)
                and not any(Y.has_nz(r, i) for r in rows if r != joint)
            )
            for i, p in enumerate(arm.parameters)
        ]
    )


def mass_matrix(arm: Arm, pi: np.ndarray, q: np.ndarray) -> np.ndarray:
    """M(q) (N, n, n) [kg m²] of the arm's own expression at poses q (N, n) (armature included)."""
    f = arm.function("M")
    n = arm.n_joints
    zero = np.zeros(n)
    return np.array([np.asarray(f(qk, zero, zero, pi)) for qk in np.atleast_2d(q)])


def centre(limits) -> np.ndarray:
    """The centre of each joint's range [rad] (`limits`: `trajectories.ArmLimits`)."""
    return 0.5 * (np.asarray(limits.q_min) + np.asarray(limits.q_max))


def arm_scale(robot: Robot, limits, speed: np.ndarray) -> ArmScale:
    """The arm's reference magnitudes (`ArmScale`): effort limits (else the nominal torque's 95th percentile over
    poses spread across the ranges, moving at `speed`), the nominal diagonal inertia at the centre pose, the
    cruise speed [rad/s], the moving mass [kg] and the chain's length [m]."""
    arm, pi = robot.datasheets()[robot.datasheet]
    n = arm.n_joints
    singular(robot, arm, pi, limits)
    rng = np.random.default_rng(0)
    q = rng.uniform(limits.q_min, limits.q_max, size=(64, n))
    tau = arm.predict(link_pi(arm, pi), q, rng.choice([-1.0, 1.0], size=(64, n)) * speed, np.zeros((64, n)))
    effort = robot.limits().get("torque")
    torque = [
        float(effort[j]) if effort is not None and effort[j] else max(float(np.quantile(np.abs(tau[:, j]), 0.95)), 1e-3)
        for j in range(n)
    ]
    inertia = np.diag(mass_matrix(arm, pi, centre(limits)[None, :])[0])
    masses = arm.link_masses(pi)
    return ArmScale(
        tuple(torque),
        tuple(float(v) for v in inertia),
        tuple(float(v) for v in speed),
        float(sum(masses.values())) if masses else 0.0,
        reach(robot),
    )


def singular(robot: Robot, arm: Arm, pi: np.ndarray, limits) -> None:
    """InputError naming the joint when the nominal mass matrix is singular (a joint with no inertia about its axis:
    a URDF without the rotor behind it), which no forward simulation can integrate."""
    M = mass_matrix(arm, pi, centre(limits)[None, :])[0]
    lam, V = np.linalg.eigh(M)
    if lam[0] > 1e-9 * max(lam[-1], 1e-12):
        return
    j = int(np.argmax(np.abs(V[:, 0])))
    raise InputError(
        f"the nominal model's mass matrix is singular (smallest eigenvalue {lam[0]:.2g} kg m²): joint "
        f"{robot.joint_names[j]} has no inertia about its axis (its link in the URDF, and no rotor); give its "
        f"reflected rotor inertia in [robot.{robot.joint_tables[j]}] rotor_inertia to simulate it"
    )


def reach(robot: Robot) -> float:
    """The chain's length [m]: the sum of the joints' placement distances (an upper bound of the arm's reach)."""
    arm = robot.datasheets()[robot.datasheet][0]
    chain = getattr(arm, "chain", ())
    return float(sum(np.linalg.norm(j.translation) for j in chain)) or 1.0


def joints_of(robot: Robot, scale: ArmScale | None) -> Joints:
    """The effect syntax's view of the robot's joints: the datasheet's per-direction Coulomb levels (joint side),
    the joints' names and the reference magnitudes."""
    positive = [j.coulomb_friction.positive for j in robot.joints]
    negative = [j.coulomb_friction.negative for j in robot.joints]
    return Joints(positive, negative, robot.joint_names, scale)


def build_plant(robot: Robot, effects: dict[str, dict], scale: ArmScale, joints: Joints, limits) -> ArmPlant:
    """The true plant for the (normalised, active) `effects`, each applied by its `Effect.chain_plant` in catalogue
    order, then the mechanism (`Effect.chain_mechanism`) of the one that has one."""
    arm, pi = robot.datasheets()[robot.datasheet]
    n = arm.n_joints
    mean = np.array([0.5 * (a + b) for a, b in zip(*joints)])
    plant = ArmPlant(
        robot,
        arm,
        np.array(pi, dtype=float),
        np.array(pi, dtype=float),
        scale,
        joints,
        np.zeros(n),
        mean.copy(),
        mean.copy(),
        np.zeros(n),
        np.full(n, 0.05),
        np.zeros(n),
        np.zeros(n),
        effects=dict(effects),
    )
    hidden = [(e, effects[name]) for name, e in CATALOGUE.items() if name in effects]
    for effect, p in hidden:
        effect.chain_plant(plant, p)
    for effect, p in hidden:
        joint = effect.chain_mechanism(plant, p)
        if joint is not None:
            plant.elastic = elastic_joint(plant, *joint, limits)
    return plant


def link_inertia(plant: ArmPlant, joint: int, q: np.ndarray) -> np.ndarray:
    """The link-side inertia M_link[j, j] [kg m²] behind joint `joint` (0-based) at each pose of q (N, n) [rad]: the
    mass matrix of π without the joint terms (the rotors' armature sits on the motor side of the spring)."""
    link = plant.pi * (1 - joint_terms_of(plant.arm, joint))
    return mass_matrix(plant.arm, link, q)[:, joint, joint]


def elastic_joint(plant: ArmPlant, joint: int, frequency_hz: float, damping: float, limits) -> ElasticJoint:
    """Joint `joint` (0-based) elastic at `frequency_hz` [Hz] with the other joints held, damping ratio `damping`:
    k = J_link (2π f)², d = 2 ζ √(k J_link), J_link the link-side inertia at the centre pose; the motor is the
    joint's reflected rotor inertia (π's armature on that joint plus any extra), or `MOTOR_SHARE` × J_link."""
    arm = plant.arm
    poses = np.vstack([centre(limits), np.random.default_rng(1).uniform(limits.q_min, limits.q_max, (16, plant.n))])
    M_link = link_inertia(plant, joint, poses)
    M_full = mass_matrix(arm, plant.pi, centre(limits)[None, :])[0, joint, joint]
    J_link = float(M_link[0])
    B = float(M_full - J_link + plant.inertia[joint])
    added = B <= 1e-12 * max(J_link, 1e-12)
    if added:
        B = MOTOR_SHARE * J_link
    k, d = spring_for(J_link, frequency_hz, damping)
    J_min = float(np.min(M_link))
    rate = math.sqrt(k * (1 / B + 1 / J_min)) + d * (1 / B + 1 / J_min)
    return ElasticJoint(joint, k, d, B, J_link, frequency_hz, damping, rate, motor_added=added)


def check_finite(plant: ArmPlant, where: str) -> None:
    """InputError naming the effects when the plant's numbers are not finite (a magnitude too large to simulate)."""
    if not np.all(np.isfinite(plant.parameters())):
        raise InputError(
            f"{where}: the hidden effects ({', '.join(plant.effects) or 'none'}) make the plant's numbers non-finite"
        )
