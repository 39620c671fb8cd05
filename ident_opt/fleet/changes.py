"""Changes, named: per robot a baseline (its first K days), a test per identifiable parameter that tells a change from
day-to-day scatter, the day it started, and its likely cause.

**Scatter.** A parameter's daily value scatters for reasons that are not a change (temperature, a different motion
each day); its standard error alone understates that (it assumes white residuals and one fixed motion). Robots of
one model scatter alike, so the scatter σ_q of each tested parameter q is pooled over the fleet: the median over
robots of the variance of their baseline days (each day's deviation divided by its inflation, below), corrected to
an unbiased scale (÷ the χ² median over its degrees of freedom), never below the robot's own baseline variance nor
below the parameter's typical squared standard error. A day whose standard error is larger than the parameter's
typical one (a motion that excites it less) scatters more: its inflation f_d = max(1, se_d / se_ref), se_ref the
median standard error of the fleet's baseline days.

**Test.** z_d = (x_d − μ) / (σ √(f_d² + 1/K)), μ the robot's baseline mean (the 1/K: μ is itself uncertain). A
parameter has moved when `RUN_DAYS` consecutive days after the baseline all lie beyond `BAND_Z` on the same side
(the band drawn in the figures is μ ± `BAND_Z` σ f_d). One day far out is scatter until the next days agree.

**Start and pattern.** The z-series of the moved parameters together are fitted by a change from day τ on, either a
step (z = a from τ) or a drift (z = a (day − τ + 1)), over τ after the baseline and not after the first alarm; the
pair with the smallest residual gives `first_day` (the first day of the significant change) and `pattern`.

**Cause.** From τ on, the robot's statistics pooled (`tasks.evidence`, against the baseline model π0): how much of
what a refit of every parameter gains (`full`) each named cause gains with its few directions — `wear` of joint j
(its friction terms; named only if they grew), `payload` (a body on the last link), `drive` of joint j (one factor
on that joint's torque). The best cause is named when it explains at least `EXPLAINED` of it; else `other`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats as st

#: A day lies outside the baseline's band when |z| exceeds this ...
BAND_Z = 3.0
#: ... and a parameter has moved when this many consecutive days do, on the same side.
RUN_DAYS = 3
#: A named cause must explain at least this share of what a refit of every parameter explains.
EXPLAINED = 0.8
#: The causes, in the order of the contract (`docs/cli.md`), and their patterns.
CAUSES = ("wear", "payload", "drive", "other")


@dataclass
class Tested:
    """One robot's tested parameters: its fitted days (ISO dates) and their calendar day numbers, values (D, Q) and
    standard errors (D, Q) of the Q tested parameters."""

    robot: str
    days: list[str]
    day_numbers: np.ndarray
    values: np.ndarray
    se: np.ndarray


@dataclass
class Scatter:
    """The fleet's day-to-day scatter σ (Q,) of each tested parameter and its reference standard error (Q,)."""

    sigma: np.ndarray
    se_ref: np.ndarray


@dataclass
class Test:
    """One robot's test: baseline mean μ (Q,), the scatter σ (Q,) it used, z (D, Q), the band's half-width (D, Q)
    and the moved parameters {index: (first alarm day index, sign)}."""

    mean: np.ndarray
    sigma: np.ndarray
    z: np.ndarray
    band: np.ndarray
    moved: dict[int, tuple[int, int]] = field(default_factory=dict)


@dataclass
class Change:
    """A change of one robot (the contract's `changes[]`): cause, joint (1-based, None for a payload or other),
    the parameters it concerns, the first day it is significant, its pattern, baseline and latest values, z of
    the lead parameter on the latest day; plus the day the test first raised it, the share of the misfit the cause
    explains, the drive's torque factor and the lead parameter's relative change."""

    robot: str
    cause: str
    joint: int | None
    parameters: list[str]
    first_day: str
    pattern: str
    baseline: dict[str, float]
    latest: dict[str, float]
    z: float
    detected: str
    explained: float
    scale: float | None
    size: float

    def as_dict(self) -> dict:
        """The JSON object (`docs/cli.md`, fleet)."""
        return {
            "robot": self.robot,
            "cause": self.cause,
            "joint": self.joint,
            "parameters": self.parameters,
            "first_day": self.first_day,
            "pattern": self.pattern,
            "baseline": self.baseline,
            "latest": self.latest,
            "z": self.z,
            "detected_day": self.detected,
            "explained": self.explained,
            "scale": self.scale,
            "size": self.size,
        }


def _inflation(se: np.ndarray, se_ref: np.ndarray) -> np.ndarray:
    """f = max(1, se / se_ref), 1 where either is missing."""
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(np.isfinite(se) & (se_ref > 0), se / se_ref, 1.0)
    return np.maximum(f, 1.0)


def scatter(robots: list[Tested], baseline_days: int) -> Scatter:
    """The fleet's pooled scatter of each tested parameter (module doc), from each robot's first `baseline_days`."""
    Q = robots[0].values.shape[1]
    se_base = [r.se[:baseline_days] for r in robots]
    se_ref = np.nanmedian(np.concatenate(se_base), axis=0) if se_base else np.full(Q, np.nan)
    se_ref = np.where(np.isfinite(se_ref), se_ref, 0.0)
    variances = []
    for r in robots:
        x = r.values[:baseline_days]
        if len(x) < 2:
            continue
        dof = len(x) - 1
        deviation = (x - x.mean(axis=0)) / _inflation(r.se[:baseline_days], se_ref)
        variances.append(deviation.var(axis=0, ddof=1) * dof / st.chi2.median(dof))
    pooled = np.median(variances, axis=0) if variances else np.zeros(Q)
    return Scatter(np.sqrt(np.maximum(pooled, se_ref**2)), se_ref)


def test(robot: Tested, fleet: Scatter, baseline_days: int) -> Test:
    """z of every fitted day of `robot` against its baseline, and the parameters that moved (module doc)."""
    K = baseline_days
    base = robot.values[:K]
    mean = base.mean(axis=0)
    own = base.std(axis=0, ddof=1) if len(base) > 1 else np.zeros_like(mean)
    sigma = np.maximum(fleet.sigma, own)
    f = _inflation(robot.se, fleet.se_ref)
    spread = sigma * np.sqrt(f**2 + 1.0 / K)
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.where(spread > 0, (robot.values - mean) / spread, 0.0)
    out = Test(mean, sigma, z, BAND_Z * sigma * f)
    for q in range(z.shape[1]):
        alarm = _first_run(z[K:, q])
        if alarm is not None:
            out.moved[q] = (K + alarm[0], alarm[1])
    return out


def _first_run(z: np.ndarray) -> tuple[int, int] | None:
    """(index, sign) of the first day that starts `RUN_DAYS` consecutive days beyond ±`BAND_Z` on one side."""
    first = None
    for sign in (1, -1):
        count = 0
        for d, beyond in enumerate(sign * z > BAND_Z):
            count = count + 1 if beyond else 0
            if count == RUN_DAYS:
                if first is None or d - RUN_DAYS + 1 < first[0]:
                    first = (d - RUN_DAYS + 1, sign)
                break
    return first


def onset(test: Test, day_numbers: np.ndarray, baseline_days: int, moved: list[int]) -> tuple[int, str]:
    """(τ, pattern): the day index from which the moved parameters' z-series are best fitted by one step or one
    drift (module doc), between the first day after the baseline and the first alarm."""
    K = baseline_days
    z = test.z[:, moved]
    last = min(test.moved[q][0] for q in moved)
    best = (-np.inf, K, "step")
    for tau in range(K, last + 1):
        for pattern in ("step", "drift"):
            g = (day_numbers >= day_numbers[tau]).astype(float)
            if pattern == "drift":
                g = g * (day_numbers - day_numbers[tau] + 1)
            gain = float(np.sum((g @ z) ** 2) / (g @ g))
            if gain > best[0] + 1e-12:
                best = (gain, tau, pattern)
    return best[1], best[2]


def name_cause(reductions: dict[str, float], growth: dict[str, float]) -> tuple[str, int | None, float]:
    """(cause, joint, explained share) from pooled evidence (`tasks.Evidence`): the named cause that explains most
    of what a refit of every parameter gains, if at least `EXPLAINED` of it (wear only if the friction grew)."""
    full = reductions.get("full", 0.0)
    if full <= 0:
        return "other", None, 0.0
    shares = {key: value / full for key, value in reductions.items() if key != "full"}
    key = max(shares, key=shares.get)
    share = float(min(shares[key], 1.0))
    cause, _, joint = key.partition(":")
    if share < EXPLAINED or (cause == "wear" and growth.get(key, 0.0) <= 0):
        return "other", None, share
    return cause, int(joint) if joint else None, share
