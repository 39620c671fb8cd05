"""Background realism: what a real flexible arm does beyond the diagnosis catalogue (see effects.BACKGROUND).

All three act on the joint (motor-side, collocated with the encoder) torques of the truth plant, whatever its
kind (rigid, elastic joint, flexible link); with none active the plant is untouched. Joint side, SI units:

- ``stiction``: presliding (Dahl) friction per joint j, with its bristle deflection z_j [rad] an extra state,
      F_j = σ0_j z_j,   dz_j/dt = v_j − σ0_j |v_j| z_j / Fb_j,
  v_j the encoder-side rate. Sliding, F_j → Fb_j sgn(v_j) (a Coulomb-like level the rigid model absorbs);
  at rest z_j stays where the last motion left it, so the joint holds a torque that depends on how it came
  to rest, and the PD (no integrator) keeps whatever error it had. z starts at a random presliding state,
  uniform in |z| < Fb/σ0 (the arm came to rest somehow before the trial).
- ``drift``: a slow torque disturbance d(t) on the joints (cable drag, thermal drift of the drive), an
  Ornstein-Uhlenbeck process of standard deviation s and correlation time T, stationary from the start:
      d_{k+1} = a d_k + s √(1 − a²) ξ_k,   a = exp(−Δt / T),   ξ_k ~ N(0, 1) per 1 ms tick.
  The controller does not know it; the PD answers it, so it shows in the logged torque, mostly below 1 Hz.
- ``ripple``: a current ripple locked to the motor angle θ_m = N q (back-EMF harmonics the current loop does
  not remove, so its amplitude grows with speed): r_j = a_j v_j sin(c_j N_j q_j). It is part of the actual
  motor current, so it is both applied to the arm (held over each tick, like the commanded torque) and logged;
  at 100 Hz logging its lines alias as a real logger's would.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from ident_opt.problem import Robot

#: rad/s: a bound of the joint speeds the trajectories reach (plateaus ≤ 1.33 rad/s, plus PD overshoot).
MAX_SPEED = 3.0


def has_states(background: dict) -> bool:
    """Whether the background adds states (stiction's two bristle deflections)."""
    return "stiction" in background


def with_background(base: ca.Function, nx: int, background: dict) -> ca.Function:
    """The plant with background terms: (x, τ, d) -> (ẋ, y), x = [base state (nx), z (2) if stiction].

    τ [N m] is the actual motor torque (commanded + ripple), d [N m] the drift disturbance; with no
    background the result is `base` evaluated at τ, exactly (d unused).
    """
    n_z = 2 if has_states(background) else 0
    x, tau, d = ca.SX.sym("x", nx + n_z), ca.SX.sym("tau", 2), ca.SX.sym("d", 2)
    applied = tau
    if "drift" in background:
        applied = applied + d
    if n_z:
        p = background["stiction"]
        sigma = ca.DM(p["stiffness"])
        z = x[nx:]
        applied = applied - sigma * z
    xdot, y = base(x[:nx], applied)
    if n_z:
        v = y[2:4]  # encoder-side rates: the motor side at an elastic joint, where the gearbox is
        # Fb = 0 on a joint: its z stays at 0 (and starts there), so it adds no force.
        active = ca.DM([1.0 if b > 0 else 0.0 for b in p["breakaway"]])
        safe_fb = ca.DM([b if b > 0 else 1.0 for b in p["breakaway"]])
        zdot = active * (v - sigma * ca.fabs(v) * z / safe_fb)
        xdot = ca.vertcat(xdot, zdot)
    return ca.Function("plant_bg", [x, tau, d], [xdot, y], ["x", "tau", "d"], ["xdot", "y"])


def ripple(background: dict, robot: Robot, q_enc: ca.SX, dq_enc: ca.SX) -> ca.SX | None:
    """The current ripple r [N m] at encoder angles q_enc [rad] and rates dq_enc [rad/s]; None when off."""
    if "ripple" not in background:
        return None
    p = background["ripple"]
    gear = [j.gear_ratio for j in robot.joints]
    return ca.vertcat(*[p["amplitude"][j] * dq_enc[j] * ca.sin(p["cycles"][j] * gear[j] * q_enc[j]) for j in range(2)])


def drift(background: dict, n: int, dt: float, rng: np.random.Generator) -> np.ndarray:
    """The drift disturbance d (n, 2) [N m] on a grid of step dt [s] (zeros when off; no draw then)."""
    out = np.zeros((n, 2))
    if "drift" not in background or n == 0:
        return out
    p = background["drift"]
    s, a = np.asarray(p["std"]), math.exp(-dt / p["time"])
    xi = rng.standard_normal((n, 2))
    out[0] = s * xi[0]  # stationary from the start
    kick = s * math.sqrt(1.0 - a * a) * xi
    for k in range(1, n):  # first-order recursion: a Python loop over 80 000 ticks costs ~50 ms
        out[k] = a * out[k - 1] + kick[k]
    return out


def initial_bristles(background: dict, rng: np.random.Generator) -> np.ndarray:
    """z at the start [rad]: uniform in |z| < Fb/σ0 per joint (empty when there is no stiction)."""
    if not has_states(background):
        return np.zeros(0)
    p = background["stiction"]
    limit = np.asarray(p["breakaway"]) / np.asarray(p["stiffness"])
    return rng.uniform(-1.0, 1.0, 2) * limit


def rates(background: dict, inertia: np.ndarray) -> list[float]:
    """Bounds of the fastest rates [1/s] stiction adds, for the RK4 step: the bristle equation's
    σ0 v_max / Fb and the presliding oscillation √(σ0 / J) (J [kg m²] a lower bound of each joint's inertia)."""
    if not has_states(background):
        return []
    p = background["stiction"]
    out = []
    for j in range(2):
        sigma, fb = p["stiffness"][j], p["breakaway"][j]
        if fb > 0:
            out += [sigma * MAX_SPEED / fb, math.sqrt(sigma / inertia[j])]
    return out
