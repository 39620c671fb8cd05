"""`simulate_trial`: one measured-style trial from the built-in simulator, with its ground truth."""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ident_opt import outputs
from ident_opt.arm.base import Robot
from ident_opt.arm.kinds import ByKind
from ident_opt.columns import channel_names, data_columns
from ident_opt.data.dataset import Dataset, in_source_convention
from ident_opt.errors import InputError
from ident_opt.problem.spec import Limits
from ident_opt.simulator import closed_loop, measurement
from ident_opt.simulator.chain import ChainPlant
from ident_opt.simulator.planar import PlanarPlant
from ident_opt.simulator.plant import plain
from ident_opt.simulator.trajectories import RANGE_MARGIN, Reference
from ident_opt.simulator.truth import Truth

MIN_DURATION, MAX_DURATION = 1.0, 3600.0  # s: enough samples for the derivative filter; memory stays bounded
#: The controller's closed-loop bandwidth [Hz] a trial may ask for: a sluggish loop still tracks the slow
#: references; a stiff one stays well below the 1 kHz controller's Nyquist limit.
MIN_BANDWIDTH, MAX_BANDWIDTH = 1.0, 40.0
#: Largest torque-noise multiple (of the σ measured on the real robot).
MAX_NOISE_SCALE = 100.0
#: An n-joint arm's torque noise: this share of each joint's reference torque (`ArmScale.torque`, its effort limit):
#: 0.35 N m on a 176 N m joint, 0.024 N m on a 12 N m wrist, the order of a joint-torque sensor's.
NOISE_SHARE = 0.002
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
    #: the files the trial was made from (the problem file, its URDF, its trials): `write` never replaces one
    inputs: tuple[Path, ...] = ()

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
        path = check_trial_path(csv_path)
        gz = path.name.lower().endswith(".gz")
        try:
            truth = json.dumps(self.truth, indent=2, allow_nan=False) + "\n"
        except ValueError:
            raise InputError(
                f"{path}: the simulated trial's truth holds non-finite numbers (an effect too large to simulate); "
                "nothing written"
            ) from None
        # A robot whose data have their own angle convention (a URDF arm's) logs in it; the loader maps it back.
        frame = in_source_convention(self.frame, self.robot.column_map)
        # Called from the API (no command's run around it): a run of its own, so that the command line's output
        # rules hold (never one of the trial's inputs; both files or neither).
        with contextlib.nullcontext() if outputs.current() is not None else outputs.run():
            outputs.declare_inputs(self.inputs)
            try:
                _atomic(path, lambda tmp: frame.to_csv(tmp, index=False, compression="gzip" if gz else None))
                _atomic(truth_path(path), lambda tmp: tmp.write_text(truth))
            except OSError as exc:
                raise InputError(f"{path}: cannot write the simulated trial ({exc.strerror})") from None
        return path


def check_trial_path(csv_path: str | Path, flag: str | None = None) -> Path:
    """`csv_path` as a Path, once it names a CSV (*.csv or *.csv.gz, the only format a simulated trial is written
    in); an InputError (naming `flag`) otherwise, which `ident-opt simulate` raises before it simulates anything."""
    path = Path(csv_path)
    if not path.name.lower().endswith((".csv", ".csv.gz")):
        label = f"{flag} {path}" if flag else str(path)
        raise InputError(
            f"{label}: the simulated trial is written as CSV only (not {path.suffix or 'a name without a suffix'}); "
            "name it *.csv or *.csv.gz"
        )
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


def _checked_arguments(
    robot: Robot,
    output: str,
    duration: float,
    seed: int,
    rate_hz: float,
    bandwidth_hz: float,
    noise_scale: float | Sequence[float],
) -> np.ndarray:
    """The noise scale as an array (one value, or one per joint), after an InputError for any argument of
    `simulate_trial` out of range: a bad request is refused before any simulation work."""
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
    return scale


def simulate_trial(
    robot: Robot,
    *,
    # the motion
    trajectory: str = "tud01",
    duration: float = 80.0,
    seed: int = 0,
    limits: Limits | None = None,
    # the hidden plant and its loop
    effects: Mapping[str, Mapping] | Sequence[str] = (),
    mechanism: Callable[[Truth], object] | None = None,
    bandwidth_hz: float = closed_loop.BANDWIDTH_HZ,
    # the log
    rate_hz: float = 100.0,
    output: str = "torque",
    noise: bool = True,
    noise_scale: float | Sequence[float] = 1.0,
    exact_derivatives: bool = False,
    progress: bool = True,
) -> SimTrial:
    """Simulate one trial of `robot` with hidden `effects`; deterministic.

    `effects`: name -> keys (e.g. {"elasticity": {"joint": 2, "frequency_hz": 8}}) or effect strings
    ("elasticity:joint=2,frequency_hz=8"); see `ident_opt.effects.CATALOGUE`. `duration` [s], `rate_hz` [Hz] (a divisor
    of 1 kHz, or faster up to 5 kHz: the controller then runs at that rate), `output` "torque" (tau1 … taun
    [N m]) or "current" (i1 … in [A]). With `noise=False` the angles are not quantised and no noise is added;
    `exact_derivatives=True` logs the true dq and the ddq the dynamics produce instead of estimating them
    from the logged angles. `bandwidth_hz` [Hz]: the controller's closed-loop bandwidth (its PD gains);
    `noise_scale`: the torque noise's σ as a multiple of the arm's reference σ (with `noise`), one factor for
    every joint or one per joint. The planar two-link arm (`planar.PlanarPlant`) is its datasheet read
    physically, on the MERIt trials' motion; an arm of n joints is its nominal model (`chain.ChainPlant`) moving within
    `limits` (the problem's `[limits]`; default: the URDF's <limit> values, `Robot.limits`). `mechanism` (planar
    arm): truth -> a mechanism that replaces the one the hidden effects built (`truth.elastic`), e.g. a plant the
    diagnosis was not tuned on (`simulator.unseen`).
    """
    n = robot.n_joints
    scale = _checked_arguments(robot, output, duration, seed, rate_hz, bandwidth_hz, noise_scale)
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
    plant = PLANTS.of(robot)(robot, effects, limits, mechanism)
    control = closed_loop.control_hz(settings["rate_hz"])  # 1 kHz unless the log is faster
    ref = plant.reference(settings, control)
    out = plant.run(ref, control, settings, progress)
    finite(out, plant.effects)
    frame = logged(out, ref, robot, settings, scale, plant.logged_torque, plant.elastic, **plant.sensors)
    settings["effects_requested"] = {k: plain(v) for k, v in plant.requested.items()}
    return SimTrial(frame, plant.truth_file(out, ref, settings, scale), robot)


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


#: Each kind of arm's plant (`arm.kinds.ByKind`): the one place the simulator asks which kind it has.
PLANTS = ByKind(planar=PlanarPlant, chain=ChainPlant)
