"""Scoring candidates on held-out data, and the rule that names a cause (or `none`).

Score (higher is better), for a candidate fitted against baseline b and evaluated on the n held-out samples:

    score = (n/2) Σ_j ln(MSE_b,j / MSE_cand,j)  −  (k/2) ln n

the held-out Gaussian log-likelihood gain over its own baseline (per joint variance) minus a BIC-style
penalty for its k added parameters (linear and nonlinear). Candidates are ranked by it. When a cause was
fitted against both nominal models, the version kept is the one with the better score against the
datasheet with every fitted parameter counted (the refit's π too), so a refit must earn its 10 parameters.
A cause is named only when the best score is
positive *and*, on some joint, the extension removes at least `MARGIN` (5 %) of the baseline's held-out
MSE and at least `MARGIN_VARIANCE` (0.01 %) of the measured torque's variance (an nMSE drop of 1e-4). The
log-likelihood alone counts correlated residual samples as independent and would accept tiny gains on long
trials; the two floors ask for a gain that matters relative to what the baseline gets wrong and is not
numerically nil. A candidate must also be *resolved* by its cause's own rule (`resolved`, `rules`: e.g. a
delay shorter than 2 ms is what sample-and-hold timing and filter mismatch produce on a perfect model, not a
cause).
"""

from __future__ import annotations

import numpy as np

from ident_opt.effects import CATALOGUE
from ident_opt.numerics import signals

#: Least fraction of the baseline's held-out MSE (on some joint) the named extension must remove.
MARGIN = 0.05
#: Least fraction of the measured torque's variance (on the same joint) it must remove: the planar engine's;
#: the n-joint engine's is its own (`chain.engine.ChainEngine.margin_variance`).
MARGIN_VARIANCE = 1e-4
#: Least share of a refitted π's log-gain a cause fitted with the datasheet's π must explain.
RECOVER = 0.8
#: Least share a datasheet-side cause must explain alone to be taken on trial, completed by a partner
#: to `RECOVER` in the next round (`diagnosis._rounds`).
PARTNER = 0.2


def mse(tau: np.ndarray, tau_hat: np.ndarray, rest: np.ndarray | None = None) -> np.ndarray:
    """Mean squared error per joint [N² m²]; with rest-stretch labels, each stretch's mean residual is
    removed first (`signals.demean_runs`: the torque stiction holds at rest is not scored)."""
    r = tau - tau_hat
    if rest is not None:
        r = signals.demean_runs(r, rest)
    return np.mean(r**2, axis=0)


def nmse(tau: np.ndarray, tau_hat: np.ndarray, rest: np.ndarray | None = None) -> list[float]:
    """`mse` ÷ variance of the measured torque, per joint."""
    return (mse(tau, tau_hat, rest) / np.var(tau, axis=0)).tolist()


def _log_ratios(before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """ln(before_j / after_j) per joint, 0 on a joint with nothing compared (both 0: the n-joint engine leaves out
    every held-out sample of a joint that never moves faster than its stick speed there, `ArmContext.labels`)."""
    before, after = np.asarray(before, dtype=float), np.asarray(after, dtype=float)
    empty = (before == 0) & (after == 0)
    return np.where(empty, 0.0, np.log(np.where(empty, 1.0, before) / np.where(empty, 1.0, after)))


def score(mse_before: np.ndarray, mse_after: np.ndarray, n: int, k: int) -> float:
    """Penalised held-out log-likelihood gain (see the module docstring)."""
    gain = 0.5 * n * float(np.sum(_log_ratios(mse_before, mse_after)))
    return gain - 0.5 * k * float(np.log(n))


def recovered(mse_base: np.ndarray, mse_cand: np.ndarray, mse_refit: np.ndarray) -> float:
    """Share of the refit's held-out log-gain over `mse_base` that the candidate achieves:
    Σ_j ln(MSE_base,j / MSE_cand,j) ÷ Σ_j ln(MSE_base,j / MSE_refit,j)."""
    whole = float(np.sum(_log_ratios(mse_base, mse_refit)))
    part = float(np.sum(_log_ratios(mse_base, mse_cand)))
    return part / whole if whole > 0 else float("inf")


def resolved(cause: str, estimate: dict, dt: float) -> bool:
    """Whether a fitted candidate describes an effect at all (its cause's `Effect.resolved`, `dt` [s])."""
    return CATALOGUE[cause].resolved(estimate, dt)


def rules() -> list[tuple[str, str]]:
    """The causes' resolution rules as (rule, reason), for the reports."""
    return [e.resolution for e in CATALOGUE.values() if e.resolution is not None]


def rules_note() -> str:
    """The resolution rules in parentheses, e.g. "(delays shorter than 2 ms are not named)"; "" when none."""
    found = [rule for rule, _ in rules()]
    return f"({'; '.join(found)})" if found else ""


def clears_margin(
    mse_before: np.ndarray,
    mse_after: np.ndarray,
    score_value: float,
    variance: np.ndarray,
    floor: float = MARGIN_VARIANCE,
) -> bool:
    """Whether a candidate beats its baseline clearly enough to be named (`variance`: of the measured
    held-out torque per joint [N² m²]; `floor`: the least share of it removed, the engine's)."""
    return shortfall(mse_before, mse_after, score_value, variance, True, None, floor) is None


def shortfall(
    mse_before: np.ndarray,
    mse_after: np.ndarray,
    score_value: float,
    variance: np.ndarray,
    resolved_: bool,
    share,
    floor: float = MARGIN_VARIANCE,
) -> str | None:
    """Why a candidate is not named, in words (None when it passes every rule): the first rule it fails of
    `resolved`, score > 0, `clears_margin`'s two floors, and `RECOVER` (`share`: the part of a refitted π's
    gain it explains, or None when that rule does not apply)."""
    before, after = np.asarray(mse_before), np.asarray(mse_after)
    enough = before - after >= MARGIN * before
    if not resolved_:
        return "its estimate fails its cause's own rule"
    if score_value <= 0:
        return f"its held-out gain does not pay for its parameters (score {score_value:.1f} <= 0)"
    if not np.any(enough):
        most = max(float(np.max((before - after) / np.maximum(before, 1e-300))), 0.0)
        return f"it removes at most {most:.1%} of the held-out MSE on any joint (margin {MARGIN:.0%})"
    if not np.any(enough & (before - after >= floor * np.asarray(variance))):
        return f"what it removes is below {100 * floor:g}% of the torque variance"
    if share is not None and share < RECOVER:
        return f"it explains {share:.0%} of what refitting π gains (at least {RECOVER:.0%} asked)"
    return None
