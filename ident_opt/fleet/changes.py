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
parameter has moved when, after the baseline, a window of L ≥ `RUN_DAYS` consecutive days all lie beyond `DAY_Z` on
one side and their mean deviation lies beyond `WINDOW_Z` times its standard error σ √(mean f_d² / L + 1/K): a
persistent shift adds up over days, while one day far out (a motion that excites the parameter badly) is scatter
until the next days agree. The last day of the first such window is the day the test raises it (with the days up to
then, as a daily run would). The figures draw the band μ ± `BAND_Z` σ f_d.

**Start and pattern.** The z-series of the moved parameters together are fitted by a change from day τ on, either a
step (z = a from τ) or a drift (z = a (day − τ + 1)), over τ after the baseline and not after the day the test
raised it. The
cause is judged on the days from the later of the two τ (so that no unchanged day dilutes its evidence); the change's
pattern is its cause's (a drift for wear, a step for a payload or a drive; for other, the one that fits best), and
`first_day` is that pattern's τ: the first day of the significant change.

**Cause.** From there on, the robot's statistics pooled (`tasks.evidence`, against the baseline model π0, each joint
weighted by its out-of-sample misfit): what a refit of every parameter (`full`) gains beyond what it gains on as many
unchanged days (the baseline's days, each predicted by the others: day-to-day scatter), and the share of it each
cause gains beyond its own such null — `wear` of joint j (its friction terms; named only if they grew), `payload` (a
body on the last link), `drive` of joint j (one factor on that joint's torque), and where the model has them a
joint's torque offset (named `other`, with its joint). The best cause is named when it explains at least `EXPLAINED`
of it; else `other`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats as st

#: The band drawn around a parameter's baseline mean, in scatter units (figures, series).
BAND_Z = 3.0
#: A parameter has moved when at least `RUN_DAYS` consecutive days lie beyond `DAY_Z` on one side and their mean
#: beyond `WINDOW_Z` standard errors of a mean of that many days (module doc).
RUN_DAYS, DAY_Z, WINDOW_Z = 3, 1.5, 5.0
#: A named cause must explain at least this share of what a refit of every parameter explains beyond scatter.
EXPLAINED = 0.8
#: Causes whose shares are within `TIE` of the best explain the change alike (a joint whose torque is mostly friction:
#: a higher gain on it looks like more friction); the first of them in `PREFERENCE` is named: a friction that rose
#: is the likelier event, then a payload, then a drive, then an offset.
TIE, PREFERENCE = 0.05, ("wear", "payload", "drive", "offset")
#: The causes, in the order of the contract (`docs/cli.md`), and the patterns of those that have one.
CAUSES = ("wear", "payload", "drive", "other")
PATTERNS = {"wear": "drift", "payload": "step", "drive": "step"}


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
    the lead parameter (the one furthest out on the latest day) then; plus the day the test first raised it, the
    share of the misfit the cause explains, the drive's torque factor and the lead parameter's relative change."""

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
    lead: str

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
            "lead": self.lead,
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
        deviation = (x - np.nanmean(x, axis=0)) / _inflation(r.se[:baseline_days], se_ref)
        variances.append(np.nanvar(deviation, axis=0, ddof=1) * dof / st.chi2.median(dof))
    pooled = np.nanmedian(variances, axis=0) if variances else np.zeros(Q)
    pooled = np.where(np.isfinite(pooled), pooled, 0.0)
    return Scatter(np.sqrt(np.maximum(pooled, se_ref**2)), se_ref)


def test(robot: Tested, fleet: Scatter, baseline_days: int) -> Test:
    """z of every fitted day of `robot` against its baseline, and the parameters that moved (module doc)."""
    K = baseline_days
    base = robot.values[:K]
    mean = np.nanmean(base, axis=0)
    own = np.nan_to_num(np.nanstd(base, axis=0, ddof=1)) if len(base) > 1 else np.zeros_like(mean)
    sigma = np.maximum(fleet.sigma, own)
    f = _inflation(robot.se, fleet.se_ref)
    spread = sigma * np.sqrt(f**2 + 1.0 / K)
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.where(spread > 0, (robot.values - mean) / spread, 0.0)
    out = Test(mean, sigma, z, BAND_Z * sigma * f)
    for q in range(z.shape[1]):
        deviation = robot.values[K:, q] - mean[q]
        alarm = first_alarm(z[K:, q], deviation, f[K:, q] ** 2, sigma[q], K)
        if alarm is not None:
            out.moved[q] = (K + alarm[0], alarm[1])
    return out


def first_alarm(z: np.ndarray, deviation: np.ndarray, f2: np.ndarray, sigma: float, K: int) -> tuple[int, int] | None:
    """(index, sign) of the first day on which the days so far end a window of at least `RUN_DAYS` consecutive
    days, each beyond ±`DAY_Z` on one side, whose mean deviation lies beyond `WINDOW_Z` of its own standard error,
    σ √(mean f² / L + 1/K) for L days (module doc): the day the test raises it; None when it never does."""
    first = None
    for sign in (1, -1):
        beyond = np.nan_to_num(sign * z) > DAY_Z
        d = 0
        while d < len(z) and (first is None or d + RUN_DAYS - 1 < first[0]):
            if not beyond[d]:
                d += 1
                continue
            end = d
            while end < len(z) and beyond[end]:
                end += 1
            hit = _window(sign * deviation[d:end], f2[d:end], sigma, K)
            if hit is not None:
                if first is None or d + hit < first[0]:
                    first = (d + hit, sign)
                break
            d = end
    return first


def _window(dev: np.ndarray, f2: np.ndarray, sigma: float, K: int) -> int | None:
    """Within a run of days beyond `DAY_Z`, the first day that ends a window of `RUN_DAYS` or more days whose mean
    deviation `dev` exceeds `WINDOW_Z` standard errors (None when no window does)."""
    total, spread = np.concatenate([[0.0], np.cumsum(dev)]), np.concatenate([[0.0], np.cumsum(f2)])
    for last in range(RUN_DAYS - 1, len(dev)):
        starts = np.arange(0, last - RUN_DAYS + 2)
        length = last + 1 - starts
        mean = (total[last + 1] - total[starts]) / length
        se = sigma * np.sqrt((spread[last + 1] - spread[starts]) / length**2 + 1.0 / K)
        if np.any(mean > WINDOW_Z * se):
            return last
    return None


def onsets(test: Test, day_numbers: np.ndarray, baseline_days: int, moved: list[int]) -> dict[str, tuple[int, float]]:
    """Per pattern ("step", "drift") the day index τ from which the moved parameters' z-series are best fitted by one
    change of that shape (module doc), between the first day after the baseline and the day the test raised the
    change, with the share of Σ z² it fits."""
    K = baseline_days
    z = np.nan_to_num(test.z[:, moved])
    last = min(test.moved[q][0] for q in moved)
    total = max(float(np.sum(z[K:] ** 2)), 1e-300)
    best = {"step": (K, -np.inf), "drift": (K, -np.inf)}
    for tau in range(K, last + 1):
        after = (day_numbers >= day_numbers[tau]).astype(float)
        for pattern, g in (("step", after), ("drift", after * (day_numbers - day_numbers[tau] + 1))):
            gain = float(np.sum((g @ z) ** 2) / (g @ g)) / total
            if gain > best[pattern][1] + 1e-12:
                best[pattern] = (tau, gain)
    return best


def pattern_of(cause: str, fits: dict[str, tuple[int, float]]) -> str:
    """A change's pattern: the one its cause has (`PATTERNS`), for `other` the one that fits best."""
    return PATTERNS.get(cause) or max(fits, key=lambda p: fits[p][1])


def name_cause(
    gains: dict[str, float], null: dict[str, float], growth: dict[str, float]
) -> tuple[str, int | None, float]:
    """(cause, joint, explained share) from pooled evidence (`tasks.Evidence`): of what a refit of every parameter
    gains beyond what it gains on unchanged days (`null`: scatter), the share each cause gains beyond its own null;
    the best is named when it explains at least `EXPLAINED` (wear only if the joint's friction grew; of causes within
    `TIE` of the best, the first in `PREFERENCE`; a joint's torque offset is `other`, of that joint), else `other`."""
    full = gains.get("full", 0.0) - null.get("full", 0.0)
    if full <= 0:
        return "other", None, 0.0
    shares = {k: (v - null.get(k, 0.0)) / full for k, v in gains.items() if k != "full"}
    shares = {k: v for k, v in shares.items() if not (k.startswith("wear:") and growth.get(k, 0.0) <= 0)}
    best = max(shares.values(), default=0.0)
    key = min((k for k, v in shares.items() if v >= best - TIE), key=lambda k: PREFERENCE.index(k.partition(":")[0]))
    share = float(min(max(shares[key], 0.0), 1.0))
    cause, _, joint = key.partition(":")
    if share < EXPLAINED:
        return "other", None, share
    if cause == "offset":
        return "other", int(joint), share
    return cause, int(joint) if joint else None, share
