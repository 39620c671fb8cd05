"""Sufficient statistics of a linear-in-parameters torque model, kept per joint.

For joint j, G_j = Σ_k Y_kjᵀ Y_kj, b_j = Σ_k Y_kjᵀ τ_kj, s_j = Σ_k τ_kj², over samples k. Every estimator
that is linear in π (OLS, WLS, ridge, constrained QP, bounded LS) needs only these and n, so:
memory does not grow with the trial length; statistics of several trials simply add; and a new sample
is a rank-2 update (one row per joint), which makes online re-solves exact and constant-cost.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ident_opt.robot import ArmModel


@dataclass
class Stats:
    """Per-joint Gram matrices G (2, P, P), moments b (2, P), torque energy s (2,), sample count n."""

    G: np.ndarray
    b: np.ndarray
    s: np.ndarray
    n: int = 0

    @classmethod
    def zeros(cls, n_params: int) -> Stats:
        return cls(np.zeros((2, n_params, n_params)), np.zeros((2, n_params)), np.zeros(2), 0)

    @classmethod
    def from_regressor(cls, Y: np.ndarray, tau: np.ndarray) -> Stats:
        """From an already built regressor Y (N, 2, P) and torques τ (N, 2) [N m]."""
        G = np.einsum("kjp,kjr->jpr", Y, Y)
        b = np.einsum("kjp,kj->jp", Y, tau)
        return cls(G, b, np.einsum("kj,kj->j", tau, tau), Y.shape[0])

    @classmethod
    def from_data(
        cls, model: ArmModel, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, tau: np.ndarray, chunk: int = 65536
    ) -> Stats:
        """One pass over N samples in chunks: memory O(chunk · P), independent of N."""
        total = cls.zeros(model.n_params)
        for start in range(0, len(q), chunk):
            sl = slice(start, start + chunk)
            total += cls.from_regressor(model.regressor(q[sl], dq[sl], ddq[sl]), tau[sl])
        return total

    def __add__(self, other: Stats) -> Stats:
        return Stats(self.G + other.G, self.b + other.b, self.s + other.s, self.n + other.n)

    def add_sample(self, Y: np.ndarray, tau: np.ndarray) -> None:
        """In place: one new sample, Y (2, P) and τ (2,) — a rank-2 update of G."""
        self.G += Y[:, :, None] * Y[:, None, :]
        self.b += Y * tau[:, None]
        self.s += tau * tau
        self.n += 1

    def copy(self) -> Stats:
        return Stats(self.G.copy(), self.b.copy(), self.s.copy(), self.n)

    def combined(self, weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """(G, b, s) summed over joints, each joint weighted by `weights` (e.g. 1/σ_j² for WLS)."""
        w = np.ones(2) if weights is None else np.asarray(weights, dtype=float)
        return (np.tensordot(w, self.G, 1), np.tensordot(w, self.b, 1), float(w @ self.s))

    def rss(self, pi: np.ndarray) -> np.ndarray:
        """Residual sum of squares per joint, Σ_k (τ_kj − Y_kj π)², from the statistics alone [N² m²]."""
        pi = np.asarray(pi, dtype=float)
        return self.s - 2 * self.b @ pi + np.einsum("p,jpr,r->j", pi, self.G, pi)
