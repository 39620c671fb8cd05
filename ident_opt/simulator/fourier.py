"""Periodic excitation trajectories: a finite Fourier series per joint with an offset (Swevers et al. 1997).

For joint j, harmonics l = 1..H of the base frequency ω_f = 2π f_f [rad/s]:

    q_j(t)   = q0_j + Σ_l ( a_jl sin(l ω_f t) − b_jl cos(l ω_f t) ) / (l ω_f)         [rad]
    dq_j(t)  = Σ_l a_jl cos(l ω_f t) + b_jl sin(l ω_f t)                               [rad/s]
    ddq_j(t) = Σ_l l ω_f ( −a_jl sin(l ω_f t) + b_jl cos(l ω_f t) )                    [rad/s²]

The coefficients are stacked joint by joint, x = [q0_1, a_11..a_1H, b_11..b_1H, q0_2, ...] (n (2H+1),); a
and b are in rad/s. The trajectory is periodic with period 1/f_f, and it starts (and so ends, after whole
periods) at rest exactly when Σ_l a_jl = 0 and Σ_l l b_jl = 0 for every joint (`rest_matrix`).
Every quantity is linear in x, so q, dq, ddq on a time grid are basis matrices times x (`basis`), which
NumPy and CasADi use alike.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Fourier:
    """A finite Fourier series per joint: `n_joints`, `harmonics` H, base frequency `base_hz` f_f [Hz]."""

    n_joints: int
    harmonics: int
    base_hz: float

    @property
    def per_joint(self) -> int:
        """Coefficients per joint: the offset, H sine and H cosine terms."""
        return 2 * self.harmonics + 1

    @property
    def size(self) -> int:
        """Length of the coefficient vector x."""
        return self.n_joints * self.per_joint

    @property
    def period(self) -> float:
        """The period 1/f_f [s]."""
        return 1.0 / self.base_hz

    def basis(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Bq, Bv, Ba), each (N, 2H+1): q_j(t) = Bq @ x_j, dq_j = Bv @ x_j, ddq_j = Ba @ x_j at times t [s]."""
        t = np.asarray(t, dtype=float)
        w = 2 * np.pi * self.base_hz
        lw = np.arange(1, self.harmonics + 1) * w
        s, c = np.sin(np.outer(t, lw)), np.cos(np.outer(t, lw))
        one, zero = np.ones((len(t), 1)), np.zeros((len(t), 1))
        Bq = np.hstack([one, s / lw, -c / lw])
        Bv = np.hstack([zero, c, s])
        Ba = np.hstack([zero, -s * lw, c * lw])
        return Bq, Bv, Ba

    def joint_slice(self, j: int) -> slice:
        """Where joint j's coefficients sit in x."""
        return slice(j * self.per_joint, (j + 1) * self.per_joint)

    def evaluate(
        self, x: np.ndarray, t: np.ndarray | None, basis: tuple[np.ndarray, ...] | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q, dq, ddq (N, n) [rad, rad/s, rad/s²] of coefficients x at times t [s] (or at those of `basis`, the
        `basis` of some times computed once)."""
        x = np.asarray(x, dtype=float)
        B = self.basis(t) if basis is None else basis
        return tuple(np.column_stack([b @ x[self.joint_slice(j)] for j in range(self.n_joints)]) for b in B)

    def rest_matrix(self) -> np.ndarray:
        """A (2n, size): A x = 0 ⇔ every joint has dq(0) = 0 and ddq(0) = 0 (at rest at the start and the end)."""
        H, A = self.harmonics, np.zeros((2 * self.n_joints, self.size))
        for j in range(self.n_joints):
            k = j * self.per_joint
            A[2 * j, k + 1 : k + 1 + H] = 1.0  # Σ a_l = 0
            A[2 * j + 1, k + 1 + H : k + 1 + 2 * H] = np.arange(1, H + 1)  # Σ l b_l = 0
        return A

    def to_rest(self, x: np.ndarray) -> np.ndarray:
        """x projected onto the rest constraints (offsets untouched): the nearest coefficients at rest at t = 0."""
        A = self.rest_matrix()
        x = np.asarray(x, dtype=float)
        return x - A.T @ np.linalg.solve(A @ A.T, A @ x)

    def random(self, rng: np.random.Generator, centre: np.ndarray) -> np.ndarray:
        """Random coefficients at rest at t = 0 around offsets `centre` (n,) [rad]: a, b ~ N(0, 1)/l [rad/s]
        (decaying harmonics), not yet scaled to any limit."""
        x = np.zeros(self.size)
        decay = 1.0 / np.arange(1, self.harmonics + 1)
        for j in range(self.n_joints):
            sl = self.joint_slice(j)
            x[sl] = np.concatenate(
                [[centre[j]], rng.normal(size=self.harmonics) * decay, rng.normal(size=self.harmonics) * decay]
            )
        return self.to_rest(x)

    def scaled(self, x: np.ndarray, factor: float | np.ndarray) -> np.ndarray:
        """x with every joint's harmonics multiplied by `factor` (scalar or (n,)), the offsets kept."""
        x = np.array(x, dtype=float)
        factor = np.broadcast_to(np.asarray(factor, dtype=float), (self.n_joints,))
        for j in range(self.n_joints):
            sl = self.joint_slice(j)
            x[sl.start + 1 : sl.stop] *= factor[j]
        return x


def default_base_hz(duration: float, nominal_hz: float = 0.1) -> float:
    """A base frequency near `nominal_hz` [Hz] with a whole number of periods in `duration` [s]."""
    return max(1, round(duration * nominal_hz)) / duration
