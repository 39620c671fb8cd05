"""Error metrics per joint, on arrays (N, n) of N samples and n joints. Two normalisations of the MSE, both
reported and clearly named:

- ``nmse``: MSE ÷ variance of the measured torque (the usual definition; 1 = no better than a constant),
- ``nmse_range``: MSE ÷ (max − min)² of the measured torque — the paper's definition, which is what makes
  its nMSE table reproducible.
"""

from __future__ import annotations

import numpy as np

#: The held-out metrics every study reports, per joint (the keys of `all_metrics`).
METRICS = ("rmse", "nmse", "nmse_range")


def rmse(tau: np.ndarray, tau_hat: np.ndarray) -> np.ndarray:
    """Root-mean-square error per joint [N m]; inputs (N, n), output (n,)."""
    return np.sqrt(np.mean((tau - tau_hat) ** 2, axis=0))


def nmse(tau: np.ndarray, tau_hat: np.ndarray) -> np.ndarray:
    """MSE ÷ variance of the measured torque, per joint."""
    return np.mean((tau - tau_hat) ** 2, axis=0) / np.var(tau, axis=0)


def nmse_range(tau: np.ndarray, tau_hat: np.ndarray) -> np.ndarray:
    """MSE ÷ (max − min)² of the measured torque, per joint (the paper's nMSE)."""
    return np.mean((tau - tau_hat) ** 2, axis=0) / np.ptp(tau, axis=0) ** 2


def coverage(tau: np.ndarray, mean: np.ndarray, std: np.ndarray, level: float = 0.95) -> np.ndarray:
    """Fraction of samples whose measured torque lies in the central `level` predictive interval (per joint)."""
    from scipy.stats import norm  # deferred: scipy.stats takes over a second to import; only this needs it

    z = norm.ppf(0.5 + level / 2)
    return np.mean(np.abs(tau - mean) <= z * std, axis=0)


def all_metrics(tau: np.ndarray, tau_hat: np.ndarray) -> dict[str, list[float]]:
    """{"rmse": [joint 1, …, joint n], "nmse": [...], "nmse_range": [...]} as plain floats."""
    return {
        name: [float(v) for v in fn(tau, tau_hat)]
        for name, fn in (("rmse", rmse), ("nmse", nmse), ("nmse_range", nmse_range))
    }
