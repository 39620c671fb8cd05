"""Reference trajectories q_r(t), dq_r(t), ddq_r(t) for the closed-loop simulator [rad, rad/s, rad/s²].

- ``tud01``: like the MERIt/TUDOR trial TUD01 — a rest, then point-to-point moves with trapezoidal
  velocity profiles (velocity plateaus at about 1.1 / 1.3 rad/s as in the real trial), separated by rests
  of 0.2–2 s, many of them moving a single joint.
- ``fourier``: a Swevers-style excitation, q_i(t) = q0_i + Σ_l a_il/(l ω_f) sin(l ω_f t) − b_il/(l ω_f)
  cos(l ω_f t), faded in smoothly from rest and scaled to the joint, speed and acceleration limits.
- ``mixed``: 10 s blocks of the two, alternating (point-to-point first), each starting and ending at rest at
  the centre pose: the smooth blocks cross low speeds slowly (Stribeck friction shows), the point-to-point
  ones stop and start (modes ring, a delay shows on every edge). For effects that need both.
- a trajectory file (a path ending in .csv, e.g. written by `ident-opt excite`): columns t, q1, q2, dq1, dq2,
  ddq1, ddq2 [s, rad, rad/s, rad/s²] (other columns ignored), interpolated linearly onto the controller's grid;
  it must cover the duration.

Limits are those measured on the real exp1 trial (q1 in [0.23, 3.17], q2 in [−1.43, 1.40] rad,
|dq| up to about 1.2 / 1.35 rad/s, |ddq| up to about 4.5 / 6.6 rad/s²).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ident_opt.columns import kinematic_columns
from ident_opt.errors import InputError
from ident_opt.problem.spec import TRAJECTORIES  # the names a [simulate] section may give

Q_MIN = np.array([0.25, -1.40])  # rad
Q_MAX = np.array([3.15, 1.40])  # rad
V_MAX = np.array([1.12, 1.33])  # rad/s, the velocity plateaus of the real trial
A_MAX = np.array([4.0, 5.0])  # rad/s²
#: Joint torque range the trajectories are designed to stay within [N m]. The problem file carries no torque
#: limit; these are the real trials' extremes (13.1 and 2.6 N m on exp1) with a margin.
TAU_MAX = np.array([15.0, 4.0])

#: Largest |q| [rad], |dq| [rad/s] and |ddq| [rad/s²] a trajectory file may hold: beyond them it is not a motion
#: an arm makes (a unit mistake, a corrupted file), and the simulation would overflow.
FILE_BOUNDS = (100.0, 100.0, 1e4)
#: Length [s] of one block of the `mixed` reference.
MIXED_BLOCK_S = 10.0


@dataclass(frozen=True)
class Box:
    """Where a reference moves, per joint (n,): angles in [q_min, q_max] [rad], cruise speed v_max [rad/s],
    acceleration a_max [rad/s²]; point-to-point poses start `margin` [rad] inside the range and moves cover at
    least `step` [rad]."""

    q_min: np.ndarray
    q_max: np.ndarray
    v_max: np.ndarray
    a_max: np.ndarray
    margin: np.ndarray
    step: np.ndarray

    @property
    def n(self) -> int:
        """The number of joints."""
        return len(self.q_min)


#: The planar two-link arm's box: the real exp1's range, speeds and accelerations.
PLANAR = Box(Q_MIN, Q_MAX, V_MAX, A_MAX, np.full(2, 0.2), np.full(2, 0.3))
#: Of each joint's range an n-joint reference keeps away from either limit (the tracking error, a hidden offset
#: and the controller's overshoot stay inside), the share of its speed limit it cruises at (at most
#: `CRUISE_MAX`) and the share of its acceleration limit it uses.
RANGE_MARGIN, CRUISE_SHARE, CRUISE_MAX, ACCELERATION_SHARE = 0.15, 0.5, 1.5, 0.8
#: An n-joint reference's last move ends this long [s] before the trial does: it ends at rest, where the derivatives'
#: zero-phase filter has nothing to smear.
END_REST_S = 0.5
#: Acceleration limit [rad/s²] where neither [limits] nor the URDF gives one.
DEFAULT_ACCELERATION = 4.0


def arm_box(q_min, q_max, velocity, acceleration) -> Box:
    """The box of an n-joint arm whose joints' limits are q_min, q_max [rad], |dq| ≤ velocity [rad/s] and |ddq| ≤
    acceleration [rad/s²]: the range less `RANGE_MARGIN` at both ends, cruising at `CRUISE_SHARE` of the speed
    limit (at most `CRUISE_MAX`), `ACCELERATION_SHARE` of the acceleration limit; moves of at least 15 % of the
    range."""
    low, high = np.asarray(q_min, dtype=float), np.asarray(q_max, dtype=float)
    span = high - low
    inner_low, inner_high = low + RANGE_MARGIN * span, high - RANGE_MARGIN * span
    v = np.minimum(CRUISE_SHARE * np.asarray(velocity, dtype=float), CRUISE_MAX)
    a = ACCELERATION_SHARE * np.asarray(acceleration, dtype=float)
    return Box(inner_low, inner_high, v, a, 0.1 * span, 0.15 * span)


@dataclass(frozen=True)
class Reference:
    """A reference sampled at times t (N,), with q, dq, ddq (N, n)."""

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray


def reference(name: str, duration: float, seed: int, dt: float, box: Box = PLANAR) -> Reference:
    """The reference `name` ("tud01", "fourier", "mixed" or a trajectory file *.csv) over [0, duration] s every
    dt s, within `box` (default: the planar two-link arm's)."""
    t = np.arange(round(duration / dt)) * dt
    if str(name).lower().endswith(".csv"):
        return from_file(Path(name), t, box.n)
    if name not in TRAJECTORIES:
        raise InputError(f"trajectory {name!r}: unknown; known: {', '.join(TRAJECTORIES)}, or a *.csv file")
    rng = np.random.default_rng([seed, 7])  # the trajectory's own stream, independent of the noise
    if box is not PLANAR and name == "fourier":  # an n-joint trial ends at rest (its derivatives' filter has edges)
        return fourier(t, rng, fade_out=True, box=box)
    return {"tud01": tud01, "fourier": fourier, "mixed": mixed}[name](t, rng, box=box)


def from_file(path: Path, t: np.ndarray, n_joints: int = 2) -> Reference:
    """The trajectory in the CSV file `path` (t, q, dq, ddq of `n_joints` joints: `columns.kinematic_columns`; t from
    0, increasing; |q|, |dq|, |ddq| within `FILE_BOUNDS`) at times t [s]."""
    try:
        frame = pd.read_csv(path)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read the trajectory file ({exc})") from None
    columns = kinematic_columns(n_joints)
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise InputError(f"{path}: the trajectory file lacks column(s) {', '.join(missing)}")
    try:
        values = frame[list(columns)].to_numpy(dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{path}: the trajectory file's columns {', '.join(columns)} must hold numbers") from None
    if len(values) < 2 or not np.all(np.isfinite(values)) or np.any(np.diff(values[:, 0]) <= 0):
        raise InputError(f"{path}: the trajectory file needs finite values and increasing times t")
    for k, (signal, bound) in enumerate(zip(("q", "dq", "ddq"), FILE_BOUNDS)):
        block = np.abs(values[:, 1 + k * n_joints : 1 + (k + 1) * n_joints])
        if np.any(block > bound):
            row, j = np.unravel_index(int(np.argmax(block)), block.shape)
            raise InputError(
                f"{path}: column {signal}{j + 1}, data row {row + 1}: {values[row, 1 + k * n_joints + j]:g} is beyond "
                f"{bound:g} (no arm moves like that; a unit mistake?)"
            )
    tf = values[:, 0]
    if tf[0] > t[0] + 1e-9 or tf[-1] < t[-1] - 1e-9:
        raise InputError(
            f"{path}: the trajectory covers [{tf[0]:g}, {tf[-1]:g}] s, not the {t[-1] + (t[1] - t[0]):g} s asked for"
        )
    q, dq, ddq = (
        np.column_stack([np.interp(t, tf, values[:, 1 + k * n_joints + j]) for j in range(n_joints)]) for k in range(3)
    )
    return Reference(t, q, dq, ddq)


def _trapezoid(tau: np.ndarray, distance: float, vmax: float, amax: float) -> tuple[np.ndarray, ...]:
    """Rest-to-rest move of `distance` rad with a trapezoidal velocity profile, at local times `tau` ≥ 0.

    Returns (position, velocity, acceleration, duration); a triangle when the plateau is not reached.
    """
    d, s = abs(distance), np.sign(distance)
    ta = vmax / amax
    if d < vmax * ta:  # never reaches vmax: triangle
        ta = np.sqrt(d / amax)
        vmax = amax * ta
    tc = d / vmax - ta  # cruise time
    T = 2 * ta + tc
    tt = np.clip(tau, 0.0, T)
    x = np.where(
        tt < ta,
        0.5 * amax * tt**2,
        np.where(tt < ta + tc, 0.5 * amax * ta**2 + vmax * (tt - ta), d - 0.5 * amax * (T - tt) ** 2),
    )
    v = np.where(tt < ta, amax * tt, np.where(tt < ta + tc, vmax, amax * (T - tt)))
    a = np.where(tt < ta, amax, np.where(tt < ta + tc, 0.0, -amax))
    done = tau >= T
    v, a = np.where(done, 0.0, v), np.where(done, 0.0, a)
    return s * x, s * v, s * a, T


def tud01(t: np.ndarray, rng: np.random.Generator, home: np.ndarray | None = None, box: Box = PLANAR) -> Reference:
    """Point-to-point moves with rests (see the module docstring) within `box`; deterministic for the generator.
    `home` [rad]: start there and return there, at rest, by the end (else a random start, no return)."""
    n, m = len(t), box.n
    q, dq, ddq = np.zeros((n, m)), np.zeros((n, m)), np.zeros((n, m))
    pose = rng.uniform(box.q_min + box.margin, box.q_max - box.margin) if home is None else np.array(home, dtype=float)
    q[:] = pose
    duration = t[-1] if n else 0.0
    start = min(0.15 * duration, 12.0)  # the real trial starts with a long rest (15 s of 80)
    next_move = _next_move if box is PLANAR else _next_arm_move

    def move(j: int, target: float, at: float) -> float:
        if abs(target - pose[j]) <= 1e-9:  # already there
            return at
        after = t >= at
        x, v, a, T = _trapezoid(t[after] - at, target - pose[j], box.v_max[j], box.a_max[j])
        q[after, j] = pose[j] + x
        dq[after, j], ddq[after, j] = v, a
        pose[j] = target
        return at + T

    def lasting(j: int, distance: float) -> float:  # a move's duration [s] (0: no move)
        return _trapezoid(np.zeros(1), distance, box.v_max[j], box.a_max[j])[3] if abs(distance) > 1e-9 else 0.0

    while start < duration:
        moving, targets = next_move(rng, pose, box)
        ends = start + max(lasting(j, targets[j] - pose[j]) for j in range(m))
        if home is not None:  # the move, then the way home and a rest, must fit
            if ends + max(lasting(j, home[j] - targets[j]) for j in range(m)) + 0.5 > duration:
                break
        elif box is not PLANAR and ends + END_REST_S > duration:  # an n-joint trial ends at rest
            break
        end = start
        for j in range(m):
            if moving[j]:
                end = max(end, move(j, targets[j], start))
        start = end + rng.uniform(0.2, 2.0)
    if home is not None:
        at = min(start, duration - 0.5 - max(lasting(j, home[j] - pose[j]) for j in range(m)))
        for j in range(m):
            move(j, float(home[j]), at)
    return Reference(t, q, dq, ddq)


def _next_move(rng: np.random.Generator, pose: np.ndarray, box: Box = PLANAR) -> tuple[list[bool], np.ndarray]:
    """(which joints move, their targets [rad]): both joints, joint 1 only or joint 2 only, each by ≥ 0.3 rad."""
    kind = rng.choice(3, p=[0.6, 0.15, 0.25])
    moving = [kind in (0, 1), kind in (0, 2)]
    return moving, _targets(rng, pose, box, moving)


def _next_arm_move(rng: np.random.Generator, pose: np.ndarray, box: Box) -> tuple[list[bool], np.ndarray]:
    """(which joints move, their targets [rad]) of an n-joint arm: every joint (half the moves), one joint, or a
    random subset (a quarter each), each by at least `box.step`."""
    n = box.n
    kind = rng.choice(3, p=[0.5, 0.25, 0.25])
    if kind == 0:
        moving = [True] * n
    elif kind == 1:
        moving = [j == int(rng.integers(n)) for j in range(n)]
    else:
        moving = list(rng.random(n) < 0.5) or [True] * n
        if not any(moving):
            moving[int(rng.integers(n))] = True
    return moving, _targets(rng, pose, box, moving)


def _targets(rng: np.random.Generator, pose: np.ndarray, box: Box, moving: list[bool]) -> np.ndarray:
    """Targets [rad] drawn in the box for the `moving` joints, each at least `box.step` from where it is."""
    targets = pose.copy()
    for j in range(box.n):
        while moving[j] and abs(targets[j] - pose[j]) < box.step[j]:
            targets[j] = rng.uniform(box.q_min[j], box.q_max[j])
    return targets


def fourier(
    t: np.ndarray,
    rng: np.random.Generator,
    harmonics: int = 5,
    base_hz: float = 0.1,
    fade: float = 2.0,
    fade_out: bool = False,
    box: Box = PLANAR,
) -> Reference:
    """A Swevers-style Fourier excitation (5 harmonics of 0.1 Hz), faded in over `fade` s from rest at the
    centre pose (and, with `fade_out`, faded out to rest there over the last `fade` s).

    The scaling to the limits is that of the steady motion; the fade-in's ė·x term comes on top, so the speed
    can exceed `V_MAX` by up to about 26 % during the first `fade` s (13 % of 600 trials of 12–80 s did;
    kept, so that trials stay as published). With `fade_out` the whole motion is scaled back inside."""
    w = 2 * np.pi * base_hz
    l = np.arange(1, harmonics + 1)
    a, b = rng.normal(size=(2, box.n, harmonics)) / l  # decaying harmonics: smooth, mostly low frequency
    arg = np.outer(t, l * w)
    s, c = np.sin(arg), np.cos(arg)
    # Per joint: deviation x = Σ a/(lω) sin − b/(lω) cos, and its two derivatives.
    x = s @ (a / (l * w)).T - c @ (b / (l * w)).T
    v = c @ a.T + s @ b.T
    acc = -(s @ (a * l * w).T) + c @ (b * l * w).T
    x = x - x[:1]  # start at the centre pose
    # Scale each joint to the limits (position half-range with margin, speed, acceleration).
    half = 0.45 * (box.q_max - box.q_min)
    ratio = np.max(
        [np.abs(x).max(0) / half, np.abs(v).max(0) / (0.9 * box.v_max), np.abs(acc).max(0) / (0.6 * box.a_max)],
        axis=0,
    )
    x, v, acc = x / ratio, v / ratio, acc / ratio
    # Smooth fades from and to rest: the envelope g = e(τ_in) e(τ_out), e(τ) = 10τ³ − 15τ⁴ + 6τ⁵ (zero speed
    # and acceleration at both ends), and q = centre + g x differentiated by the product rule.
    fade_out = fade_out and len(t) > 0
    g, dg, ddg = _fade(t, fade)
    if fade_out:
        g2, dg2, ddg2 = _fade(t[-1] - t, fade)
        g, dg, ddg = g * g2, dg * g2 - g * dg2, ddg * g2 - 2 * dg * dg2 + g * ddg2
    dev = g * x
    dq = dg * x + g * v
    ddq = ddg * x + 2 * dg * v + g * acc
    if fade_out:  # the fade-out acts where x is large: scale back into the speed and acceleration limits
        again = np.maximum(
            np.max([np.abs(dq).max(0) / (0.9 * box.v_max), np.abs(ddq).max(0) / (0.6 * box.a_max)], axis=0), 1
        )
        dev, dq, ddq = dev / again, dq / again, ddq / again
    return Reference(t, 0.5 * (box.q_min + box.q_max) + dev, dq, ddq)


def _fade(tau: np.ndarray, fade: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """e(τ/fade) = 10u³ − 15u⁴ + 6u⁵ (u clipped to [0, 1]) and its first two derivatives in τ, as (N, 1)."""
    u = np.clip(tau / fade, 0.0, 1.0)[:, None]
    inside = u < 1
    e = 10 * u**3 - 15 * u**4 + 6 * u**5
    de = (30 * u**2 - 60 * u**3 + 30 * u**4) / fade * inside
    dde = (60 * u - 180 * u**2 + 120 * u**3) / fade**2 * inside
    return e, de, dde


def mixed(t: np.ndarray, rng: np.random.Generator, block: float = MIXED_BLOCK_S, box: Box = PLANAR) -> Reference:
    """`MIXED_BLOCK_S` blocks, point-to-point (`tud01`) and smooth (`fourier`) in turn, each from and to rest
    at the centre pose (see the module docstring)."""
    centre = 0.5 * (box.q_min + box.q_max)
    m = box.n
    q, dq, ddq = np.tile(centre, (len(t), 1)), np.zeros((len(t), m)), np.zeros((len(t), m))
    index = np.floor(t / block).astype(int)  # the block each sample falls in
    for k in np.unique(index):
        inside = index == k
        if inside.sum() > 1:
            local = t[inside] - k * block
            r = tud01(local, rng, home=centre, box=box) if k % 2 == 0 else fourier(local, rng, fade_out=True, box=box)
            q[inside], dq[inside], ddq[inside] = r.q, r.dq, r.ddq
    return Reference(t, q, dq, ddq)
