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
that is what the physically constrained fit (CPBR, `bounded_consistent.WarmConsistentLS`) is for; its mass-matrix cones
are the arm's declared 2×2 LMIs (`Arm.mass_lmis`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

# Plain LAPACK calls: a few µs each instead of numpy.linalg.solve's ~10 µs of wrapping (P is 9 here).
from scipy.linalg.lapack import dposv as _dposv

from ident_opt.arm.base import Arm
from ident_opt.consistency import physical_bounds

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
