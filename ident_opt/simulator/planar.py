"""The planar two-link arm's plant (`plant.Plant`): its datasheet read physically (`truth`), the hidden effects and
the background terms of a real arm, flexible links (`elastic`), on the MERIt trials' motion under the closed loop
of `closed_loop`."""

from __future__ import annotations

from dataclasses import asdict, replace

import casadi as ca
import numpy as np

from ident_opt.arm.datasheet import PlanarRobot, datasheet_pi, rigid_body
from ident_opt.effects import CATALOGUE, is_active, normalise
from ident_opt.simulator import background, closed_loop, measurement
from ident_opt.simulator.integrate import march
from ident_opt.simulator.planar_dynamics import TRUTH_MODEL
from ident_opt.simulator.plant import plain
from ident_opt.simulator.trajectories import Reference, reference
from ident_opt.simulator.truth import Truth, build_truth, coulomb_levels, initial_state


class PlanarPlant:
    """The planar arm's true plant for the hidden `effects` (module doc); `mechanism`: truth -> a mechanism that
    replaces the one the effects built (`truth.elastic`), e.g. a plant the diagnosis was not tuned on
    (`simulator.unseen`). `limits` are the MERIt trials' own (the references' box)."""

    sensors: dict = {}  # noqa: RUF012 (the planar arm's measurement: `measurement`'s defaults)

    def __init__(self, robot: PlanarRobot, effects, limits=None, mechanism=None) -> None:
        coulomb = coulomb_levels(robot)
        self.robot = robot
        self.requested = normalise(effects, coulomb)
        self.effects = {name: p for name, p in self.requested.items() if is_active(name, p, coulomb)}
        self.truth = build_truth(robot, self.effects)
        if mechanism is not None:
            self.truth = replace(self.truth, elastic=mechanism(self.truth))

    @property
    def elastic(self):
        return self.truth.elastic

    def logged_torque(self, t: np.ndarray, tau: np.ndarray) -> np.ndarray:
        return self.truth.logged_torque(t, tau)

    def reference(self, settings: dict, control: float) -> Reference:
        return reference(settings["trajectory"], settings["duration"], settings["seed"], 1.0 / control)

    def run(self, ref: Reference, control: float, settings: dict, progress: bool) -> np.ndarray:
        """The loop of `closed_loop` along `ref` (sampled at the control rate `control` [Hz]): out (N, 9), τ, q_enc,
        dq_enc, ddq_enc, deflection at each tick. The run's seed drives the background terms' randomness (external
        torques, initial states) on streams of their own; its `bandwidth_hz` sets the PD gains."""
        truth, seed = self.truth, int(settings["seed"])
        step = closed_loop.tick(truth, self.robot, closed_loop.gains(self.robot, settings["bandwidth_hz"]), control)
        z0 = background.initial_states(truth.background, np.random.default_rng([seed, 17]))
        x = ca.DM(np.concatenate([initial_state(truth, ref.q[0]), z0]))
        d = background.disturbance(truth.background, len(ref.t), 1.0 / control, np.random.default_rng([seed, 13]))
        refs = np.hstack([ref.q, ref.dq, ref.ddq, d]).T
        chunk = max(1, min(closed_loop.CHUNK, refs.shape[1]))  # a short trial in one call of its own length
        return march(step.mapaccum(chunk), x, refs, (), chunk, progress).T

    def truth_file(self, out: np.ndarray, ref: Reference, settings: dict, scale: np.ndarray) -> dict:
        return truth_file(self.robot, self.truth, out, ref.q, settings)


def truth_file(robot: PlanarRobot, truth: Truth, out: np.ndarray, q_ref: np.ndarray, settings: dict) -> dict:
    """The ground truth, with effects in the diagnosis's estimate keys (`docs/effects.md`)."""
    effects = {name: CATALOGUE[name].truth_entry(truth, p) for name, p in truth.effects.items()}
    physical = asdict(rigid_body(truth.robot, "physical"))  # the true plant's, not the datasheet's
    for name, p in truth.effects.items():
        CATALOGUE[name].true_physical(physical, p)
    g = closed_loop.gains(robot, settings["bandwidth_hz"])
    control = closed_loop.control_hz(settings["rate_hz"])
    error = out[:, 2:4] - q_ref  # encoder angle minus reference, at every control tick
    return plain(
        {
            "model": list(TRUTH_MODEL.names),
            "pi": truth.pi_rigid,
            "pi_datasheet": datasheet_pi(robot, "physical"),
            "plant_model": {
                "extensions": list(truth.model.extensions),
                "stribeck_velocity": list(truth.model.stribeck_velocity),
                "pi": truth.model.as_dict(truth.pi),
            },
            "effects": effects,
            "background": dict(truth.background),  # realism terms outside the diagnosis catalogue
            "physical": physical,
            "settings": settings,
            "measurement": {
                "torque_noise_std": (np.broadcast_to(settings["noise_scale"], (2,)) * measurement.TORQUE_NOISE).tolist()
                if settings["noise"]
                else [0.0, 0.0],
                "encoder_counts_per_motor_rev": measurement.ENCODER_COUNTS if settings["noise"] else None,
                "derivatives": "exact"
                if settings["exact_derivatives"]
                else f"estimated, zero-phase Butterworth at {measurement.DERIVATIVE_CUTOFF_HZ:g} Hz",
            },
            "controller": {
                "control_hz": control,
                "bandwidth_hz": settings["bandwidth_hz"],
                "kp": list(g.kp),
                "kd": list(g.kd),
                "rk4_substeps": closed_loop.substeps(truth, g, robot, control),
            },
            "tracking": {
                "rms_error": np.sqrt((error**2).mean(0)).tolist(),
                "max_error": np.abs(error).max(0).tolist(),
            },
        }
    )
