"""The alarm as a state machine over samples (`Detector`), the same one offline (`alarms`), in the stream and in the
generated C (`contact.casadi_step`): the rules are `contact.thresholds`'s module doc.

State: `count` (excesses in a row while quiet), `below` (samples in a row without an excess while in alarm),
`alarm`, `hold` (settling left after a release [s]) and `peak` (n,): per joint, its τ_ext [N m] of largest size
while it exceeded during the last alarm (0: it did not). While settling, an excess of the sign opposite to the
joint's peak counts only beyond the peak's size: the overshoot of a release is never larger than the push.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ident_opt.contact.thresholds import Thresholds


@dataclass
class Detector:
    """One arm's alarm logic at `thresholds`, one sample at a time (`step`)."""

    thresholds: Thresholds
    count: int = 0
    below: int = 0
    alarm: bool = False
    hold: float = 0.0
    peak: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        if self.peak.size != self.thresholds.n:
            self.peak = np.zeros(self.thresholds.n)

    @property
    def quiet(self) -> bool:
        """Whether learning must stay off now: in alarm, or settling after one."""
        return self.alarm or self.hold > 0.0

    def excess(self, r: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """(n,) bool: joints whose |τ_ext| [N m] exceeds its threshold at speed dq [rad/s]; while settling, those of
        the sign opposite to their peak in the alarm only beyond the peak's size (module doc)."""
        over = np.abs(r) > self.thresholds.limits(dq)[0]
        if self.hold > 0.0:
            over &= (self.peak == 0.0) | (np.sign(r) == np.sign(self.peak)) | (np.abs(r) > np.abs(self.peak))
        return over

    def step(self, r: np.ndarray, dq: np.ndarray, dt: float) -> bool:
        """Take one sample's τ_ext (n,) [N m] and dq (n,) [rad/s], dt [s] after the previous one; the alarm after it."""
        over = self.excess(r, dq)
        persistence = self.thresholds.persistence
        if self.alarm:
            self.peak = np.where(over & (np.abs(r) > np.abs(self.peak)), r, self.peak)
            self.below = 0 if over.any() else self.below + 1
            if self.below >= persistence:
                self.alarm, self.below, self.hold = False, 0, self.thresholds.settling
            return self.alarm
        self.hold = max(0.0, self.hold - dt)
        self.count = self.count + 1 if over.any() else 0
        if self.count >= persistence:
            self.alarm, self.count, self.below = True, 0, 0
            self.peak = np.where(over, r, 0.0)
        return self.alarm


@dataclass(frozen=True)
class Alarm:
    """One alarm: its first and last sample's times [s] (the trial's own), the joint of the largest excess
    (1-based) and its τ_ext there [N m, signed]."""

    start: float
    end: float
    joint: int
    peak: float

    def as_json(self) -> dict:
        return {"start": self.start, "end": self.end, "joint": self.joint, "peak": self.peak}


def alarms(t: np.ndarray, r: np.ndarray, dq: np.ndarray, thresholds: Thresholds) -> tuple[np.ndarray, np.ndarray]:
    """(alarm, quiet), each (N,) bool, along a trial: t (N,) [s], τ_ext r and dq (N, n)."""
    detector = Detector(thresholds)
    alarm, quiet = np.zeros(len(t), bool), np.zeros(len(t), bool)
    dt = np.diff(np.asarray(t, dtype=float), prepend=float(t[0]) if len(t) else 0.0)
    for k in range(len(t)):
        alarm[k] = detector.step(r[k], dq[k], float(dt[k]))
        quiet[k] = detector.quiet
    return alarm, quiet


def spans(t: np.ndarray, r: np.ndarray, dq: np.ndarray, alarm: np.ndarray, thresholds: Thresholds) -> list[Alarm]:
    """The alarms of a trial: each run of `alarm` from its first to its last sample, with the joint whose |τ_ext|
    went furthest beyond its threshold (relative) and τ_ext there."""
    edges = np.diff(np.concatenate([[0], alarm.astype(int), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    ratio = np.abs(r) / thresholds.limits(dq)
    out = []
    for a, b in zip(starts, ends):
        k, j = np.unravel_index(np.argmax(ratio[a : b + 1]), ratio[a : b + 1].shape)
        out.append(Alarm(float(t[a]), float(t[b]), int(j) + 1, float(r[a + k, j])))
    return out


def per_minute(count: int, t: np.ndarray) -> float:
    """Alarms per minute over a trial's duration t[-1] − t[0] [s] (0 for a trial without duration)."""
    minutes = (float(t[-1]) - float(t[0])) / 60.0 if len(t) > 1 else 0.0
    return count / minutes if minutes > 0 else 0.0
