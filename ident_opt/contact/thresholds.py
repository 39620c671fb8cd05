"""When the observer's τ_ext is a contact: thresholds per joint calibrated on collision-free trials, a persistence
count, and the settling after a release.

Without contact τ_ext is not zero: it is the identified model's error. Where a joint moves that error is the
model's (inertia, Coriolis, the friction's curve); where it rests, the friction band (a resting joint holds any
torque within ± its Coulomb level, which the model reads as sign(dq) of a noisy dq). So each joint j gets two
thresholds [N m], chosen by its speed at each sample:

    θ_j(k) = θ_moving,j  if |dq_j(k)| > v_rest,j  else  θ_resting,j.

An excess is |τ_ext,j(k)| > θ_j(k) on some joint; an alarm starts at the `persistence`-th excess in a row (its
sample is the alarm's start) and ends after `persistence` samples in a row without one. After a release the drive
overshoots to the opposite sign and settles: for `settling` seconds after an alarm ends, an excess on a joint
whose sign is opposite to its peak during the alarm counts only beyond that peak's size (a push of the same sign,
a larger one, or one on another joint still does), and the learning stays off (`Detector.quiet`).

Calibration (`calibrate`) on collision-free residuals: v_rest,j is `REST_SHARE` of the joint's 95th-percentile
speed; θ is `margin` × the largest level the joint's |τ_ext| held for `persistence` samples in a row in that
regime (the sliding minimum's maximum): with margin 1 no calibration sample would raise an alarm.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

#: θ = MARGIN × the collision-free level (module doc).
MARGIN = 1.5
#: A sample is at rest when |dq_j| < REST_SHARE × the joint's 95th-percentile speed (at least MIN_REST_SPEED).
REST_SHARE = 0.05
MIN_REST_SPEED = 1e-3  # rad/s
#: The excess must last this long [s] before an alarm (at least two samples): `Thresholds.persistence`.
PERSISTENCE_S = 0.03
#: The settling after a release [s]: the drive's opposite-sign overshoot lasts 1–3 s on real arms.
SETTLING_S = 2.0
#: A threshold is at least this share of the joint's largest calibration torque (a noise-free simulation), and at
#: least MIN_THRESHOLD [N m] (a joint whose calibration torque is 0).
FLOOR_SHARE = 1e-3
MIN_THRESHOLD = 1e-6


@dataclass(frozen=True)
class Thresholds:
    """What decides an alarm, decided once (`calibrate`) and passed on: per joint the observer's gain [1/s], the
    thresholds moving and resting [N m] and the speed below which a joint rests [rad/s]; the persistence
    [samples], the settling after a release [s], and the sample step they were calibrated for [s]."""

    gain: tuple[float, ...]
    moving: tuple[float, ...]
    resting: tuple[float, ...]
    rest_speed: tuple[float, ...]
    persistence: int
    settling: float
    dt: float
    margin: float = MARGIN

    @property
    def n(self) -> int:
        return len(self.moving)

    @property
    def learning_lag(self) -> int:
        """Samples a stream waits before it learns from a sample [samples]: the persistence plus three of the
        observer's time constants (1/K), so that a push is alarmed before its onset would be learnt."""
        return self.persistence + math.ceil(3.0 / (min(self.gain) * self.dt))

    def limits(self, dq: np.ndarray) -> np.ndarray:
        """θ (N, n) [N m] at the joint speeds dq (N, n) [rad/s]: moving or resting per joint and sample."""
        at_rest = np.abs(np.atleast_2d(dq)) <= np.asarray(self.rest_speed)
        return np.where(at_rest, np.asarray(self.resting), np.asarray(self.moving))

    def as_json(self) -> list[dict]:
        """Per joint (1-based): its thresholds moving and resting [N m], rest speed [rad/s], gain [1/s]."""
        return [
            {
                "joint": j + 1,
                "moving": self.moving[j],
                "resting": self.resting[j],
                "rest_speed": self.rest_speed[j],
                "gain": self.gain[j],
            }
            for j in range(self.n)
        ]


def persistence_samples(dt: float) -> int:
    """The persistence [samples] at a sample step dt [s]: `PERSISTENCE_S`, at least 2."""
    return max(2, round(PERSISTENCE_S / dt))


def held_level(r: np.ndarray, persistence: int) -> np.ndarray:
    """(N, n): at each sample, the level |r| held over the last `persistence` samples (the sliding minimum); the
    first samples take the minimum over what came before."""
    a = np.abs(r)
    out = a.copy()
    if len(a) >= persistence:
        out[persistence - 1 :] = sliding_window_view(a, persistence, axis=0).min(axis=-1)
    for k in range(min(persistence - 1, len(a))):
        out[k] = a[: k + 1].min(axis=0)
    return out


def calibrate(
    residuals: Sequence[np.ndarray],
    speeds: Sequence[np.ndarray],
    torques: Sequence[np.ndarray],
    gain: np.ndarray,
    dt: float,
    margin: float = MARGIN,
) -> Thresholds:
    """`Thresholds` from collision-free trials: each one's τ_ext (N, n) [N m], dq (N, n) [rad/s] and τ (N, n) [N m];
    the observer's `gain` (n,) [1/s], the sample step dt [s] (module doc)."""
    dq_all = np.vstack([np.abs(v) for v in speeds])
    rest = np.maximum(MIN_REST_SPEED, REST_SHARE * np.quantile(dq_all, 0.95, axis=0))
    persistence = persistence_samples(dt)
    held = np.vstack([held_level(r, persistence) for r in residuals])
    at_rest = dq_all <= rest
    floor = np.maximum(MIN_THRESHOLD, FLOOR_SHARE * np.vstack([np.abs(t) for t in torques]).max(axis=0))
    moving, resting = (_level(held, mask, floor) for mask in (~at_rest, at_rest))
    moving = np.where(np.isnan(moving), resting, moving)
    resting = np.where(np.isnan(resting), moving, resting)
    moving, resting = (np.maximum(floor, np.nan_to_num(x, nan=0.0)) for x in (moving, resting))

    def floats(x) -> tuple[float, ...]:
        return tuple(float(v) for v in x)

    return Thresholds(
        gain=floats(gain),
        moving=floats(margin * moving),
        resting=floats(margin * resting),
        rest_speed=floats(rest),
        persistence=persistence,
        settling=SETTLING_S,
        dt=float(dt),
        margin=float(margin),
    )


def _level(held: np.ndarray, mask: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """Per joint, the largest held level among the samples of `mask` (NaN for a joint with none)."""
    out = np.full(held.shape[1], np.nan)
    for j in range(held.shape[1]):
        if mask[:, j].any():
            out[j] = max(float(held[mask[:, j], j].max()), float(floor[j]))
    return out
