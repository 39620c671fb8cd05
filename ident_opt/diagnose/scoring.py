"""Scoring candidates on held-out data, and the rule that names a cause (or `none`).

Score (higher is better), for a candidate fitted against baseline b and evaluated on the n held-out samples:

    score = (n/2) Σ_j ln(MSE_b,j / MSE_cand,j)  −  (k/2) ln n

the held-out Gaussian log-likelihood gain over its own baseline (per joint variance) minus a BIC-style
penalty for its k added parameters (linear and nonlinear). A cause is named only when the best score is
positive *and* the extension removes at least `MARGIN` (5 %) of the baseline's held-out MSE on some joint:
the log-likelihood alone counts correlated residual samples as independent and would accept tiny gains on
long trials; 5 % of the MSE is a practical-significance floor that noise fitting does not reach.
"""

from __future__ import annotations

import numpy as np

#: Least fraction of the baseline's held-out MSE (on some joint) the named extension must remove.
MARGIN = 0.05


def mse(tau: np.ndarray, tau_hat: np.ndarray) -> np.ndarray:
    """Mean squared error per joint [N² m²]."""
    return np.mean((tau - tau_hat) ** 2, axis=0)


def score(mse_before: np.ndarray, mse_after: np.ndarray, n: int, k: int) -> float:
    """Penalised held-out log-likelihood gain (see the module docstring)."""
    gain = 0.5 * n * float(np.sum(np.log(np.asarray(mse_before) / np.asarray(mse_after))))
    return gain - 0.5 * k * float(np.log(n))


def clears_margin(mse_before: np.ndarray, mse_after: np.ndarray, score_value: float) -> bool:
    """Whether a candidate beats its baseline clearly enough to be named."""
    reduction = 1.0 - np.asarray(mse_after) / np.asarray(mse_before)
    return bool(score_value > 0 and np.max(reduction) >= MARGIN)
