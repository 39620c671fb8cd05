"""Box-bounded least squares on the sufficient statistics, by a warm-started primal active-set method.

    minimise    ½ πᵀ H π − hᵀ π           (H = Σ_j w_j G_j, h = Σ_j w_j b_j: the statistics, no data)
    subject to  lower ≤ π ≤ upper

Why our own solver: online, the statistics change by a rank-2 term per sample, so the optimal active set
almost never changes between two steps. Started from the previous solution and active set, the method
below does one P×P (or smaller) linear solve, checks the bounds and the multipliers' signs (the KKT
conditions) and stops: O(P³) per sample, whatever the number of samples seen. A QP solver that cannot
warm-start (Clarabel) or the paper's re-solve over all stacked data (`scipy.optimize.lsq_linear`) costs
far more and grows with N.

The answer is exact, not approximate: at termination the free parameters solve the normal equations
restricted to the free set, every bound holds, and every fixed parameter's multiplier has the sign that
makes the point optimal (g_p = (Hπ − h)_p ≥ 0 at a lower bound, ≤ 0 at an upper bound). For H ≻ 0 this
point is unique, so a warm start changes the work done, never the answer.

Bounds (`default_bounds`, from the parameters' declared kinds through `consistency.physical_bounds`; the
paper's "bounded least squares" does not say which it used):

| kind (two-link examples)            | bound | why                                                          |
|-------------------------------------|-------|--------------------------------------------------------------|
| inertia, armature (a1, a3, ia2)     | ≥ 0   | inertia sums: a1 = I1 + m1 lc1² + m2 l1² + a3, a3 = I2 + m2 lc2², N² J |
| friction (fv*, fc*, fs*)            | ≥ 0   | friction dissipates: it never pushes the joint along its motion |
| coupling, gravity (a2, b1, b2, b*s) | free  | m2 l1 lc2 and g·(m lc) change sign with the centre of mass's side |

`default_bounds(model, signs_from=π_datasheet)` also fixes the sign of the coupling and gravity parameters
to the datasheet's (a stronger, robot-specific prior: the centre of mass lies on the datasheet's side of
the joint). Box bounds alone do not make M(q) positive definite (a3 = 0 with a2 ≠ 0 is still indefinite):
that is what the physically constrained fit (CPBR, `WarmConsistentLS`) is for; its mass-matrix cones are
the arm's declared 2×2 LMIs (`Arm.mass_lmis`).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

# Plain LAPACK calls: a few µs each instead of numpy.linalg.solve's ~10 µs of wrapping (P is 9 here).
from scipy.linalg.lapack import dgesv as _dgesv
from scipy.linalg.lapack import dposv as _dposv

from ident_opt.arm.base import Arm
from ident_opt.consistency import MARGIN, MatrixInequality, mass_constraints, physical_bounds
from ident_opt.fitting.constrained import solve_constrained
from ident_opt.fitting.stats import Stats

#: Multipliers and bound violations below this, relative to the scale of the gradient, count as zero.
KKT_TOL = 1e-11


@dataclass(frozen=True)
class Bounds:
    """lower ≤ π ≤ upper, per parameter in the model's order (±inf for none); units those of π."""

    lower: np.ndarray
    upper: np.ndarray

    def __post_init__(self):
        if self.lower.shape != self.upper.shape or np.any(self.lower > self.upper):
            raise ValueError("bounds need lower ≤ upper, with equal shapes")


def default_bounds(model: Arm, signs_from: np.ndarray | None = None) -> Bounds:
    """The documented physical bounds (module doc) for `model`, from its parameters' kinds; with
    `signs_from` (e.g. the datasheet π), coupling and gravity parameters are also kept on the side of zero
    where that vector has them."""
    return Bounds(*physical_bounds(model.parameters, signs_from))


@dataclass
class BoundedSolution:
    """π, its active set (`state`: −1 at the lower bound, +1 at the upper, 0 free), the iterations
    the active-set loop took and the KKT residual (0 for an exact optimum, relative units)."""

    pi: np.ndarray
    state: np.ndarray
    iterations: int
    kkt: float = field(default=0.0)


def kkt_residual(H: np.ndarray, h: np.ndarray, pi: np.ndarray, bounds: Bounds, state: np.ndarray) -> float:
    """The largest violation of the optimality conditions at (π, active set), relative to |H||π| + |h|:
    bound violations, stationarity of the free parameters, wrong-signed multipliers of fixed ones."""
    g = H @ pi - h
    scale = np.abs(H) @ np.abs(pi) + np.abs(h) + 1e-300
    free = state == 0
    bound_violation = np.maximum(bounds.lower - pi, 0.0) + np.maximum(pi - bounds.upper, 0.0)
    wrong_sign = np.where(state < 0, np.maximum(-g, 0.0), np.where(state > 0, np.maximum(g, 0.0), 0.0))
    stationarity = np.where(free, np.abs(g), 0.0)
    return float(np.max((bound_violation * np.abs(np.diag(H)) + wrong_sign + stationarity) / scale))


def solve_bounded(
    H: np.ndarray,
    h: np.ndarray,
    bounds: Bounds,
    start: np.ndarray | None = None,
    state: np.ndarray | None = None,
    max_iter: int | None = None,
) -> BoundedSolution:
    """The minimiser of ½πᵀHπ − hᵀπ on the box (H ≻ 0), from a warm start (`start`, `state` = a
    previous solution and active set; cold start: all free at the projection of 0).

    Primal active set: keep a feasible point; solve the normal equations on the free set; if that
    leaves the box, step to the first bound met and fix it; else release the fixed parameter whose
    multiplier has the wrong sign the most, or stop when none has (KKT conditions hold).
    """

    def target(free: np.ndarray, x: np.ndarray) -> np.ndarray:
        if free.all():
            return np.linalg.solve(H, h)
        F, X = np.flatnonzero(free), np.flatnonzero(~free)
        return np.linalg.solve(H[np.ix_(F, F)], h[F] - H[np.ix_(F, X)] @ x[X]) if F.size else np.empty(0)

    def scale(x: np.ndarray) -> np.ndarray:
        return np.abs(H) @ np.maximum(np.abs(x), 1.0) + np.abs(h)

    return _active_set(bounds, h.shape[0], target, lambda x: H @ x - h, scale, start, state, max_iter)


def _active_set(bounds: Bounds, P: int, target, gradient, scale, start, state, max_iter) -> BoundedSolution:
    """The primal active-set loop of `solve_bounded` and `FactorBoundedLS`, on their own linear algebra: `target`
    (free mask, x) → the minimiser over the free parameters with the others at x; `gradient` x → Hx − h; `scale` x →
    the gradient's natural size per parameter (its "zero" is `KKT_TOL` of it)."""
    lo, hi = bounds.lower, bounds.upper
    state = np.zeros(P, dtype=np.int8) if state is None else state.astype(np.int8).copy()
    x = np.clip(np.zeros(P) if start is None else start, lo, hi)
    state[(state < 0) & ~np.isfinite(lo)] = 0
    state[(state > 0) & ~np.isfinite(hi)] = 0
    x[state < 0], x[state > 0] = lo[state < 0], hi[state > 0]
    # Scale for "zero" multipliers: the gradient's natural size at this problem.
    tol = KKT_TOL * scale(x)
    max_iter = max_iter or 10 * P + 10
    for iteration in range(1, max_iter + 1):
        free = state == 0
        goal = target(free, x)
        xf = x[free]
        if np.all(goal >= lo[free]) and np.all(goal <= hi[free]):
            x[free] = goal
            g = gradient(x)
            # Fixed at lower: optimal only if moving up does not help (g ≥ 0); at upper: g ≤ 0.
            wrong = np.where(state < 0, -g, np.where(state > 0, g, -np.inf)) - tol
            j = int(np.argmax(wrong))
            if wrong[j] <= 0:
                return BoundedSolution(x, state, iteration)
            state[j] = 0
            continue
        # Ratio test: the largest step toward the goal that stays in the box; fix the bound it meets.
        d = goal - xf
        with np.errstate(divide="ignore", invalid="ignore"):
            steps = np.where(d < 0, (lo[free] - xf) / d, np.where(d > 0, (hi[free] - xf) / d, np.inf))
        k = int(np.argmin(steps))
        alpha = max(0.0, min(1.0, float(steps[k])))
        x[free] = xf + alpha * d
        p = int(np.flatnonzero(free)[k])
        state[p] = -1 if d[k] < 0 else 1
        x[p] = lo[p] if d[k] < 0 else hi[p]
        np.clip(x, lo, hi, out=x)
    raise RuntimeError(f"bounded least squares: no convergence in {max_iter} active-set iterations")


class FactorBoundedLS:
    """Box-bounded least squares kept as a square-root information factor: H = RᵀR, h = Rᵀz with R upper triangular
    (P, P), folded from the regressor rows by orthogonal transformations, never formed as YᵀY. Its solution is that
    of `solve_bounded` on the same data, accurate to ~κ(Y)·ε where the normal equations give ~κ(Y)²·ε: what an arm
    identified through many base parameters (an ill-conditioned Y, κ(Y)² ~ 1e7 to 1e12 on real trials) needs for the
    generated update (`adaptation.c_update.generate_pi_update`, the same factor) and this path to agree to 1e-9.

    `add(D, τ)` folds one sample (D (n, P), τ (n,)) by a QR of [[R z]; [D τ]] and re-solves from the previous
    solution and active set (`_active_set`; the free parameters by least squares on R's free columns, the gradient
    Rᵀ(Rπ − z)); all or nothing. "Zero" multipliers are measured as the generated code does: against
    √H_pp Σ_k √H_kk max(|π_k|, 1) + |h_p| (Cauchy–Schwarz on |H| max(|π|, 1)), so h and diag H are kept too."""

    def __init__(self, bounds: Bounds, D: np.ndarray, tau: np.ndarray):
        A, b = D.reshape(-1, D.shape[-1]), tau.reshape(-1)
        self.bounds = bounds
        self.R, self.z = self._factor(np.zeros((0, A.shape[1])), np.zeros(0), A, b)
        self.h, self.hdiag = A.T @ b, np.einsum("kp,kp->p", A, A)
        self.last: BoundedSolution | None = None
        self.iterations = 0

    @staticmethod
    def _factor(R: np.ndarray, z: np.ndarray, A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(R, z) of the rows [R z] and [A b] stacked, with a non-negative diagonal."""
        P = A.shape[1]
        top = np.vstack([np.column_stack([R, z]), np.column_stack([A, b])])
        F = scipy.linalg.qr(top, mode="r", check_finite=False)[0][:P]
        sign = np.where(np.diag(F) < 0, -1.0, 1.0)
        F = F * sign[:, None]
        return np.triu(F[:, :P]), F[:, P].copy()

    def solve(self, R: np.ndarray | None = None, z: np.ndarray | None = None, h=None, hdiag=None) -> BoundedSolution:
        """The bounded solution on the factor (R, z) with h, diag H (default: the current ones), warm-started from
        the last."""
        R, z = (self.R if R is None else R), (self.z if z is None else z)
        h, roots = (self.h if h is None else h), np.sqrt(self.hdiag if hdiag is None else hdiag)

        def target(free: np.ndarray, x: np.ndarray) -> np.ndarray:
            F, X = np.flatnonzero(free), np.flatnonzero(~free)
            if not F.size:
                return np.empty(0)
            if not X.size:
                return scipy.linalg.solve_triangular(R, z, check_finite=False)
            Q, T = np.linalg.qr(R[:, F])
            return scipy.linalg.solve_triangular(T, Q.T @ (z - R[:, X] @ x[X]), check_finite=False)

        def scale(x: np.ndarray) -> np.ndarray:
            return roots * float(roots @ np.maximum(np.abs(x), 1.0)) + np.abs(h)

        last = self.last
        start, state = (None, None) if last is None else (last.pi, last.state)
        return _active_set(self.bounds, R.shape[0], target, lambda x: R.T @ (R @ x - z), scale, start, state, None)

    def _folded(self, D: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, ...]:
        """(R, z, h, diag H) with the rows D (…, P) and torques τ (…) folded in (nothing committed)."""
        A, b = D.reshape(-1, D.shape[-1]), tau.reshape(-1)
        R, z = self._factor(self.R, self.z, A, b)
        return R, z, self.h + A.T @ b, self.hdiag + np.einsum("kp,kp->p", A, A)

    def fold(self, D: np.ndarray, tau: np.ndarray) -> None:
        """Fold rows in without re-solving (many samples at once: D (N, n, P), τ (N, n))."""
        self.R, self.z, self.h, self.hdiag = self._folded(D, tau)

    def add(self, D: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Fold one sample (D (n, P), τ (n,)) in and re-solve; the new π. Nothing changes when it raises."""
        R, z, h, hdiag = self._folded(D, tau)
        sol = self.solve(R, z, h, hdiag)
        if not np.isfinite(sol.pi).all():
            raise FloatingPointError("the re-solve gave a non-finite θ; the sample was not folded in")
        self.R, self.z, self.h, self.hdiag, self.last = R, z, h, hdiag, sol
        self.iterations += sol.iterations
        return sol.pi.copy()


class WarmBoundedLS:
    """Box-bounded LS re-solved from statistics that change a little between calls: each call starts
    from the previous solution and active set (`solve_bounded`), so a step costs one small linear solve
    when the active set does not change.

    Fast path (the common case online): with the previous active set, solve the free parameters' normal
    equations, check the bounds and the fixed parameters' multiplier signs, and stop — the same test
    `solve_bounded` ends with, done with the index sets of that active set cached. Anything else goes to
    `solve_bounded` from the previous solution.
    """

    def __init__(self, bounds: Bounds):
        self.bounds = bounds
        self.last: BoundedSolution | None = None
        self.iterations = 0  # total active-set iterations so far (1 per call when nothing changes)
        self.fast = 0  # calls answered by the fast path
        self._sets: dict[bytes, tuple] = {}

    def _index_sets(self, state: np.ndarray) -> tuple:
        """(F, X, F×F, F×X, lower_F, upper_F, fixed values, fixed signs) of an active set, cached."""
        key = state.tobytes()
        if key not in self._sets:
            F, X = np.flatnonzero(state == 0), np.flatnonzero(state != 0)
            values = np.where(state[X] < 0, self.bounds.lower[X], self.bounds.upper[X])
            self._sets[key] = (
                F,
                X,
                np.ix_(F, F),
                np.ix_(F, X),
                self.bounds.lower[F],
                self.bounds.upper[F],
                values,
                state[X].astype(float),
            )
        return self._sets[key]

    def solve(self, H: np.ndarray, h: np.ndarray) -> np.ndarray:
        """π̂ for the statistics (H, h) [units of π]; exact (KKT-checked by construction)."""
        last = self.last
        if last is not None:
            F, X, FF, FX, loF, hiF, xX, sX = self._index_sets(last.state)
            # Cholesky (LAPACK dposv, little call overhead): the free block of H ≻ 0 is positive definite.
            rhs = h[F] - H[FX] @ xX if X.size else h
            _, target, info = _dposv(H[FF] if X.size else H, rhs)
            if info == 0 and np.minimum(target - loF, hiF - target).min() >= 0:
                x = np.empty_like(h)
                x[F], x[X] = target, xX
                if not X.size:
                    self.iterations += 1
                    self.fast += 1
                    self.last = BoundedSolution(x, last.state, 1)
                    return x
                # Multiplier sign test of `solve_bounded`: g·sign ≤ tol at every fixed parameter.
                HX = H[X]
                g = HX @ x - h[X]
                tol = KKT_TOL * (np.abs(HX) @ np.maximum(np.abs(x), 1.0) + np.abs(h[X]))
                if (g * sX <= tol).all():
                    self.iterations += 1
                    self.fast += 1
                    self.last = BoundedSolution(x, last.state, 1)
                    return x
            sol = solve_bounded(H, h, self.bounds, last.pi, last.state)
        else:
            sol = solve_bounded(H, h, self.bounds)
        self.iterations += sol.iterations
        self.last = sol
        return sol.pi


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
