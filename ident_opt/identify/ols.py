"""Ordinary (and joint-weighted) least squares from sufficient statistics."""

from __future__ import annotations

import numpy as np

from ident_opt.identify.stats import Stats


def solve_ols(stats: Stats, weights: np.ndarray | None = None) -> np.ndarray:
    """π̂ minimising Σ_j w_j Σ_k (τ_kj − Y_kj π)², from the statistics (least-norm if G is singular)."""
    G, b, _ = stats.combined(weights)
    return np.linalg.lstsq(G, b, rcond=None)[0]


def fit_ols(stats: Stats, model, weights=None):
    """OLS/WLS with standard errors and diagnostics: see `ident_opt.identify.fit.fit_ols`."""
    from ident_opt.identify.fit import fit_ols as _fit_ols

    return _fit_ols(stats, model, weights)
