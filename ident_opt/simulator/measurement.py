"""From the simulated control loop to a logged trial, the way a real robot's logger would record it.

- logging at `rate_hz`: a divisor of the 1 kHz control rate (1000, 500, 250, 200, 100 ... Hz), or a faster
  rate up to 5 kHz, at which the controller then runs too (one logged sample per tick, see `closed_loop`);
- encoders quantised to `ENCODER_COUNTS` counts per motor revolution (joint-side step 2π/(counts·N));
- torque (or current) noise: white Gaussian, σ per joint as measured on the real exp1 at rest;
- the torque channel as the hidden effects leave it (`Truth.logged_torque`: e.g. a delay);
- dq, ddq estimated from the logged angles with the project's zero-phase estimator (`estimate_derivatives`),
  unless exact derivatives are asked for (then the true encoder-side rates and the accelerations the
  dynamics produce, so that the rigid model holds exactly at every logged sample).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pandas as pd

from ident_opt.columns import columns_of, joint_columns
from ident_opt.errors import InputError
from ident_opt.numerics.derivatives import estimate_derivatives
from ident_opt.simulator.closed_loop import CONTROL_HZ, MAX_CONTROL_HZ, control_hz

ENCODER_COUNTS = 4096  # counts per motor revolution (a 1024-line encoder, quadrature)
#: Encoder counts per joint revolution where a joint's gear ratio is not given (a 19-bit joint-side encoder).
JOINT_COUNTS = 2**19
TORQUE_NOISE = (
    0.16,
    0.054,
)  # N m, white part of the real exp1 torque at rest (first 15 s, std of Δτ over √2)
DERIVATIVE_CUTOFF_HZ = 15.0  # Hz: the logger's fixed cut-off (the real exp1's pipeline, not the loader's rule)


def decimation(rate_hz: float) -> int:
    """Control ticks per logged sample: the rate must divide the 1 kHz control rate, or be faster than it
    (up to `MAX_CONTROL_HZ`), in which case the loop runs at the logging rate and every tick is logged."""
    ok = np.isfinite(rate_hz) and 0 < rate_hz <= MAX_CONTROL_HZ
    ratio = control_hz(rate_hz) / rate_hz if ok else np.nan
    if not (np.isfinite(ratio) and abs(ratio - round(ratio)) <= 1e-9):
        raise InputError(
            f"rate {rate_hz:g} Hz: the logging rate must divide the {CONTROL_HZ:g} Hz control rate "
            f"(e.g. 1000, 500, 250, 200, 100, 50 Hz) or be faster, up to {MAX_CONTROL_HZ:g} Hz"
        )
    return round(ratio)


def log(
    out: np.ndarray,
    q_ref: np.ndarray,
    robot,
    *,
    rate_hz: float,
    channel: Callable[[np.ndarray, np.ndarray], np.ndarray],
    noise: bool,
    noise_scale: float | np.ndarray = 1.0,
    exact_derivatives: bool,
    output: str,
    rng: np.random.Generator,
    deflection_column: str | None,
    noise_std: np.ndarray | None = None,
    encoder_step: np.ndarray | None = None,
) -> pd.DataFrame:
    """The logged trial as a data-format frame, from the per-tick loop output (N, 4n + 1): τ, q_enc, dq_enc, ddq_enc
    (n each) and a deflection (see `plant.Plant.run`).

    `channel`: (t [s], τ (N, n) [N m]) -> the torque as logged, at the ticks; `deflection_column`: where the
    spring deflection goes (None: the plant has none); `noise_std` (n,) [N m] and `encoder_step` (n,) [rad]: the
    torque noise's σ and the encoders' joint-side step (default: the planar arm's, `TORQUE_NOISE` and
    `ENCODER_COUNTS` per motor revolution through its gears)."""
    every = decimation(rate_hz)
    n_ticks, n = out.shape[0], q_ref.shape[1]
    t_tick = np.arange(n_ticks) / control_hz(rate_hz)
    idx = np.arange(0, n_ticks, every)
    t = t_tick[idx]
    tau_tick, q_enc, dq_enc, ddq_enc, deflection = (
        out[:, :n],
        out[:, n : 2 * n],
        out[:, 2 * n : 3 * n],
        out[:, 3 * n : 4 * n],
        out[:, 4 * n],
    )
    tau = channel(t_tick, tau_tick)[idx]
    q = q_enc[idx].copy()
    if noise:
        if encoder_step is None:
            encoder_step = encoder_steps(robot)
        sigma = np.asarray(TORQUE_NOISE) if noise_std is None else np.asarray(noise_std)
        q = np.round(q / encoder_step) * encoder_step
        tau = tau + rng.normal(size=tau.shape) * (noise_scale * sigma)
    if exact_derivatives:
        dq, ddq = dq_enc[idx], ddq_enc[idx]
    else:
        dq, ddq, _ = estimate_derivatives(t, q, DERIVATIVE_CUTOFF_HZ)
    load = tau / current_factors(robot) if output == "current" else tau
    signals = {"q": q, "dq": dq, "ddq": ddq, "i" if output == "current" else "tau": load}
    cols = {"t": t, **columns_of(signals)}
    # Extra columns a real logger has: the commanded angles, and a strain-like deflection of a spring.
    cols.update({f"{name}_ref": q_ref[idx, j] for j, name in enumerate(joint_columns("q", q.shape[1]))})
    if deflection_column is not None:
        cols[deflection_column] = deflection[idx]
    return pd.DataFrame(cols)


def current_factors(robot) -> np.ndarray:
    """Each joint's torque per ampere [N m/A] (torque constant × gear ratio); an InputError naming the first joint
    whose problem file does not give both (currents cannot be logged or read without them)."""
    factors = []
    for name, table, joint in zip(robot.joint_names, robot.joint_tables, robot.joints):
        k = joint.current_to_torque
        if k is None or not np.isfinite(k) or k == 0:
            raise InputError(
                f"currents need each joint's torque constant and gear ratio; [robot.{table}] ({name}) does not give "
                "both (torque_constant, gear_ratio): log torques instead, or add them"
            )
        factors.append(float(k))
    return np.array(factors)


def encoder_steps(robot) -> np.ndarray:
    """Each joint's encoder step [rad], joint side: `ENCODER_COUNTS` per motor revolution through its gear ratio, or
    `JOINT_COUNTS` per joint revolution where the problem gives no gear ratio."""
    return np.array(
        [
            2 * np.pi / (ENCODER_COUNTS * j.gear_ratio) if j.gear_ratio else 2 * np.pi / JOINT_COUNTS
            for j in robot.joints
        ],
    )
