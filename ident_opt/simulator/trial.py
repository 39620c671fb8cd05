"""`simulate_trial`: one measured-style trial from the built-in simulator, with its ground truth."""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from ident_opt import outputs
from ident_opt.arm.base import Robot
from ident_opt.arm.datasheet import PlanarRobot, datasheet_pi, rigid_body
from ident_opt.arm.kinds import ByKind
from ident_opt.columns import channel_names, data_columns
from ident_opt.data.dataset import Dataset, in_source_convention
from ident_opt.effects import BACKGROUND, CATALOGUE, is_active, normalise
from ident_opt.errors import InputError
from ident_opt.problem.spec import Limits
from ident_opt.simulator import chain_loop, chain_plant, closed_loop, measurement
from ident_opt.simulator.planar_dynamics import TRUTH_MODEL
from ident_opt.simulator.trajectories import DEFAULT_ACCELERATION, RANGE_MARGIN, Box, Reference, arm_box, reference
from ident_opt.simulator.truth import Truth, build_truth, coulomb_levels

MIN_DURATION, MAX_DURATION = 1.0, 3600.0  # s: enough samples for the derivative filter; memory stays bounded
#: The controller's closed-loop bandwidth [Hz] a trial may ask for: a sluggish loop still tracks the slow
#: references; a stiff one stays well below the 1 kHz controller's Nyquist limit.
MIN_BANDWIDTH, MAX_BANDWIDTH = 1.0, 40.0
#: Largest torque-noise multiple (of the σ measured on the real robot).
MAX_NOISE_SCALE = 100.0
#: An n-joint arm's torque noise: this share of each joint's reference torque (`ArmScale.torque`, its effort limit):
#: 0.35 N m on a 176 N m joint, 0.024 N m on a 12 N m wrist, the order of a joint-torque sensor's.
NOISE_SHARE = 0.002
#: Encoder counts per joint revolution where a joint's gear ratio is not given (a 19-bit joint-side encoder).
JOINT_COUNTS = 2**19
#: Where neither [limits] nor the URDF gives a joint's speed limit [rad/s].
DEFAULT_SPEED = 2.0
#: How far beyond the references' box [share of its span] a trajectory file may go: the box is the joint range
#: less `trajectories.RANGE_MARGIN` at each end, so this reaches back to the limits themselves.
RANGE_MARGIN_OUT = RANGE_MARGIN / (1 - 2 * RANGE_MARGIN)


@dataclass
class SimTrial:
    """A simulated trial: `frame` in the data format (plus extra columns), `truth` a JSON-able dict."""

    frame: pd.DataFrame
    truth: dict
    robot: Robot

    def dataset(self) -> Dataset:
        """The trial as the data loader would return it (currents converted to joint torques)."""
        f = self.frame
        names = channel_names(self.robot.n_joints)

        def signal(kind: str) -> np.ndarray:
            return f[list(names[kind])].to_numpy(dtype=float)

        if names["tau"][0] in f:
            tau = signal("tau")
        else:
            tau = signal("i") * measurement.current_factors(self.robot)
        used = set(data_columns(self.robot.n_joints))
        extra = f[[c for c in f.columns if c not in used]].reset_index(drop=True)
        return Dataset(
            "simulated",
            f["t"].to_numpy(dtype=float),
            signal("q"),
            signal("dq"),
            signal("ddq"),
            tau,
            extra,
            "given",
            0,
            ["simulated by ident_opt.simulator"],
        )

    def write(self, csv_path: str | Path) -> Path:
        """Write the CSV (full float precision) and the sidecar `<stem>.truth.json`; returns the CSV path.

        Both are written to temporary files and renamed into place, so a reader never sees half a file.
        """
        path = Path(csv_path)
        if not path.name.lower().endswith((".csv", ".csv.gz")):
            raise InputError(f"{path}: the simulated trial is written as CSV; name it *.csv or *.csv.gz")
        gz = path.name.lower().endswith(".gz")
        try:
            truth = json.dumps(self.truth, indent=2, allow_nan=False) + "\n"
        except ValueError:
            raise InputError(
                f"{path}: the simulated trial's truth holds non-finite numbers (an effect too large to simulate); "
                "nothing written"
            ) from None
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            # A robot whose data have their own angle convention (a URDF arm's) logs in it; the loader maps it back.
            frame = in_source_convention(self.frame, self.robot.column_map)
            _atomic(path, lambda tmp: frame.to_csv(tmp, index=False, compression="gzip" if gz else None))
            _atomic(truth_path(path), lambda tmp: tmp.write_text(truth))
        except OSError as exc:
            raise InputError(f"{path}: cannot write the simulated trial ({exc.strerror})") from None
        return path


def truth_path(csv_path: str | Path) -> Path:
    """The sidecar truth file of a trial CSV: `<stem>.truth.json` beside it."""
    path = Path(csv_path)
    return path.with_name(path.name.removesuffix(".gz").removesuffix(".csv") + ".truth.json")


def _atomic(path: Path, write) -> None:
    """`write(tmp_path)` to a temporary file beside `path`, then rename it into place (`outputs.atomic_path`:
    the user's umask, the temporary file removed on failure, undone if the command fails)."""
    with outputs.atomic_path(path) as tmp:
        write(tmp)


def simulate_trial(
    robot: Robot,
    *,
    trajectory: str = "tud01",
    duration: float = 80.0,
    rate_hz: float = 100.0,
    seed: int = 0,
    effects: Mapping[str, Mapping] | Sequence[str] = (),
    output: str = "torque",
    noise: bool = True,
    exact_derivatives: bool = False,
    progress: bool = True,
    bandwidth_hz: float = closed_loop.BANDWIDTH_HZ,
    noise_scale: float | Sequence[float] = 1.0,
    limits: Limits | None = None,
    mechanism: Callable[[Truth], object] | None = None,
) -> SimTrial:
    """Simulate one trial of `robot` with hidden `effects`; deterministic.

    `effects`: name -> keys (e.g. {"elasticity": {"joint": 2, "frequency_hz": 8}}) or effect strings
    ("elasticity:joint=2,frequency_hz=8"); see `ident_opt.effects.CATALOGUE`. `duration` [s], `rate_hz` [Hz] (a divisor
    of 1 kHz, or faster up to 5 kHz: the controller then runs at that rate), `output` "torque" (tau1 … taun
    [N m]) or "current" (i1 … in [A]). With `noise=False` the angles are not quantised and no noise is added;
    `exact_derivatives=True` logs the true dq and the ddq the dynamics produce instead of estimating them
    from the logged angles. `bandwidth_hz` [Hz]: the controller's closed-loop bandwidth (its PD gains);
    `noise_scale`: the torque noise's σ as a multiple of the arm's reference σ (with `noise`), one factor for
    every joint or one per joint. The planar two-link arm (`Robot.engine` "planar") is its datasheet read
    physically, on the MERIt trials' motion; any other arm is its nominal model (`chain_plant`) moving within
    `limits` (the problem's `[limits]`; default: the URDF's <limit> values, `Robot.limits`). `mechanism` (planar
    arm): truth -> a mechanism that replaces the one the hidden effects built (`truth.elastic`), e.g. a plant the
    diagnosis was not tuned on (`simulator.unseen`).
    """
    n = robot.n_joints
    if output not in ("torque", "current"):
        raise InputError(f'output {output!r}: must be "torque" or "current"')
    if not (np.isfinite(duration) and MIN_DURATION <= duration <= MAX_DURATION):
        raise InputError(f"duration {duration!r}: must be between {MIN_DURATION:g} and {MAX_DURATION:g} s")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InputError(f"seed {seed!r}: must be an integer >= 0")
    measurement.decimation(rate_hz)
    if not (np.isfinite(bandwidth_hz) and MIN_BANDWIDTH <= bandwidth_hz <= MAX_BANDWIDTH):
        raise InputError(
            f"bandwidth {bandwidth_hz!r}: the controller's bandwidth must be between {MIN_BANDWIDTH:g} and "
            f"{MAX_BANDWIDTH:g} Hz"
        )
    scale = np.asarray(noise_scale, dtype=float)
    if scale.shape not in ((), (n,)) or not np.all(np.isfinite(scale) & (scale >= 0) & (scale <= MAX_NOISE_SCALE)):
        raise InputError(
            f"noise scale {noise_scale!r}: must be between 0 and {MAX_NOISE_SCALE:g}, one for every joint or one each"
        )
    if output == "current":
        measurement.current_factors(robot)  # refuses before any work when the problem lacks what currents need
    settings = {
        "trajectory": trajectory,
        "duration": float(duration),
        "rate_hz": float(rate_hz),
        "seed": int(seed),
        "output": output,
        "noise": bool(noise),
        "noise_scale": float(scale) if np.ndim(noise_scale) == 0 else scale.tolist(),
        "bandwidth_hz": float(bandwidth_hz),
        "exact_derivatives": bool(exact_derivatives),
    }
    scale = np.broadcast_to(scale, (n,))
    return TRIALS.of(robot)(robot, effects, settings, scale, progress, limits, mechanism)


def _planar_trial(
    robot: PlanarRobot, effects, settings: dict, scale: np.ndarray, progress: bool, limits, mechanism
) -> SimTrial:
    """The planar two-link arm's trial (`simulate_trial`): the MERIt-tuned simulator (`truth`, `closed_loop`)."""
    coulomb = coulomb_levels(robot)
    wanted = normalise(effects, coulomb)
    active = {name: p for name, p in wanted.items() if is_active(name, p, coulomb)}
    truth = build_truth(robot, active)
    if mechanism is not None:
        truth = replace(truth, elastic=mechanism(truth))
    seed, rate_hz = settings["seed"], settings["rate_hz"]
    control = closed_loop.control_hz(rate_hz)  # 1 kHz unless the log is faster
    ref = reference(settings["trajectory"], settings["duration"], seed, 1.0 / control)
    out = closed_loop.run(
        truth, robot, ref, progress=progress, seed=int(seed), control=control, bandwidth_hz=settings["bandwidth_hz"]
    )
    finite(out, active)
    frame = logged(out, ref, robot, settings, scale, truth.logged_torque, truth.elastic)
    settings["effects_requested"] = {k: _plain(v) for k, v in wanted.items()}
    return SimTrial(frame, _truth_dict(robot, truth, out, ref.q, settings), robot)


def logged(out: np.ndarray, ref: Reference, robot, settings: dict, scale, channel, elastic, **sensors) -> pd.DataFrame:
    """The loop's output as logged (`measurement.log`) with the trial's settings (rate, noise, derivatives, output)
    and the measurement noise's own random stream; `elastic`: the plant's elastic joint (its deflection is
    logged) or None; `sensors`: the arm's noise σ and encoder steps, where not the planar arm's."""
    return measurement.log(
        out,
        ref.q,
        robot,
        rate_hz=settings["rate_hz"],
        channel=channel,
        noise=settings["noise"],
        noise_scale=scale,
        exact_derivatives=settings["exact_derivatives"],
        output=settings["output"],
        rng=np.random.default_rng([settings["seed"], 11]),
        deflection_column=elastic.deflection_column if elastic else None,
        **sensors,
    )


def finite(out: np.ndarray, effects: Mapping) -> None:
    """InputError naming the hidden effects when the simulated loop's output is not finite (nothing is written)."""
    if not np.all(np.isfinite(out)):
        raise InputError(
            "the simulation diverged (non-finite angles or torques): the hidden effects "
            f"({', '.join(effects) or 'none'}) or the trajectory are beyond what the arm can follow; nothing written"
        )


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


def _arm_trial(robot: Robot, effects, settings: dict, scale: np.ndarray, progress: bool, limits, mechanism) -> SimTrial:
    """An n-joint arm's trial (`simulate_trial`): its nominal model as the true plant (`chain_plant`), the hidden
    effects on any joint, the closed loop `chain_loop`, logged like the planar arm's."""
    if mechanism is not None:
        raise InputError("a replacement mechanism (simulator.unseen) is built for the planar two-link arm only")
    box = box_of(robot, limits)
    arm_scale = chain_plant.arm_scale(robot, box, box.v_max)
    joints = chain_plant.joints_of(robot, arm_scale)
    background = [name for name in _names(effects) if name in BACKGROUND]
    if background:
        raise InputError(
            f"effect {background[0]!r}: the background terms ({', '.join(BACKGROUND)}) are the planar two-link "
            f"arm's; this problem's robot is {robot.described_as}"
        )
    wanted = normalise(effects, joints)
    active = {name: p for name, p in wanted.items() if is_active(name, p, joints)}
    plant = chain_plant.build_plant(robot, active, arm_scale, joints, box)
    chain_plant.check_finite(plant, "simulate")
    seed, rate_hz = settings["seed"], settings["rate_hz"]
    control = closed_loop.control_hz(rate_hz)
    ref = reference(settings["trajectory"], settings["duration"], seed, 1.0 / control, box)
    outside(ref, box, robot, settings["trajectory"])
    out, g, steps = chain_loop.run(
        plant, ref, box, progress=progress, control=control, bandwidth_hz=settings["bandwidth_hz"]
    )
    if plant.elastic is not None:  # the spring's link inertia over the motion run (the other joints move)
        n, j = robot.n_joints, plant.elastic.index
        q_true = out[:: max(1, len(out) // 2000), n : 2 * n] + plant.offset  # at most ~2000 poses
        M = chain_plant.link_inertia(plant, j, q_true)
        plant.elastic = replace(plant.elastic, trial_inertia=(float(M.mean()), float(M.min()), float(M.max())))
    sigma = NOISE_SHARE * np.asarray(arm_scale.torque)
    frame = logged(
        out,
        ref,
        robot,
        settings,
        scale,
        plant.logged_torque,
        plant.elastic,
        noise_std=sigma,
        encoder_step=encoder_steps(robot),
    )
    settings["effects_requested"] = {k: _plain(v) for k, v in wanted.items()}
    error = out[:, robot.n_joints : 2 * robot.n_joints] - ref.q
    truth = _arm_truth(plant, settings, sigma * scale if settings["noise"] else np.zeros(robot.n_joints))
    truth["controller"] = {
        "control_hz": control,
        "bandwidth_hz": settings["bandwidth_hz"],
        "kp": list(g.kp),
        "kd": list(g.kd),
        "rk4_substeps": steps.fine,
        "rk4_substeps_away_from_reversals": steps.coarse,
        "fine_tick_share": steps.fine_share,
    }
    truth["tracking"] = {"rms_error": np.sqrt((error**2).mean(0)).tolist(), "max_error": np.abs(error).max(0).tolist()}
    truth["limits"] = {"position_min": box.q_min.tolist(), "position_max": box.q_max.tolist()}
    return SimTrial(frame, _plain(truth), robot)


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


def encoder_steps(robot: Robot) -> np.ndarray:
    """Each joint's encoder step [rad], joint side: `ENCODER_COUNTS` per motor revolution through its gear ratio, or
    `JOINT_COUNTS` per joint revolution where the problem gives no gear ratio."""
    return np.array(
        [
            2 * np.pi / (measurement.ENCODER_COUNTS * j.gear_ratio) if j.gear_ratio else 2 * np.pi / JOINT_COUNTS
            for j in robot.joints
        ]
    )


def _arm_truth(plant, settings: dict, noise_std: np.ndarray) -> dict:
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
            "encoder_step_rad": encoder_steps(plant.robot).tolist() if settings["noise"] else None,
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


def _plain(value):
    """JSON-able copy (tuples to lists, NumPy scalars to floats)."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _truth_dict(robot: PlanarRobot, truth: Truth, out: np.ndarray, q_ref: np.ndarray, settings: dict) -> dict:
    """The ground truth, with effects in the diagnosis's estimate keys (`docs/effects.md`)."""
    effects = {name: CATALOGUE[name].truth_entry(truth, p) for name, p in truth.effects.items()}
    physical = asdict(rigid_body(truth.robot, "physical"))  # the true plant's, not the datasheet's
    for name, p in truth.effects.items():
        CATALOGUE[name].true_physical(physical, p)
    g = closed_loop.gains(robot, settings["bandwidth_hz"])
    control = closed_loop.control_hz(settings["rate_hz"])
    error = out[:, 2:4] - q_ref  # encoder angle minus reference, at every control tick
    return _plain(
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


#: Each kind of arm's trial (`arm.kinds.ByKind`): the one place the simulator asks which kind it has.
TRIALS = ByKind(planar=_planar_trial, chain=_arm_trial)
