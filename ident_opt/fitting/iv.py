"""Instrumental-variable identification (IDIM-IV): least squares without the errors-in-variables bias.

Accelerations are estimated by differentiating noisy encoders, so the regressor itself is noisy:
Y = Y₀ + E. Least squares then solves (Y₀ + E)ᵀ(Y₀ + E) π = (Y₀ + E)ᵀ τ and, because EᵀE does not
vanish, shrinks π toward zero (on the DFKI double pendulum at a 15 Hz cut-off: every inertial and gravity
parameter 60–70 % low). An instrument Z is a second regressor correlated with Y₀ but not with E; then

    π̂_IV = (Σ_j Z_jᵀ Y_j)⁻¹ Σ_j Z_jᵀ τ_j

is consistent (Gautier, Janot et al., the IDIM-IV family). Here Z is the same model's regressor evaluated
on an *independent derivative estimate*: the angles low-passed at `derivatives.INSTRUMENT_RATIO` × the data's
cut-off (`Dataset.instruments`). The noise that biases OLS lives in the upper part of the pass band (its power
grows as f⁴), which the instrument's filter removes, while the motion below is kept, so Z stays strongly
correlated with Y₀. With Z = Y the estimate is exactly OLS (a test checks it).

Everything is kept as statistics per joint, like `Stats`: A_j = Z_jᵀY_j, c_j = Z_jᵀτ_j, K_j = Z_jᵀZ_j.
Standard errors are the IV sandwich Cov = A⁻¹ (Σ_j σ_j² K_j) A⁻ᵀ, with σ_j² the residual variance of
joint j (from the ordinary statistics); like OLS's, they assume independent residuals.

**Any estimator on instruments** (`InstrumentStats.two_stage`): two-stage least squares projects each joint's
torque equation onto its instruments, Σ_j ‖P_Zj (τ_j − Y_j π)‖², which is a quadratic in π with the statistics
G_j = A_jᵀK_j⁺A_j, b_j = A_jᵀK_j⁺c_j. Any estimator that works from statistics (the constrained and consistent
fits included) run on these is an instrumental-variable estimator: without constraints it is the 2SLS estimate
(each joint's own instruments), with them the consistent fit nearest to it in the IV metric. Its standard errors
come out as the 2SLS sandwich, because the residuals it is given are those of the measured torques.

**What IV keeps of bias** (`probe_trials`): instruments filtered from the same angles still share some of the
regressor's noise, and the low-pass that makes the regressor smooth distorts the dynamics it passes. Neither is
noise that averages out, so the 2SLS errors do not cover them. Statistics built with `probes` carry the same trials
read with the instruments, and with all the derivatives, at half their cut-off; the robust fit (`estimators`) adds
what each read moves it by to its standard errors.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from ident_opt.arm.base import Arm
from ident_opt.data.dataset import Dataset, refiltered
from ident_opt.fitting.fit import LinearFit, check_stats, finish
from ident_opt.fitting.stats import Stats
from ident_opt.numerics.derivatives import choose_cutoff, instrument_derivatives

#: Directions of the instruments' Gram matrix below this fraction of its largest eigenvalue are not instruments.
TWO_STAGE_RCOND = 1e-12
#: The bias probes read a trial again at this factor × its instruments' cut-off, and × its own cut-off
#: (`probe_trials`).
PROBE_FACTOR = 0.5


@dataclass
class InstrumentStats:
    """Per joint: A = ZᵀY (J, P, P), c = Zᵀτ (J, P), K = ZᵀZ (J, P, P), with the ordinary `stats` (YᵀY, …)."""

    A: np.ndarray
    c: np.ndarray
    K: np.ndarray
    stats: Stats
    #: The same trials' statistics read the ways of `probe_trials`, by name (empty: no probe was asked for).
    probes: dict[str, InstrumentStats] = field(default_factory=dict)

    @classmethod
    def from_regressors(cls, Y: np.ndarray, Z: np.ndarray, tau: np.ndarray) -> InstrumentStats:
        """From the regressor Y (N, J, P), the instruments Z (N, J, P) and the torques τ (N, J) [N m]."""
        A = np.einsum("kjp,kjr->jpr", Z, Y)
        c = np.einsum("kjp,kj->jp", Z, tau)
        K = np.einsum("kjp,kjr->jpr", Z, Z)
        return cls(A, c, K, Stats.from_regressor(Y, tau))

    @classmethod
    def from_data(cls, arm: Arm, data: Dataset) -> InstrumentStats:
        """Y from the trial's q, dq, ddq; Z from its instruments' kinematics (`Dataset.instruments`, else the
        angles differentiated at `derivatives.INSTRUMENT_RATIO` × its cut-off, or × the one
        `derivatives.choose_cutoff` reads for logged derivatives); τ filtered like the regressor's inputs
        (`Dataset.tau_fit`)."""
        dq_z, ddq_z = instrument_kinematics(data)
        Y = arm.regressor(data.q, data.dq, data.ddq)
        Z = arm.regressor(data.q, dq_z, ddq_z)
        return cls.from_regressors(Y, Z, data.tau_fit)

    @classmethod
    def zeros(cls, n_params: int, n_joints: int) -> InstrumentStats:
        """Empty statistics for P = `n_params` parameters and `n_joints` joints."""
        J, P = n_joints, n_params
        return cls(np.zeros((J, P, P)), np.zeros((J, P)), np.zeros((J, P, P)), Stats.zeros(P, J))

    def two_stage(self) -> TwoStageStats:
        """The two-stage statistics (module doc): what any estimator from statistics needs to be an IV one."""
        G, b, s = [], [], []
        for A, c, K in zip(self.A, self.c, self.K):
            # K⁺ = U diag(1/λ) Uᵀ over the directions the instruments span: with W = diag(λ^-½) Uᵀ, G = (WA)ᵀ(WA)
            # is a Gram matrix by construction (positive semi-definite whatever the rounding), b = (WA)ᵀ(Wc).
            lam, U = np.linalg.eigh(0.5 * (K + K.T))
            keep = lam > TWO_STAGE_RCOND * max(lam.max(), 0.0)
            W = U[:, keep].T / np.sqrt(lam[keep])[:, None]
            WA, Wc = W @ A, W @ c
            G.append(WA.T @ WA)
            b.append(WA.T @ Wc)
            s.append(float(Wc @ Wc))
        return TwoStageStats(
            np.array(G), np.array(b), np.array(s), self.stats.n, self.stats.effective, measured=self.stats
        )

    def __add__(self, other: InstrumentStats) -> InstrumentStats:
        """The statistics of both trials together (derivatives never straddle two trials); a probe survives when
        both sides have it (or one side holds no sample yet)."""
        if self.stats.n == 0 or other.stats.n == 0:
            probes = self.probes or other.probes
        else:
            probes = {k: self.probes[k] + other.probes[k] for k in self.probes.keys() & other.probes.keys()}
        return InstrumentStats(self.A + other.A, self.c + other.c, self.K + other.K, self.stats + other.stats, probes)


def probe_trials(data: Dataset) -> dict[str, Dataset]:
    """Trial `data` read again two ways an unbiased instrumental-variable fit does not care about (`PROBE_FACTOR`):
    "instruments", its instruments at half their cut-off (noise shared by instruments and regressor moves the fit);
    "cutoff", its regressor and instruments at half its derivative cut-off (the filter's distortion of the dynamics
    moves it; only for derivatives estimated here). What the estimate moves by bounds its bias (`estimators`,
    "robust"). Whole trials only: derivatives are estimated again along the samples."""
    cutoff = data.cutoff_hz if data.cutoff_hz is not None else choose_cutoff(data.t, data.q)
    out = {"instruments": replace(data, instruments=instrument_derivatives(data.t, data.q, PROBE_FACTOR * cutoff))}
    if data.cutoff_hz is not None:
        out["cutoff"] = refiltered(data, PROBE_FACTOR * data.cutoff_hz)
    return out


def instrument_kinematics(data: Dataset, cutoff_hz: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(dq, ddq) of the instruments of trial `data` [rad/s, rad/s²]: its own (`Dataset.instruments`), else its
    angles differentiated at `derivatives.INSTRUMENT_RATIO` × `cutoff_hz` (default: its derivatives' cut-off, or
    the one `derivatives.choose_cutoff` reads for logged derivatives)."""
    if data.instruments is not None:
        return data.instruments
    cutoff = cutoff_hz or (data.cutoff_hz if data.cutoff_hz is not None else choose_cutoff(data.t, data.q))
    return instrument_derivatives(data.t, data.q, cutoff)


@dataclass
class TwoStageStats(Stats):
    """Statistics G, b, s of the projected torque equations (`InstrumentStats.two_stage`) whose residuals
    (`rss`) are those of the measured torques (`measured`): residual variances and standard errors come out as
    the 2SLS ones."""

    measured: Stats | None = None

    def rss(self, pi: np.ndarray) -> np.ndarray:
        """Residual sum of squares per joint of the measured torques, Σ_k (τ_kj − Y_kj π)² [N² m²]."""
        return self.measured.rss(pi)


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
    n, effective = iv.stats.n, iv.stats.effective
    inflation = max(1.0, n / effective if effective else 1.0)  # correlated residuals (`Stats.effective`)
    fit.se = np.sqrt(np.clip(np.diag(A_inv @ meat @ A_inv.T) * inflation, 0.0, None))
    return fit
