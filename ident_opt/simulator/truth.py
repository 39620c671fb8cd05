"""The truth plant: the physical-convention datasheet arm plus the hidden effects, as CasADi expressions.

Without effects the plant is exactly `PlanarArm(("armature",))` with `datasheet_pi(robot, "physical")`:
M(q) ddq + C(q, dq) dq + G(q) + F(dq) = τ, and the encoders log q. Each hidden effect of
`ident_opt.effects.CATALOGUE` shapes it through its own hooks, applied in catalogue order:

1. `Effect.true_robot`: the robot the datasheet π is computed from (a payload at the tip of link 2);
2. `Effect.true_plant`: π, the model structure and the sensors (`PlantSpec`: extra inertia, friction
   terms, encoder zero offsets δ so that the true angle is the logged one + δ, the logged torque channel);
3. `Effect.mechanism`: a mechanism that replaces the rigid arm, as the effect describes it (an elastic joint or a
   flexible link: its kind, joint, frequency and damping), built here (`simulator.elastic`) with its own states,
   plant, initial state and fastest rate.

Background terms (`ident_opt.effects.background`: stiction, drift, ripple, contact) are kept apart in
`Truth.background` and wrapped around this plant by background.py.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from ident_opt.arm.datasheet import PlanarRobot, datasheet_pi, rigid_body
from ident_opt.arm.planar import PlanarArm
from ident_opt.effects import BACKGROUND, CATALOGUE, EXTENSIONS
from ident_opt.simulator import elastic
from ident_opt.simulator.planar_dynamics import TRUTH_MODEL, link_pi, solve_forward, with_load_friction


@dataclass
class PlantSpec:
    """The true plant while the hidden effects shape it (`Effect.true_plant` changes it in place)."""

    robot: PlanarRobot  # the datasheet robot with any hidden payload
    pi: dict[str, float]  # π by name
    extensions: list[str]  # the PlanarArm extensions π needs
    options: dict  # other PlanarArm fields (e.g. stribeck_velocity)
    armature: list[float]  # reflected rotor inertia per joint [kg m²] (a1 holds joint 1's, ia2 is joint 2's)
    offset: list[float]  # encoder zero offsets δ [rad]: the true angle is the logged (encoder) angle + δ
    channel: list[Callable]  # the logged torque: (t_tick [s], τ (N, 2) [N m]) -> τ as logged, in order
    load_friction: list[float] = field(default_factory=lambda: [0.0, 0.0])  # μ per joint (see `link_torque`)


@dataclass(frozen=True)
class Truth:
    """The true plant: its model structure, π (vector in `model.names` order), and effects."""

    robot: PlanarRobot  # the datasheet robot with any hidden payload
    model: PlanarArm
    pi: np.ndarray
    elastic: object | None  # the mechanism replacing the rigid arm (`simulator.elastic.Elastic`), if any
    offset: tuple[float, float]
    effects: dict
    background: dict = field(default_factory=dict)  # background realism terms (`ident_opt.effects.background`)
    armature: tuple[float, float] = (0.0, 0.0)  # reflected rotor inertia per joint [kg m²]
    channel: tuple[Callable, ...] = ()  # see `PlantSpec.channel`
    load_friction: tuple[float, float] = (0.0, 0.0)  # μ per joint: Coulomb level fc + μ |τ_load|

    @property
    def pi_rigid(self) -> dict[str, float]:
        """π in `TRUTH_MODEL`'s names; a name an extension replaced is the mean of the parameters standing in
        for it (`Effect.fallback`: e.g. the Coulomb level fc1 as the mean of the per-direction fc1p, fc1n)."""
        p = self.model.as_dict(self.pi)
        stand_ins = {name: rigid for ext in self.model.extensions for name, rigid in EXTENSIONS[ext].fallback.items()}
        out = {}
        for name in TRUTH_MODEL.names:
            parts = [p[n] for n, rigid in stand_ins.items() if rigid == name]
            out[name] = p[name] if name in p else sum(parts) / len(parts)
        return out

    def logged_torque(self, t: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The torque channel as logged at the control ticks t [s]: the applied τ (N, 2) [N m] through the
        hidden effects on that channel, in order (τ itself when there are none)."""
        for transform in self.channel:
            tau = transform(t, tau)
        return tau


def coulomb_levels(robot: PlanarRobot) -> tuple[tuple, tuple]:
    """The datasheet's per-direction Coulomb levels reflected to the joint [N m]: (positive, negative)."""
    body = rigid_body(robot, "physical")
    return tuple(body.fc_positive), tuple(body.fc_negative)


def build_truth(robot: PlanarRobot, effects: dict[str, dict]) -> Truth:
    """The true plant for the (normalised, active) `effects`; background terms go to `Truth.background`."""
    background = {name: p for name, p in effects.items() if name in BACKGROUND}
    effects = {name: p for name, p in effects.items() if name not in BACKGROUND}
    hidden = [(e, effects[name]) for name, e in CATALOGUE.items() if name in effects]
    true_robot = robot
    for effect, p in hidden:
        true_robot = effect.true_robot(true_robot, p)
    spec = PlantSpec(
        true_robot,
        datasheet_pi(true_robot, "physical"),
        list(TRUTH_MODEL.extensions),
        {},
        list(rigid_body(true_robot, "physical").armature),
        [0.0, 0.0],
        [],
    )
    for effect, p in hidden:
        effect.true_plant(spec, p)
    model = PlanarArm(tuple(spec.extensions), **spec.options)
    mechanisms = [elastic.build(spec, *m) for effect, p in hidden if (m := effect.mechanism(spec, p)) is not None]
    return Truth(
        true_robot,
        model,
        model.vector(spec.pi),
        mechanisms[0] if mechanisms else None,
        tuple(spec.offset),
        effects,
        background,
        tuple(spec.armature),
        tuple(spec.channel),
        tuple(spec.load_friction),
    )


def _forward(truth: Truth, q, dq, tau) -> ca.SX:
    """ddq of the rigid plant, with load-dependent friction if any (`with_load_friction`)."""
    link = ca.DM(link_pi(truth.model, truth.pi, truth.armature))
    return with_load_friction(
        truth,
        dq,
        lambda extra: solve_forward(truth.model, ca.DM(truth.pi), q, dq, tau - extra),
        lambda ddq: truth.model.tau_expression(q, dq, ddq, link),
    )


def state_size(truth: Truth) -> int:
    """Length of the state x: [q (2), dq (2)], or the mechanism's (e.g. [q (2), θ, dq (2), dθ] with an
    elastic joint)."""
    return 4 if truth.elastic is None else truth.elastic.state_size


def plant(truth: Truth) -> ca.Function:
    """The plant as a CasADi Function (x, τ) -> (ẋ, y) with y = [q_enc (2), dq_enc (2), ddq_enc (2), deflection]:
    encoder angle (true angle − δ), its rate and the acceleration the dynamics produce [rad, rad/s, rad/s²],
    and a spring deflection [rad] (0 when rigid; a mechanism logs its own, e.g. the motor side of an elastic
    joint)."""
    if truth.elastic is not None:
        return truth.elastic.plant(truth)
    x, tau = ca.SX.sym("x", 4), ca.SX.sym("tau", 2)
    q, dq = x[:2], x[2:]
    ddq = _forward(truth, q, dq, tau)
    xdot = ca.vertcat(dq, ddq)
    y = ca.vertcat(q - ca.DM(truth.offset), dq, ddq, 0)
    return ca.Function("plant", [x, tau], [xdot, y], ["x", "tau"], ["xdot", "y"])


def initial_state(truth: Truth, q_enc: np.ndarray) -> np.ndarray:
    """A state at rest whose encoders read `q_enc` [rad] (a mechanism starts at its static deflection)."""
    q = np.asarray(q_enc, dtype=float) + np.asarray(truth.offset)
    if truth.elastic is None:
        return np.concatenate([q, [0.0, 0.0]])
    return truth.elastic.initial_state(truth, q)
