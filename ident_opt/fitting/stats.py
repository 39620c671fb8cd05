"""Sufficient statistics of a linear-in-parameters torque model, kept per joint.

For joint j, G_j = Σ_k Y_kjᵀ Y_kj, b_j = Σ_k Y_kjᵀ τ_kj, s_j = Σ_k τ_kj², over samples k. Every estimator
that is linear in π (OLS, WLS, ridge, constrained QP, bounded LS) needs only these and n, so:
memory does not grow with the trial length; statistics of several trials simply add; and a new sample
is a rank-J update for J joints (one row each), which makes online re-solves exact and constant-cost.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ident_opt.arm.base import Arm


@dataclass
class Stats:
    """Per-joint Gram matrices G (J, P, P), moments b (J, P), torque energy s (J,) and sample count n, for
    J = the arm's `n_joints` joints."""

    G: np.ndarray
    b: np.ndarray
    s: np.ndarray
    n: int = 0
    #: How many of the n residuals are independent (None: all). Torques low-passed at a cut-off f_c (parallel
    #: filtering) leave residuals correlated over about 1/(2 f_c): a trial sampled at f_s then carries about
    #: n · 2 f_c / f_s independent ones, and standard errors grow by √(n / effective) (`fitting.fit.finish`).
    effective: float | None = None

    @classmethod
    def zeros(cls, n_params: int, n_joints: int = 2) -> Stats:
        """Empty statistics for P = `n_params` parameters and `n_joints` joints (default: the two-link arm's)."""
        return cls(np.zeros((n_joints, n_params, n_params)), np.zeros((n_joints, n_params)), np.zeros(n_joints), 0)

    @property
    def n_joints(self) -> int:
        """The number of joints (rows of Y per sample) the statistics are kept for."""
        return self.G.shape[0]

    @classmethod
    def from_regressor(cls, Y: np.ndarray, tau: np.ndarray) -> Stats:
        """From an already built regressor Y (N, J, P) and torques τ (N, J) [N m]."""
        G = np.einsum("kjp,kjr->jpr", Y, Y)
        b = np.einsum("kjp,kj->jp", Y, tau)
        return cls(G, b, np.einsum("kj,kj->j", tau, tau), Y.shape[0])

    @classmethod
    def from_data(
        cls, model: Arm, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, tau: np.ndarray, chunk: int = 65536
    ) -> Stats:
        """One pass over N samples (q, dq, ddq, τ each (N, J)) in chunks: memory O(chunk · P), independent of N."""
        total = cls.zeros(model.n_params, model.n_joints)
        for start in range(0, len(q), chunk):
            sl = slice(start, start + chunk)
            total += cls.from_regressor(model.regressor(q[sl], dq[sl], ddq[sl]), tau[sl])
        return total

    def __add__(self, other: Stats) -> Stats:
        """The statistics of both sample sets together."""
        effective = None
        if self.effective is not None or other.effective is not None:
            effective = (self.n if self.effective is None else self.effective) + (
                other.n if other.effective is None else other.effective
            )
        return Stats(self.G + other.G, self.b + other.b, self.s + other.s, self.n + other.n, effective)

    def add_sample(self, Y: np.ndarray, tau: np.ndarray) -> None:
        """In place: one new sample, Y (J, P) and τ (J,) — a rank-J update of G."""
        self.G += Y[:, :, None] * Y[:, None, :]
        self.b += Y * tau[:, None]
        self.s += tau * tau
        self.n += 1

    def copy(self) -> Stats:
        """An independent copy."""
        return Stats(self.G.copy(), self.b.copy(), self.s.copy(), self.n, self.effective)

    def combined(self, weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """(G, b, s) summed over joints, each joint weighted by `weights` (e.g. 1/σ_j² for WLS)."""
        w = np.ones(self.n_joints) if weights is None else np.asarray(weights, dtype=float)
        return (np.tensordot(w, self.G, 1), np.tensordot(w, self.b, 1), float(w @ self.s))

    def rss(self, pi: np.ndarray) -> np.ndarray:
        """Residual sum of squares per joint, Σ_k (τ_kj − Y_kj π)², from the statistics alone [N² m²]."""
        pi = np.asarray(pi, dtype=float)
        return self.s - 2 * self.b @ pi + np.einsum("p,jpr,r->j", pi, self.G, pi)
