"""The consistent online fit of the planar arm (CPBR): bounded least squares with the arm's exact mass LMIs as rotated
second-order cones (`_Cones`), re-solved warm after every sample (`WarmConsistentLS`): M(q) ≻ 0 for all q and the sign
bounds hold exactly after every update."""

from __future__ import annotations

import itertools

import numpy as np

# Plain LAPACK calls: a few µs each instead of numpy.linalg.solve's ~10 µs of wrapping (P is 9 here).
from scipy.linalg.lapack import dgesv as _dgesv

from ident_opt.arm.base import Arm
from ident_opt.consistency import MARGIN, MatrixInequality, mass_constraints
from ident_opt.fitting.bounded import Bounds, WarmBoundedLS
from ident_opt.fitting.constrained import solve_constrained
from ident_opt.fitting.stats import Stats


# ---------------------------------------------------------------------------------------------- CPBR
class _Cones:
    """The arm's 2×2 mass LMIs N_i(π) = Σ_p π_p B_ip ⪰ margin·I (two-link arm: i = 0 at cos q2 = +1, 1 at
    cos q2 = −1), each written as p_i ≥ 0, s_i ≥ 0, c_i(π) = p_i s_i − r_i² ≥ 0 with p = N11 − m,
    s = N22 − m, r = N12 affine in π (rows of GP, GS, GR, from `MatrixInequality.rotated_cone`): rotated
    second-order cones. All L cones are evaluated at once (vectorised). Larger LMIs are refused there."""

    def __init__(self, lmis: tuple[MatrixInequality, ...]):
        rows = [lmi.rotated_cone() for lmi in lmis]
        self.GP, self.GS, self.GR = (np.stack([r[i] for r in rows]) for i in range(3))  # (L, P) each
        self.margin = np.array([lmi.margin for lmi in lmis])  # (L,) [kg m²]
        # ∇²c_i = gp gsᵀ + gs gpᵀ − 2 gr grᵀ: constant, (L, P, P).
        self.hessian = (
            np.einsum("ip,iq->ipq", self.GP, self.GS)
            + np.einsum("ip,iq->ipq", self.GS, self.GP)
            - 2 * np.einsum("ip,iq->ipq", self.GR, self.GR)
        )
        self.n = len(lmis)

    def values(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(p, s, r, c) of every cone at x, each (L,)."""
        p, s, r = self.GP @ x - self.margin, self.GS @ x - self.margin, self.GR @ x
        return p, s, r, p * s - r * r

    def gradients(self, x: np.ndarray) -> np.ndarray:
        """∇c_i at x, (L, P)."""
        p, s, r, _ = self.values(x)
        return s[:, None] * self.GP + p[:, None] * self.GS - 2 * r[:, None] * self.GR

    def slacks(self, x: np.ndarray) -> np.ndarray:
        """λ_min(N_i(x)) − margin [kg m²] per cone: ≥ 0 feasible."""
        p, s, r, _ = self.values(x)
        return 0.5 * (p + s) - np.sqrt(0.25 * (p - s) ** 2 + r * r)


class WarmConsistentLS:
    """Physically consistent LS (CPBR) re-solved from statistics that change a little between calls.

        minimise ½πᵀHπ − hᵀπ  subject to  lower ≤ π ≤ upper,  every mass LMI of the arm ⪰ margin·I

    (two-link arm: M(q) = M0 + M1 cos q2 ⪰ margin·I for every q; the same problem as
    `constrained.fit_constrained`). The LMIs must be 2×2 (`MatrixInequality.rotated_cone`).
    Each call: (1) the box-only solution (`WarmBoundedLS`); if M is positive definite there it is the
    answer (the cone constraints are inactive). (2) Otherwise Newton's method on the KKT equations of
    the previous call's active set (box parameters fixed, active cones as equalities c(π) = 0),
    warm-started at the previous (π, μ) — typically 1–2 solves of a (P + 1)-sized system — then the KKT
    check: stationarity and c = 0 to 1e-13 relative, μ ≥ 0, the other constraints satisfied, box
    multipliers of the right sign; a failed check changes the active set by one constraint and repeats.
    (3) Only if that does not settle (a large change, or the first call), Clarabel (`fit_constrained`)
    finds the active set and Newton polishes its answer to the same exactness. `fallbacks` counts the
    calls that needed (3); `inexact` those where even the polish failed (Clarabel's answer is returned).
    """

    def __init__(self, model: Arm, bounds: Bounds, margin: float = MARGIN):
        self.model, self.bounds, self.margin = model, bounds, margin
        self.cones = _Cones(mass_constraints(model, margin))
        self.box = WarmBoundedLS(bounds)
        self.pi: np.ndarray | None = None
        self.state = np.zeros(model.n_params, dtype=np.int8)
        self.mu = np.zeros(self.cones.n)
        self.fallbacks = 0
        self.inexact = 0

    def cold(self) -> WarmConsistentLS:
        """A fresh solver with the same problem (for from-scratch reference solves)."""
        return WarmConsistentLS(self.model, self.bounds, self.margin)

    def solve(self, H: np.ndarray, h: np.ndarray) -> np.ndarray:
        """π̂ for the statistics (H, h); exact to the KKT check's tolerance."""
        x = self.box.solve(H, h)
        if np.all(self.cones.slacks(x) >= 0):
            self._accept(x, self.box.last.state, np.zeros(self.cones.n))
            return x
        if self.pi is not None and self.mu.any():
            result = self._active_set(H, h, self.pi, self.state, self.mu)
            if result is not None:
                return result
        self.fallbacks += 1
        return self._clarabel(H, h)

    def _accept(self, x: np.ndarray, state: np.ndarray, mu: np.ndarray) -> None:
        self.pi, self.state, self.mu = x.copy(), state.copy(), mu.copy()

    def _active_set(
        self, H: np.ndarray, h: np.ndarray, x: np.ndarray, state: np.ndarray, mu: np.ndarray, rounds: int = 8
    ) -> np.ndarray | None:
        """Newton on an active set, then one change of the set where the KKT check fails, a few times:
        the small active-set changes of consecutive online steps are handled without the conic solver."""
        state, mu = state.astype(np.int8).copy(), mu.astype(float).copy()
        for _ in range(rounds):
            out = self._newton(H, h, x, state, mu)
            if out is None:
                return None
            x, mu = out
            change = self._kkt_change(H, h, x, state, mu)
            if change is None:
                self._accept(x, state, mu)
                return x
            state, mu = change
        return None

    def _newton(
        self, H: np.ndarray, h: np.ndarray, x0: np.ndarray, state: np.ndarray, mu0: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Newton on the KKT equations of one active set (box `state`, cones with μ > 0):
        ∇f − Σ μ_i ∇c_i = 0 on the free parameters, c_i = 0; converged (x, μ) or None."""
        lo, hi = self.bounds.lower, self.bounds.upper
        x = x0.copy()
        x[state < 0], x[state > 0] = lo[state < 0], hi[state > 0]
        active = np.flatnonzero(mu0 > 0)
        m = mu0[active].copy()
        F = np.flatnonzero(state == 0)
        FF = np.ix_(F, F)
        nF, nA = F.size, active.size
        tol1 = 1e-13 * (np.abs(H[F]) @ np.maximum(np.abs(x), 1.0) + np.abs(h[F]))
        hess = self.cones.hessian[active].reshape(nA, -1)
        P = x.size
        kkt = np.zeros((nF + nA, nF + nA))
        for _ in range(30):
            p, s, r, c = self.cones.values(x)
            grads = (s[:, None] * self.cones.GP + p[:, None] * self.cones.GS - 2 * r[:, None] * self.cones.GR)[active]
            r1 = (H @ x - h - m @ grads)[F]
            r2 = c[active]
            cscale = (np.abs(p * s) + r * r)[active] + 1e-300
            if np.all(np.abs(r1) <= tol1) and np.all(np.abs(r2) <= 1e-13 * cscale):
                out = np.zeros(self.cones.n)
                out[active] = m
                return x, out
            K = H - (m @ hess).reshape(P, P) if nA else H
            A = grads[:, F]
            kkt[:nF, :nF], kkt[:nF, nF:], kkt[nF:, :nF] = K[FF], -A.T, A
            _, _, step, info = _dgesv(kkt, -np.concatenate([r1, r2]))
            if info != 0:  # singular KKT matrix: this active set cannot be solved here
                return None
            x[F] += step[:nF]
            m += step[nF:]
        return None

    def _kkt_change(
        self, H: np.ndarray, h: np.ndarray, x: np.ndarray, state: np.ndarray, mu: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """None when (x, μ) satisfies the KKT conditions; else the active set with its worst violation
        changed: a cone on the wrong branch of c = 0 (p or s ≤ 0) or with μ < 0 dropped, a violated
        bound or cone added, a wrong-signed box multiplier released."""
        lo, hi = self.bounds.lower, self.bounds.upper
        scale = np.abs(H) @ np.maximum(np.abs(x), 1.0) + np.abs(h)
        tol = 1e-10
        state, mu = state.copy(), mu.copy()
        p, s, r, _ = self.cones.values(x)
        wrong_branch = (mu > 0) & ((p <= 0) | (s <= 0))
        if wrong_branch.any():
            mu[int(np.argmax(wrong_branch))] = 0.0
            return state, mu
        if np.any(mu < -tol * np.max(scale)):
            mu[int(np.argmin(mu))] = 0.0
            return state, mu
        below, above = lo - x, x - hi
        size = np.maximum(np.where(np.isfinite(lo), np.abs(lo), 0.0), np.where(np.isfinite(hi), np.abs(hi), 0.0))
        worst = np.maximum(below, above) / np.maximum(size, 1.0)
        if np.max(worst) > tol:
            k = int(np.argmax(worst))
            state[k] = -1 if below[k] > above[k] else 1
            return state, mu
        slack = 0.5 * (p + s) - np.sqrt(0.25 * (p - s) ** 2 + r * r)
        violated = (mu == 0) & (slack < -1e-12 * np.maximum(np.maximum(np.abs(p), np.abs(s)), 1e-300))
        if violated.any():
            mu[int(np.argmax(violated))] = 1e-6 * np.max(scale)  # a small positive start; Newton finds it
            return state, mu
        g = H @ x - h - mu @ self.cones.gradients(x)  # the box multipliers at fixed parameters
        wrong = np.where(state < 0, -g, np.where(state > 0, g, -np.inf)) - tol * scale
        if np.max(wrong) > 0:
            state[int(np.argmax(wrong))] = 0
            return state, mu
        return None

    def _as_stats(self, H: np.ndarray, h: np.ndarray) -> Stats:
        """Statistics whose normal equations are (H, h) up to a common scale (which does not move the
        minimiser): all on the first joint, the others zero."""
        c = 1.0 / np.max(np.diag(H))
        J, P = self.model.n_joints, h.shape[0]
        G, b = np.zeros((J, P, P)), np.zeros((J, P))
        G[0], b[0] = H * c, h * c
        return Stats(G, b, np.zeros(J), 1)

    def _clarabel(self, H: np.ndarray, h: np.ndarray) -> np.ndarray:
        """The conic solver for a new active set, then Newton polishes its answer on the active set it
        shows (exact KKT); if no polish passes the check, the conic answer is returned (`inexact`)."""
        lo, hi = self.bounds.lower, self.bounds.upper
        x = solve_constrained(self._as_stats(H, h), self.model, margin=self.margin, friction=False, bounds=(lo, hi))
        near = 1e-7 * np.maximum(np.abs(x), 1.0)
        state = np.where(x - lo <= near, -1, np.where(hi - x <= near, 1, 0)).astype(np.int8)
        near_cone = self.cones.slacks(x) <= 1e-6 * max(1.0, np.max(np.abs(x)))
        F = state == 0
        grads = self.cones.gradients(x)
        # Which cones are active is not always clear from Clarabel's point (a slack of 1e-8 may be either):
        # try the likely active sets, the one it shows first; keep the first that passes the KKT check.
        subsets = sorted(
            (s for s in itertools.product((False, True), repeat=self.cones.n) if any(s)),
            key=lambda s: sum(a != b for a, b in zip(s, near_cone)),
        )
        for subset in subsets:
            on = np.array(subset)
            mu = np.zeros(self.cones.n)
            # Multipliers from stationarity on the free parameters (least squares): Newton's start.
            mu[on] = np.linalg.lstsq(grads[on][:, F].T, (H @ x - h)[F], rcond=None)[0]
            if np.any(mu[on] <= 0):
                continue
            result = self._active_set(H, h, x, state, mu)
            if result is not None:
                return result
        self.inexact += 1
        self._accept(x, state, np.zeros(self.cones.n))
        return x
