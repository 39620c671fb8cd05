"""The generalized-momentum observer (De Luca and Mattone 2003; Haddadin et al. 2017): an estimate of the external
torque τ_ext per joint from q, dq and the drive torque τ, no acceleration.

With p = M(q) dq and ṗ = τ + τ_ext − β(q, dq) (`contact.dynamics`), the observer's residual

    r(t) = K_O (p(t) − p(0) − ∫₀ᵗ (τ − β + r) ds),     K_O = diag(K_1 … K_n) [1/s],

obeys ṙ = K_O (τ_ext − r): r is τ_ext through a first-order low-pass of time constant 1/K_j on each joint. The
discrete form used here (and in the generated C, `contact.casadi_step`) is exact for that filter: with the
torque that moved the momentum over a sample step Δt_k, the trapezoid of τ − β,

    m_k = (p_k − p_{k−1} − Δt_k (u_{k−1} + u_k) / 2) / Δt_k,     u = τ − β,
    r_k = r_{k−1} + γ_k (m_k − r_{k−1}),                         γ_k = 1 − exp(−K Δt_k),   r_0 = 0,

which is r = K_O (p − p(0) − ∫(u + r)) sampled, stable for every K and every step. The gain's default is
`DEFAULT_GAIN` (a 20 ms time constant), at most half the sample rate (in 1/s) so that the filter spans at least
two samples (`default_gain`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ident_opt.contact.dynamics import Momentum

#: K_O [1/s]: the observer's bandwidth; 1/K_O = 20 ms is its time constant (a push of 0.1–1 s rises within it).
DEFAULT_GAIN = 50.0


def default_gain(rate_hz: float, n: int) -> np.ndarray:
    """K_O per joint [1/s] for samples at `rate_hz` [Hz]: `DEFAULT_GAIN`, at most rate_hz / 2."""
    return np.full(n, min(DEFAULT_GAIN, 0.5 * float(rate_hz)))


def step_torque(p: np.ndarray, u: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """m (N, n) [N m]: the torque that moved the momentum p (N, n) over each step beyond u = τ − β (N, n), by the
    trapezoid; dt (N − 1,) [s]. m_0 = 0 (no step before the first sample)."""
    m = np.zeros_like(p)
    m[1:] = (p[1:] - p[:-1] - 0.5 * dt[:, None] * (u[:-1] + u[1:])) / dt[:, None]
    return m


def residual(t: np.ndarray, p: np.ndarray, u: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """r (N, n) [N m], the observer's estimate of τ_ext at each sample (module doc): p (N, n) [N m s] the momentum,
    u = τ − β (N, n) [N m], t (N,) [s], gain K_O (n,) [1/s]."""
    dt = np.diff(np.asarray(t, dtype=float))
    m = step_torque(p, u, dt)
    gamma = np.zeros_like(p)
    gamma[1:] = 1.0 - np.exp(-np.outer(dt, gain))
    r = np.zeros_like(p)
    for k in range(1, len(p)):
        r[k] = r[k - 1] + gamma[k] * (m[k] - r[k - 1])
    return r


def residual_step(
    r: np.ndarray, p_prev: np.ndarray, u_prev: np.ndarray, p: np.ndarray, u: np.ndarray, dt: float, gain: np.ndarray
) -> np.ndarray:
    """r_k (n,) [N m] from r_{k−1}, the previous and the new momentum p [N m s] and u = τ − β [N m], dt [s]: one
    step of `residual` (the stream's and the generated C's form)."""
    m = (p - p_prev - 0.5 * dt * (u_prev + u)) / dt
    return r + (1.0 - np.exp(-gain * dt)) * (m - r)


@dataclass(frozen=True)
class MomentumObserver:
    """The observer of an identified arm: its `momentum` (p, β at the fitted π) and its `gain` K_O (n,) [1/s]."""

    momentum: Momentum
    gain: np.ndarray

    def run(self, t: np.ndarray, q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """τ_ext (N, n) [N m] along a trial: t (N,) [s], q, dq, τ (N, n) [rad, rad/s, N m]."""
        p, beta = self.momentum.of(q, dq)
        return residual(t, p, np.asarray(tau, dtype=float) - beta, np.asarray(self.gain, dtype=float))
