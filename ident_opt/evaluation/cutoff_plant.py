"""Trials for the derivative cut-off study (`evaluation.cutoff_study`): an arm driven in the kinds of motion people
record, sampled and measured like a real log.

Deliberately not the project's closed-loop simulator (`ident_opt.simulator`): the cut-off rule is judged on a
plant it was not developed with — another integrator (RK4 on the arm's own M, C, G, F), another controller, other
references and another noise model.

Kinds of motion (each 20 s by default, from rest at the hanging pose q0 = (−π/2, 0)):

- ``driven``: both joints track a sum of sines (0.1–2 Hz) of about 1 rad.
- ``passive``: joint 1 tracks the sines; joint 2 has no torque at all and swings with it.
- ``swing_up``: both joints swing through large angles (about ±2.5 rad), faster toward the end.
- ``steps``: point-to-point moves (quintic, 0.6–1.2 s) to random poses, each followed by a rest of 1.5–3 s.

Measurement: angles quantised to an encoder step with white noise, torques with white noise and a quantisation
step, all scaled by the condition's noise factor. Units: s, rad, N m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np
import pandas as pd

from ident_opt.arm.base import Arm
from ident_opt.simulator.integrate import rk4_step

KINDS = ("driven", "passive", "swing_up", "steps")
#: Measurement noise at noise factor 1: encoder step [rad] (15 bits a turn), angle noise [rad], torque noise and
#: quantisation step [N m] (the DFKI pendulum's driver reports torque in 0.006 N m steps).
ENCODER_STEP = 2 * math.pi / 2**15
ANGLE_NOISE = 5e-5
TORQUE_NOISE = 0.03
TORQUE_STEP = 0.006
#: The plant integrates at this rate [Hz] (RK4), holding the torque over each control period.
PLANT_HZ = 4000.0
#: PD bandwidth of the tracking controller [Hz] (on top of the model's feed-forward).
BANDWIDTH_HZ = 4.0


@dataclass(frozen=True)
class Condition:
    """One cell of the study: the kind of motion, the sampling (and control) rate [Hz] and the noise factor."""

    kind: str
    rate_hz: float
    noise: float


#: The plant's Coulomb friction is smooth, fc·tanh(dq / `STICTION_SPEED`) [rad/s]: a sign switching inside the
#: integrator would chatter at every rest, which no real joint does (the model identified is still fc·sign(dq)).
STICTION_SPEED = 0.005


def _coulomb(arm: Arm) -> np.ndarray:
    """Which parameters of `arm` are Coulomb friction: a friction column whose size does not change with speed."""
    F = arm.function("F")
    q, v = np.zeros(arm.n_joints), np.full(arm.n_joints, 0.7)
    out = np.zeros(arm.n_params, dtype=bool)
    for p, par in enumerate(arm.parameters):
        e = np.eye(arm.n_params)[p]
        slow, fast = np.asarray(F(q, v, q, e)).ravel(), np.asarray(F(q, 2 * v, q, e)).ravel()
        out[p] = par.kind == "friction" and np.any(slow != 0) and np.allclose(slow, fast)
    return out


@lru_cache(maxsize=8)
def _step(arm: Arm, substeps: int) -> ca.Function:
    """x⁺ = RK4 over one control period h of ẋ = (dq, M⁻¹(τ − C dq − G − F)), τ held; inputs (x, tau, pi, h).
    F is the arm's friction with its Coulomb terms smoothed (`STICTION_SPEED`)."""
    s = arm.symbols
    n = arm.n_joints
    x = ca.SX.sym("x", 2 * n)
    tau, pi, h = ca.SX.sym("tau", n), s["pi"], ca.SX.sym("h")
    coulomb = _coulomb(arm)
    F = ca.Function("F", [s["q"], s["dq"], s["pi"]], [s["F"]])
    smooth = ca.tanh(ca.fabs(s["dq"]) / STICTION_SPEED)
    friction = F(s["q"], s["dq"], s["pi"] * (1 - coulomb)) + F(s["q"], s["dq"], s["pi"] * coulomb) * smooth
    accel = ca.Function(
        "a", [s["q"], s["dq"], s["pi"], tau], [ca.solve(s["M"], tau - s["C"] @ s["dq"] - s["G"] - friction)]
    )

    def f(state):
        return ca.vertcat(state[n:], accel(state[:n], state[n:], pi, tau))

    y, dt = x, h / substeps
    for _ in range(substeps):
        y = rk4_step(f, y, dt)
    return ca.Function("step", [x, tau, pi, h], [y])


def _sines(t: np.ndarray, rng: np.random.Generator, amplitude: float, top_hz: float) -> np.ndarray:
    """A sum of five sines between 0.1 Hz and `top_hz`, random phases, peak about `amplitude` [rad], faded in over
    the first second (so motion starts from rest)."""
    freqs = np.geomspace(0.1, top_hz, 5)
    phases = rng.uniform(0, 2 * np.pi, 5)
    weights = rng.uniform(0.5, 1.0, 5) / freqs**0.5
    x = sum(w * np.sin(2 * np.pi * f * t + p) for w, f, p in zip(weights, freqs, phases))
    x = x - x[0]
    fade = np.clip(t / 1.0, 0, 1) ** 2 * (3 - 2 * np.clip(t / 1.0, 0, 1))
    return amplitude * fade * x / np.max(np.abs(x))


def _steps(t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Quintic moves to random poses (±1.5 rad about the start), each followed by a rest of 1.5–3 s."""
    q = np.zeros((len(t), 2))
    start, now, pose = 1.0, 1.0, np.zeros(2)
    while now < t[-1]:
        target = rng.uniform(-1.5, 1.5, 2)
        move = rng.uniform(0.6, 1.2)
        s = np.clip((t - now) / move, 0, 1)
        blend = 10 * s**3 - 15 * s**4 + 6 * s**5
        later = t >= now
        q[later] = pose + blend[later, None] * (target - pose)
        pose, now = target, now + move + rng.uniform(1.5, 3.0)
    del start
    return q


def reference(kind: str, t: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(q_r (N, 2) about the hanging pose [rad], driven (2,) bool) for motion `kind`."""
    if kind == "driven":
        q = np.column_stack([_sines(t, rng, 1.0, 2.0), _sines(t, rng, 1.2, 2.0)])
        return q, np.array([True, True])
    if kind == "passive":
        return np.column_stack([_sines(t, rng, 1.0, 1.5), np.zeros(len(t))]), np.array([True, False])
    if kind == "swing_up":
        ramp = np.clip(t / t[-1], 0, 1)
        q = np.column_stack([_sines(t, rng, 2.5, 0.8), _sines(t, rng, 2.0, 1.0)]) * (0.5 + 0.5 * ramp[:, None])
        return q, np.array([True, True])
    if kind == "steps":
        return _steps(t, rng), np.array([True, True])
    raise ValueError(f"unknown kind {kind!r}; known: {', '.join(KINDS)}")


def simulate(arm: Arm, pi: np.ndarray, condition: Condition, seed: int, duration: float = 20.0) -> pd.DataFrame:
    """One measured trial of `arm` with true parameters `pi`: columns t, q1, q2, tau1, tau2 (SI units), sampled at
    the condition's rate with its noise. The controller (at the same rate) is the model's feed-forward along the
    reference plus a PD; an undriven joint gets no torque."""
    rng = np.random.default_rng(seed)
    h = 1.0 / condition.rate_hz
    t = np.arange(round(duration * condition.rate_hz)) * h
    q0 = np.array([-np.pi / 2, 0.0])
    q_r, driven = reference(condition.kind, t, rng)
    q_r = q_r + q0
    dq_r = np.gradient(q_r, h, axis=0)
    ddq_r = np.gradient(dq_r, h, axis=0)
    tau_ff = arm.predict(pi, q_r, dq_r, ddq_r)
    M = arm.mass_matrices(pi, q_r)
    wn = 2 * np.pi * BANDWIDTH_HZ
    step = _step(arm, max(1, math.ceil(PLANT_HZ * h)))
    x = np.concatenate([q0, np.zeros(2)])
    q_true, tau_true = np.empty((len(t), 2)), np.empty((len(t), 2))
    for k in range(len(t)):
        q, dq = x[:2], x[2:]
        # PD shaped by the mass matrix, so both joints track at the same bandwidth
        tau = tau_ff[k] + M[k] @ (wn**2 * (q_r[k] - q) + 2 * wn * (dq_r[k] - dq))
        tau = np.where(driven, tau, 0.0)
        q_true[k], tau_true[k] = q, tau
        x = np.asarray(step(x, tau, pi, h)).ravel()
    s = condition.noise
    q_meas = q_true + rng.normal(0, ANGLE_NOISE * s, q_true.shape)
    q_meas = np.round(q_meas / (ENCODER_STEP * s)) * ENCODER_STEP * s
    tau_meas = tau_true + rng.normal(0, TORQUE_NOISE * s, tau_true.shape)
    tau_meas = np.round(tau_meas / (TORQUE_STEP * s)) * TORQUE_STEP * s
    return pd.DataFrame(
        {"t": t, "q1": q_meas[:, 0], "q2": q_meas[:, 1], "tau1": tau_meas[:, 0], "tau2": tau_meas[:, 1]}
    )
