"""Ordinary (and joint-weighted) least squares from sufficient statistics.

`solve_ols` is π alone; `fit_ols` (from `ident_opt.fitting.fit`, re-exported here) adds standard errors
and diagnostics.
"""

from __future__ import annotations

import numpy as np

from ident_opt.fitting.fit import fit_ols
from ident_opt.fitting.stats import Stats

__all__ = ["fit_ols", "solve_ols"]


def solve_ols(stats: Stats, weights: np.ndarray | None = None) -> np.ndarray:
    """π̂ minimising Σ_j w_j Σ_k (τ_kj − Y_kj π)², from the statistics (least-norm if G is singular)."""
    G, b, _ = stats.combined(weights)
    return np.linalg.lstsq(G, b, rcond=None)[0]
