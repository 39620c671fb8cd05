"""`simulate_trial`: one measured-style trial from the built-in simulator, with its ground truth."""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from ident_opt import outputs
from ident_opt.arm.datasheet import PlanarRobot, datasheet_pi, rigid_body
from ident_opt.columns import channel_names, data_columns
from ident_opt.data import Dataset, in_source_convention
from ident_opt.effects import CATALOGUE, is_active, normalise
from ident_opt.errors import InputError
from ident_opt.simulate import closed_loop, measurement
from ident_opt.simulate.trajectories import reference
from ident_opt.simulate.truth import TRUTH_MODEL, Truth, build_truth, coulomb_levels

MIN_DURATION, MAX_DURATION = 1.0, 3600.0  # s: enough samples for the derivative filter; memory stays bounded
#: The controller's closed-loop bandwidth [Hz] a trial may ask for: a sluggish loop still tracks the slow
#: references; a stiff one stays well below the 1 kHz controller's Nyquist limit.
MIN_BANDWIDTH, MAX_BANDWIDTH = 1.0, 40.0
#: Largest torque-noise multiple (of the σ measured on the real robot).
MAX_NOISE_SCALE = 100.0


@dataclass
class SimTrial:
    """A simulated trial: `frame` in the data format (plus extra columns), `truth` a JSON-able dict."""

    frame: pd.DataFrame
    truth: dict
    robot: PlanarRobot

    def dataset(self) -> Dataset:
        """The trial as the data loader would return it (currents converted to joint torques)."""
        f = self.frame
        names = channel_names(self.robot.n_joints)

        def signal(kind: str) -> np.ndarray:
            return f[list(names[kind])].to_numpy(dtype=float)

        if names["tau"][0] in f:
            tau = signal("tau")
        else:
            tau = signal("i") * np.array([j.current_to_torque for j in self.robot.joints])
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
            ["simulated by ident_opt.simulate"],
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
            path.parent.mkdir(parents=True, exist_ok=True)
            # A robot whose data have their own angle convention (a URDF arm's) logs in it; the loader maps it back.
            frame = in_source_convention(self.frame, self.robot.column_map)
            _atomic(path, lambda tmp: frame.to_csv(tmp, index=False, compression="gzip" if gz else None))
            _atomic(truth_path(path), lambda tmp: tmp.write_text(json.dumps(self.truth, indent=2) + "\n"))
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
    robot: PlanarRobot,
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
    mechanism: Callable[[Truth], object] | None = None,
) -> SimTrial:
    """Simulate one trial of `robot` (datasheet read physically) with hidden `effects`; deterministic.

    `effects`: name -> keys (e.g. {"elasticity": {"joint": 2, "frequency_hz": 8}}) or effect strings
    ("elasticity:joint=2,frequency_hz=8"); see `ident_opt.effects.CATALOGUE`. `duration` [s], `rate_hz` [Hz] (a divisor
    of 1 kHz, or faster up to 5 kHz: the controller then runs at that rate), `output` "torque" (tau1, tau2
    [N m]) or "current" (i1, i2 [A]). With `noise=False` the angles are not quantised and no noise is added;
    `exact_derivatives=True` logs the true dq and the ddq the dynamics produce instead of estimating them
    from the logged angles. `bandwidth_hz` [Hz]: the controller's closed-loop bandwidth (its PD gains);
    `noise_scale`: the torque noise's σ as a multiple of the one measured on the real robot (with `noise`), one
    factor for both joints or one per joint. `mechanism`: truth -> a mechanism that replaces the one the hidden
    effects built (`truth.elastic`), e.g. a plant the diagnosis was not tuned on (`simulate.unseen`).
    """
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
    if scale.shape not in ((), (2,)) or not np.all(np.isfinite(scale) & (scale >= 0) & (scale <= MAX_NOISE_SCALE)):
        raise InputError(
            f"noise scale {noise_scale!r}: must be between 0 and {MAX_NOISE_SCALE:g}, one for both joints or one each"
        )
    scale = np.broadcast_to(scale, (2,))
    coulomb = coulomb_levels(robot)
    wanted = normalise(effects, coulomb)
    active = {name: p for name, p in wanted.items() if is_active(name, p, coulomb)}
    truth = build_truth(robot, active)
    if mechanism is not None:
        truth = replace(truth, elastic=mechanism(truth))
    control = closed_loop.control_hz(rate_hz)  # 1 kHz unless the log is faster
    ref = reference(trajectory, duration, seed, 1.0 / control)
    out = closed_loop.run(
        truth, robot, ref, progress=progress, seed=int(seed), control=control, bandwidth_hz=bandwidth_hz
    )
    rng = np.random.default_rng([seed, 11])  # the measurement noise's own stream
    frame = measurement.log(
        out,
        ref.q,
        robot,
        rate_hz=rate_hz,
        channel=truth.logged_torque,
        noise=noise,
        noise_scale=scale,
        exact_derivatives=exact_derivatives,
        output=output,
        rng=rng,
        deflection_column=truth.elastic.deflection_column if truth.elastic else None,
    )
    settings = {
        "trajectory": trajectory,
        "duration": float(duration),
        "rate_hz": float(rate_hz),
        "seed": int(seed),
        "output": output,
        "noise": bool(noise),
        "noise_scale": float(scale[0]) if np.ndim(noise_scale) == 0 else scale.tolist(),
        "bandwidth_hz": float(bandwidth_hz),
        "exact_derivatives": bool(exact_derivatives),
        "effects_requested": {k: _plain(v) for k, v in wanted.items()},
    }
    return SimTrial(frame, _truth_dict(robot, truth, out, ref.q, settings), robot)


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
