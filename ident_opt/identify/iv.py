"""Instrumental-variable identification (IDIM-IV): least squares without the errors-in-variables bias.

Accelerations are estimated by differentiating noisy encoders, so the regressor itself is noisy:
Y = Y₀ + E. Least squares then solves (Y₀ + E)ᵀ(Y₀ + E) π = (Y₀ + E)ᵀ τ and, because EᵀE does not
vanish, shrinks π toward zero (on the DFKI double pendulum at a 15 Hz cut-off: every inertial and gravity
parameter 60–70 % low). An instrument Z is a second regressor correlated with Y₀ but not with E; then

    π̂_IV = (Σ_j Z_jᵀ Y_j)⁻¹ Σ_j Z_jᵀ τ_j

is consistent (Gautier, Janot et al., the IDIM-IV family). Here Z is the same model's regressor evaluated
on an *independent derivative estimate*: the angles low-passed at `INSTRUMENT_RATIO` × the data's cut-off.
The noise that biases OLS lives in the upper part of the pass band (its power grows as f⁴), which the
instrument's filter removes, while the motion below is kept, so Z stays strongly correlated with Y₀.
With Z = Y the estimate is exactly OLS (a test checks it).

Everything is kept as statistics per joint, like `Stats`: A_j = Z_jᵀY_j, c_j = Z_jᵀτ_j, K_j = Z_jᵀZ_j.
Standard errors are the IV sandwich Cov = A⁻¹ (Σ_j σ_j² K_j) A⁻ᵀ, with σ_j² the residual variance of
joint j (from the ordinary statistics); like OLS's, they assume independent residuals.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ident_opt.arm.base import Arm
from ident_opt.data import Dataset
from ident_opt.derivatives import choose_cutoff, estimate_derivatives
from ident_opt.identify.fit import LinearFit, check_stats, finish
from ident_opt.identify.stats import Stats

#: The instruments' derivative cut-off as a fraction of the data's (measured on DFKI C.0: 0.5 keeps the
#: motion and removes most of the bias; see the module doc).
INSTRUMENT_RATIO = 0.5


@dataclass
class InstrumentStats:
    """Per joint: A = ZᵀY (J, P, P), c = Zᵀτ (J, P), K = ZᵀZ (J, P, P), with the ordinary `stats` (YᵀY, …)."""

    A: np.ndarray
    c: np.ndarray
    K: np.ndarray
    stats: Stats

    @classmethod
    def from_regressors(cls, Y: np.ndarray, Z: np.ndarray, tau: np.ndarray) -> InstrumentStats:
        """From the regressor Y (N, J, P), the instruments Z (N, J, P) and the torques τ (N, J) [N m]."""
        A = np.einsum("kjp,kjr->jpr", Z, Y)
        c = np.einsum("kjp,kj->jp", Z, tau)
        K = np.einsum("kjp,kjr->jpr", Z, Z)
        return cls(A, c, K, Stats.from_regressor(Y, tau))

    @classmethod
    def from_data(cls, arm: Arm, data: Dataset, ratio: float = INSTRUMENT_RATIO) -> InstrumentStats:
        """Y from the trial's q, dq, ddq; Z from the same angles differentiated at `ratio` × its cut-off
        (the trial's own, or for logged derivatives the one `derivatives.choose_cutoff` reads from its spectrum);
        τ filtered like the regressor's inputs (`Dataset.tau_fit`)."""
        cutoff = data.cutoff_hz if data.cutoff_hz is not None else choose_cutoff(data.t, data.q)
        dq_z, ddq_z, _ = estimate_derivatives(data.t, data.q, ratio * cutoff)
        Y = arm.regressor(data.q, data.dq, data.ddq)
        Z = arm.regressor(data.q, dq_z, ddq_z)
        return cls.from_regressors(Y, Z, data.tau_fit)

    def __add__(self, other: InstrumentStats) -> InstrumentStats:
        """The statistics of both trials together (derivatives never straddle two trials)."""
        return InstrumentStats(self.A + other.A, self.c + other.c, self.K + other.K, self.stats + other.stats)


def fit_iv(iv: InstrumentStats, arm: Arm) -> LinearFit:
    """π̂_IV from the instrument statistics, with IV standard errors (module doc); method "iv".

    The residual variances, the identifiability diagnostics and the consistency checks are those of
    `fit.finish` for this π; only the covariance differs (the IV sandwich).
    """
    check_stats(iv.stats, arm)
    t0 = time.perf_counter()
    A, c = iv.A.sum(axis=0), iv.c.sum(axis=0)
    pi = np.linalg.lstsq(A, c, rcond=None)[0]
    elapsed = time.perf_counter() - t0
    fit = finish(iv.stats, arm, pi, np.ones(arm.n_joints), "iv", solve_seconds=elapsed)
    A_inv = np.linalg.pinv(A)
    meat = sum(s2 * K for s2, K in zip(fit.sigma2, iv.K))
    fit.se = np.sqrt(np.clip(np.diag(A_inv @ meat @ A_inv.T), 0.0, None))
    return fit
