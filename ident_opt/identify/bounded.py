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

Bounds (`default_bounds`; the paper's "bounded least squares" does not say which it used):

| parameter        | bound      | why                                                                  |
|------------------|------------|----------------------------------------------------------------------|
| a1, a3, ia2      | ≥ 0        | sums of inertias: a1 = I1 + m1 lc1² + m2 l1² + a3, a3 = I2 + m2 lc2², N²J |
| fv*, fc*, fs*    | ≥ 0        | friction dissipates: it never pushes the joint along its motion     |
| a2, b1, b2, b*s  | free       | m2 l1 lc2 and g·(m lc) change sign with the centre of mass's side    |

`default_bounds(model, signs_from=π_datasheet)` also fixes the sign of a2, b1, b2 to the datasheet's (a
stronger, robot-specific prior: the centre of mass lies on the datasheet's side of the joint).
Box bounds alone do not make M(q) positive definite (a3 = 0 with a2 ≠ 0 is still indefinite): that
is what the physically constrained fit (CPBR) is for.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ident_opt.robot import ArmModel

#: Parameters that are sums of inertias (kg m²) or friction coefficients: never negative.
NON_NEGATIVE_PREFIXES = ("fv", "fc", "fs")
NON_NEGATIVE_NAMES = ("a1", "a3", "ia2")
#: Parameters whose sign follows the centre of mass's side of the joint (fixed only with `signs_from`).
SIGNED_BY_GEOMETRY = ("a2", "b1", "b2")

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


def default_bounds(model: ArmModel, signs_from: np.ndarray | None = None) -> Bounds:
    """The documented physical bounds (module doc) for `model`; with `signs_from` (e.g. the datasheet
    π), a2, b1, b2 are also kept on the side of zero where that vector has them."""
    P = model.n_params
    lower, upper = np.full(P, -np.inf), np.full(P, np.inf)
    for p, name in enumerate(model.names):
        if name in NON_NEGATIVE_NAMES or name.startswith(NON_NEGATIVE_PREFIXES):
            lower[p] = 0.0
        if signs_from is not None and name in SIGNED_BY_GEOMETRY:
            if signs_from[p] > 0:
                lower[p] = 0.0
            elif signs_from[p] < 0:
                upper[p] = 0.0
    return Bounds(lower, upper)


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


def solve_bounded(H: np.ndarray, h: np.ndarray, bounds: Bounds, start: np.ndarray | None = None,
                  state: np.ndarray | None = None, max_iter: int | None = None) -> BoundedSolution:
    """The minimiser of ½πᵀHπ − hᵀπ on the box (H ≻ 0), from a warm start (`start`, `state` = a
    previous solution and active set; cold start: all free at the projection of 0).

    Primal active set: keep a feasible point; solve the normal equations on the free set; if that
    leaves the box, step to the first bound met and fix it; else release the fixed parameter whose
    multiplier has the wrong sign the most, or stop when none has (KKT conditions hold).
    """
    lo, hi = bounds.lower, bounds.upper
    P = h.shape[0]
    state = np.zeros(P, dtype=np.int8) if state is None else state.astype(np.int8).copy()
    x = np.clip(np.zeros(P) if start is None else start, lo, hi)
    state[(state < 0) & ~np.isfinite(lo)] = 0
    state[(state > 0) & ~np.isfinite(hi)] = 0
    x[state < 0], x[state > 0] = lo[state < 0], hi[state > 0]
    # Scale for "zero" multipliers: the gradient's natural size at this problem.
    tol = KKT_TOL * (np.abs(H) @ np.maximum(np.abs(x), 1.0) + np.abs(h))
    max_iter = max_iter or 10 * P + 10
    for iteration in range(1, max_iter + 1):
        free = state == 0
        if free.all():
            target = np.linalg.solve(H, h)
        else:
            fixed = ~free
            F = np.flatnonzero(free)
            target = np.linalg.solve(H[np.ix_(F, F)], h[F] - H[np.ix_(F, np.flatnonzero(fixed))] @ x[fixed]) \
                if F.size else np.empty(0)
        xf = x[free]
        if np.all(target >= lo[free]) and np.all(target <= hi[free]):
            x[free] = target
            g = H @ x - h
            # Fixed at lower: optimal only if moving up does not help (g ≥ 0); at upper: g ≤ 0.
            wrong = np.where(state < 0, -g, np.where(state > 0, g, -np.inf)) - tol
            j = int(np.argmax(wrong))
            if wrong[j] <= 0:
                return BoundedSolution(x, state, iteration)
            state[j] = 0
            continue
        # Ratio test: the largest step toward `target` that stays in the box; fix the bound it meets.
        d = target - xf
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


class WarmBoundedLS:
    """Box-bounded LS re-solved from statistics that change a little between calls: each call starts
    from the previous solution and active set (`solve_bounded`), so a step costs one small linear solve
    when the active set does not change."""

    def __init__(self, bounds: Bounds):
        self.bounds = bounds
        self.last: BoundedSolution | None = None
        self.iterations = 0  # total active-set iterations so far (1 per call when nothing changes)

    def solve(self, H: np.ndarray, h: np.ndarray) -> np.ndarray:
        """π̂ for the statistics (H, h) [units of π]; exact (KKT-checked by construction)."""
        if self.last is None:
            sol = solve_bounded(H, h, self.bounds)
        else:
            sol = solve_bounded(H, h, self.bounds, self.last.pi, self.last.state)
        self.iterations += sol.iterations
        self.last = sol
        return sol.pi
