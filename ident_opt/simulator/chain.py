"""The plant of an arm with n joints (`plant.Plant`): its nominal model as the true arm (`chain_plant`), the hidden
effects on any joint, within the problem's `[limits]` (or the URDF's), under the closed loop of `chain_loop`."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, replace

import numpy as np

from ident_opt.arm.base import Robot
from ident_opt.effects import BACKGROUND, CATALOGUE, is_active, normalise
from ident_opt.errors import InputError
from ident_opt.problem.spec import Limits
from ident_opt.simulator import chain_loop, chain_plant, measurement
from ident_opt.simulator.plant import plain
from ident_opt.simulator.trajectories import (
    DEFAULT_ACCELERATION,
    RANGE_MARGIN,
    Box,
    Reference,
    arm_box,
    reference,
)

#: An n-joint arm's torque noise: this share of each joint's reference torque (`ArmScale.torque`, its effort limit):
#: 0.35 N m on a 176 N m joint, 0.024 N m on a 12 N m wrist, the order of a joint-torque sensor's.
NOISE_SHARE = 0.002
#: Where neither [limits] nor the URDF gives a joint's speed limit [rad/s].
DEFAULT_SPEED = 2.0
#: How far beyond the references' box [share of its span] a trajectory file may go: the box is the joint range
#: less `trajectories.RANGE_MARGIN` at each end, so this reaches back to the limits themselves.
RANGE_MARGIN_OUT = RANGE_MARGIN / (1 - 2 * RANGE_MARGIN)


class ChainPlant:
    """An n-joint arm's true plant for the hidden `effects` within `limits` (module doc); a replacement `mechanism`
    is the planar arm's only."""

    def __init__(self, robot: Robot, effects, limits: Limits | None = None, mechanism=None) -> None:
        if mechanism is not None:
            raise InputError("a replacement mechanism (simulator.unseen) is built for the planar two-link arm only")
        self.robot = robot
        self.box = box_of(robot, limits)
        self.scale = chain_plant.arm_scale(robot, self.box, self.box.v_max)
        joints = chain_plant.joints_of(robot, self.scale)
        background = [name for name in _names(effects) if name in BACKGROUND and not BACKGROUND[name].any_arm]
        if background:
            raise InputError(
                f"effect {background[0]!r}: the background terms "
                f"({', '.join(n for n, e in BACKGROUND.items() if not e.any_arm)}) are the planar two-link "
                f"arm's; this problem's robot is {robot.described_as}"
            )
        self.requested = normalise(effects, joints)
        active = {name: p for name, p in self.requested.items() if is_active(name, p, joints)}
        #: The background terms that act on any arm (a contact: an external torque), outside the plant.
        self.background = {name: p for name, p in active.items() if name in BACKGROUND}
        self.effects = {name: p for name, p in active.items() if name not in BACKGROUND}
        self.plant = chain_plant.build_plant(robot, self.effects, self.scale, joints, self.box)
        chain_plant.check_finite(self.plant, "simulate")
        self.sigma = NOISE_SHARE * np.asarray(self.scale.torque)
        self.sensors = {"noise_std": self.sigma, "encoder_step": measurement.encoder_steps(robot)}
        self.gains, self.steps, self.control = None, None, None

    @property
    def elastic(self):
        return self.plant.elastic

    def logged_torque(self, t: np.ndarray, tau: np.ndarray) -> np.ndarray:
        return self.plant.logged_torque(t, tau)

    def reference(self, settings: dict, control: float) -> Reference:
        ref = reference(settings["trajectory"], settings["duration"], settings["seed"], 1.0 / control, self.box)
        outside(ref, self.box, self.robot, settings["trajectory"])
        return ref

    def run(self, ref: Reference, control: float, settings: dict, progress: bool) -> np.ndarray:
        """The loop of `chain_loop` along `ref` (sampled at the control rate `control` [Hz]): out (N, 4n + 1), τ,
        q_enc, dq_enc, ddq_enc, deflection at each tick; the gains, the RK4 sub-steps per tick (and the share of
        ticks that took the fine ones) and the elastic joint's link inertia over the motion run (the other joints
        move) are kept for the truth file."""
        plant, self.control = self.plant, control
        d = self.disturbance(len(ref.t), 1.0 / control, int(settings["seed"]))
        out, self.gains, self.steps = chain_loop.follow(
            plant, ref, self.box, control, settings["bandwidth_hz"], progress, d
        )
        if plant.elastic is not None:
            n, j = self.robot.n_joints, plant.elastic.index
            q_true = out[:: max(1, len(out) // 2000), n : 2 * n] + plant.offset  # at most ~2000 poses
            M = chain_plant.link_inertia(plant, j, q_true)
            plant.elastic = replace(plant.elastic, trial_inertia=(float(M.mean()), float(M.min()), float(M.max())))
        return out

    def disturbance(self, ticks: int, dt: float, seed: int) -> np.ndarray | None:
        """The external torque (ticks, n) [N m] of the background terms that act on any arm (None without one)."""
        if not self.background:
            return None
        rng, n = np.random.default_rng([seed, 13]), self.robot.n_joints
        return sum(BACKGROUND[name].disturbance(p, ticks, dt, rng, joints=n) for name, p in self.background.items())

    def truth_file(self, out: np.ndarray, ref: Reference, settings: dict, scale: np.ndarray) -> dict:
        n, g, steps = self.robot.n_joints, self.gains, self.steps
        error = out[:, n : 2 * n] - ref.q
        truth = truth_file(self.plant, settings, self.sigma * scale if settings["noise"] else np.zeros(n))
        truth["controller"] = {
            "control_hz": self.control,
            "bandwidth_hz": settings["bandwidth_hz"],
            "kp": list(g.kp),
            "kd": list(g.kd),
            "rk4_substeps": steps.fine,
            "rk4_substeps_away_from_reversals": steps.coarse,
            "fine_tick_share": steps.fine_share,
        }
        truth["tracking"] = {
            "rms_error": np.sqrt((error**2).mean(0)).tolist(),
            "max_error": np.abs(error).max(0).tolist(),
        }
        truth["limits"] = {"position_min": self.box.q_min.tolist(), "position_max": self.box.q_max.tolist()}
        truth["background"] = dict(self.background)  # outside the diagnosis catalogue (a contact)
        return plain(truth)


def box_of(robot: Robot, limits: Limits | None) -> Box:
    """Where an n-joint arm's references move (`trajectories.arm_box`): within the problem's `[limits]`, or the
    URDF's <limit> values (`Robot.limits`; a joint without them: ±π rad, `DEFAULT_SPEED` rad/s), and
    `trajectories.DEFAULT_ACCELERATION`."""
    n, urdf = robot.n_joints, robot.limits()

    def value(key: str, default: float) -> np.ndarray:
        if limits is not None:
            return np.asarray(getattr(limits, key), dtype=float)
        given = urdf.get(key) or (None,) * n
        return np.array([default if v is None else float(v) for v in given])

    acceleration = np.asarray(limits.acceleration, dtype=float) if limits is not None else None
    return arm_box(
        value("position_min", -np.pi),
        value("position_max", np.pi),
        value("velocity", DEFAULT_SPEED),
        acceleration if acceleration is not None else np.full(n, DEFAULT_ACCELERATION),
    )


def outside(ref: Reference, box: Box, robot: Robot, trajectory: str) -> None:
    """InputError when a trajectory file leaves the arm's joint ranges (the generated references stay inside)."""
    low, high = (
        box.q_min - RANGE_MARGIN_OUT * (box.q_max - box.q_min),
        box.q_max + RANGE_MARGIN_OUT * (box.q_max - box.q_min),
    )
    bad = np.argwhere((ref.q < low - 1e-9) | (ref.q > high + 1e-9))
    if len(bad):
        k, j = bad[0]
        raise InputError(
            f"{trajectory}: q{j + 1} ({robot.joint_names[j]}) reaches {ref.q[k, j]:g} rad at t = {ref.t[k]:g} s, "
            "outside the joint's range ([limits] or the URDF's <limit>)"
        )


def truth_file(plant, settings: dict, noise_std: np.ndarray) -> dict:
    """The ground truth of an n-joint trial: π by name (true and datasheet), the plant's joint terms, each effect
    in the diagnosis's estimate keys (`Effect.chain_truth`), the settings and the measurement."""
    arm = plant.arm
    effects = {name: CATALOGUE[name].chain_truth(plant, p) for name, p in plant.effects.items()}
    return {
        "joints": list(plant.robot.joint_names),
        "model": list(arm.names),
        "pi": arm.as_dict(plant.pi),
        "pi_datasheet": arm.as_dict(plant.nominal),
        "plant": {
            "extra_inertia": plant.inertia.tolist(),
            "coulomb_positive": plant.positive.tolist(),
            "coulomb_negative": plant.negative.tolist(),
            "stribeck_excess": plant.excess.tolist(),
            "stribeck_velocity": plant.velocity.tolist(),
            "load_friction": plant.load_friction.tolist(),
            "encoder_offset": plant.offset.tolist(),
        },
        "effects": effects,
        "scale": asdict(plant.scale),
        "settings": settings,
        "measurement": {
            "torque_noise_std": noise_std.tolist(),
            "encoder_step_rad": measurement.encoder_steps(plant.robot).tolist() if settings["noise"] else None,
            "derivatives": "exact"
            if settings["exact_derivatives"]
            else f"estimated, zero-phase Butterworth at {measurement.DERIVATIVE_CUTOFF_HZ:g} Hz",
        },
    }


def _names(effects) -> list[str]:
    """The effect names of `effects` (a mapping or effect strings), for checks before parsing."""
    if isinstance(effects, str):
        effects = [effects]
    if isinstance(effects, Mapping):
        return [str(k) for k in effects]
    return [str(e).partition(":")[0].strip() for e in effects]
