"""Physically consistent least squares: a small conic program on the sufficient statistics.

    minimise    Σ_j w_j RSS_j(π) + λ Σ_p D_p (π_p − π0_p)²                (RSS from G, b, s; no data)
    subject to  the arm's consistency constraints (`ident_opt.consistency`), each named:
                Σ_p π_p A_p ⪰ margin·I for every mass LMI   "mass_pd_q2_0", "mass_pd_q2_pi" (two-link arm)
                π_p ≥ 0 for every friction parameter p       "friction_<p>"
                π_p ≥ 0 for every armature parameter p       "armature_<p>"    (rotor inertia N² J)
                lb ≤ π ≤ ub (optional)                       "lower_<p>", "upper_<p>"

For the two-link arm the two 2×2 LMIs are M(q) at cos q2 = ±1, which is exactly "M(q) ⪰ margin·I for every
q" (`PlanarArm.mass_lmis`); which parameters are sign-constrained follows their declared kind.

The prior term, written above as λ Σ_p D_p (π_p − π0_p)², is relative: D_p = S / π0_scale_p², with S the
weighted torque energy Σ_j w_j s_j [N² m²] and π0_scale_p = |π0_p| (floored at 1e-3 max|π0|). So
λ = `prior_weight` is dimensionless: at λ = 1, a 100 % deviation of one parameter from the prior costs as
much as all the measured torque energy. Unlike a data-scaled penalty, it also reaches columns the data do
not excite, which is where a prior is needed.

Because the problem is convex, if the unconstrained minimiser (OLS, or OLS with the prior) is feasible it
is the answer: it is returned exactly, with no constraint active.

Standard errors are the unconstrained problem's sandwich evaluated with the constrained fit's residuals
(`fit.finish`). Along a binding constraint the estimator's true distribution is one-sided, so read the SE
of a parameter involved in an active constraint as approximate.

`solve_constrained` returns π alone (the counterpart of `ols.solve_ols`); `fit_constrained` is the same call
plus standard errors, diagnostics and the active set. What depends only on the arm and the options
(constraint matrix, sparsity pattern, cones, solver settings) is assembled once and cached (`_structure`);
a call then costs a few tenths of a millisecond whatever the number of samples, most of it Clarabel's.

Two backends solve the same program, both generated from the same `Consistency` declaration.
`backend="clarabel"` (default) stacks its numeric blocks A π + s = b, s ∈ cone, and calls Clarabel
directly: a fraction of a millisecond. `backend="cvxpy"` states it in cvxpy (compiled once per structure,
data re-filled as parameters); it is the tests' cross-check, but cvxpy's bookkeeping costs several
milliseconds per solve.
"""

from __future__ import annotations

import functools
import time
import warnings
from dataclasses import dataclass
from typing import NamedTuple, TypedDict, Unpack

import clarabel
import numpy as np
from scipy import sparse

from ident_opt import consistency
from ident_opt.arm.base import Arm
from ident_opt.consistency import MARGIN, Consistency
from ident_opt.fitting.fit import LinearFit, check_stats, finish, joint_weights, normal_equations, solve_normal
from ident_opt.fitting.stats import Stats

#: A constraint whose slack is below this (SI units of the constrained quantity) is reported active.
ACTIVE_TOL = 1e-6
#: Relative size of the tie-break on rank-deficient data (far below any standard error).
TIE_BREAK = 1e-7
#: Conic solver tolerances, tight first (OLS to 1e-8 when nothing binds), looser if ill-conditioned.
TOLERANCES = (1e-11, 1e-8)


class Options(TypedDict, total=False):
    """The keyword options of `fit_constrained` and `solve_constrained` (meaning and defaults: there)."""

    margin: float
    prior: np.ndarray | None
    prior_weight: float
    bounds: tuple[np.ndarray, np.ndarray] | None
    weights: str | np.ndarray | None
    friction: bool
    mass: bool
    shortcut: bool
    backend: str


def sign_constraints(model: Arm) -> dict[str, str]:
    """Constraint name → parameter for every parameter that must be ≥ 0 ("friction_<p>", "armature_<p>"),
    from the parameters' declared kinds (`consistency.sign_constraints`)."""
    return {c.name: model.names[c.index] for c in consistency.sign_constraints(model.parameters)}


def constraint_slacks(
    model: Arm,
    pi: np.ndarray,
    margin: float = 0.0,
    friction: bool = True,
    mass: bool = True,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict[str, float]:
    """Each named constraint's slack at π (≥ 0 feasible, ≈ 0 active); PSD slack = λ_min − margin [kg m²]."""
    return Consistency.of(model, margin, friction, mass, bounds).slacks(pi)


def fit_constrained(stats: Stats, model: Arm, **options: Unpack[Options]) -> LinearFit:
    """Physically consistent π (see module doc) with standard errors, diagnostics and the active set.

    Options (all keyword):
        margin [kg m²] = 1e-6:   each mass LMI ⪰ margin·I (two-link arm: M(q) ⪰ margin·I ∀q).
        prior (P,), prior_weight λ ≥ 0 = 0: the relative pull toward π0 of the module doc.
        bounds (lb, ub) = None:  lb ≤ π ≤ ub where finite.
        weights = None:          joint weights as in `fit_ols` (None, "wls" or an array).
        friction = True:         the sign constraints (friction and armature ≥ 0); False drops them.
        mass = True:             the mass LMIs; False drops them.
        shortcut = True:         return a feasible unconstrained minimiser as is; False always runs the
                                 conic solver (tests use it to check the solver against OLS).
        backend = "clarabel":    "clarabel" (direct, fast) or "cvxpy" (the same program through cvxpy).

    `status` is the solver's. π is `solve_constrained`'s (one implementation).
    """
    sol = _solution(stats, model, **options)
    if sol.unconstrained:
        return finish(stats, model, sol.pi, sol.weights, sol.structure.method, sol.status, [], sol.seconds)
    slacks = sol.structure.consistency.slacks(sol.pi)
    active = [name for name, v in slacks.items() if v < ACTIVE_TOL]
    fit = finish(stats, model, sol.pi, sol.weights, sol.structure.method, sol.status, active, sol.seconds)
    fit.details["clarabel_seconds"] = sol.solver_seconds  # the solver alone, without cvxpy's parameter update
    return fit


def solve_constrained(stats: Stats, model: Arm, **options: Unpack[Options]) -> np.ndarray:
    """π only (no standard errors, no diagnostics): the constrained counterpart of `ols.solve_ols`.

    Options and units as in `fit_constrained`, whose π this is (one implementation). Everything that
    depends only on (arm, margin, friction, mass, bounds) — constraint matrix, sparsity patterns, cones,
    solver settings — is built once and cached (`_structure`), so a call is: the P×P normal matrix H, the
    unconstrained minimiser and its feasibility (returned exactly if feasible), else one conic solve.
    """
    return _solution(stats, model, **options).pi


def fit_bounded(
    stats: Stats, model: Arm, lb: np.ndarray, ub: np.ndarray, weights: str | np.ndarray | None = None
) -> LinearFit:
    """Box-bounded least squares lb ≤ π ≤ ub (no consistency constraints), from the statistics."""
    return fit_constrained(stats, model, bounds=(lb, ub), weights=weights, friction=False, mass=False)


def joint_weights_energy(stats: Stats, w: np.ndarray) -> float:
    """Σ_j w_j s_j: the weighted measured torque energy [N² m²] (the prior's scale)."""
    return float(w @ stats.s)


def tie_break(H: np.ndarray) -> np.ndarray:
    """ρ (P,): a tiny penalty Σ_p ρ_p π_p², only when H is singular, so the constrained minimiser is unique.

    It mirrors OLS's least-norm choice (in column-equilibrated units): ρ_p = ε H_pp, and ε × the mean
    excited H_pp for columns the data do not excite. Without it an interior-point solver returns the
    analytic centre of the optimal face, an arbitrary point along directions the data cannot see.
    """
    d = np.diag(H)
    excited = d > 1e-12 * max(d.max(), np.finfo(float).tiny)
    # Full rank by numpy.linalg.matrix_rank's test (|λ| > max|λ| · P · eps), on eigvalsh directly: the same
    # numbers without its SVD wrapper, which costs as much again on a 9×9.
    lam = np.abs(np.linalg.eigvalsh(H))
    if np.all(lam > lam.max() * len(d) * np.finfo(float).eps) or not excited.any():
        return np.zeros(len(d))
    return TIE_BREAK * np.where(excited, d, d[excited].mean())


# ---------------------------------------------------------------------------------------------- one solve
class _Solution(NamedTuple):
    """What `fit_constrained` needs beyond π: joint weights, solver status, timings [s], the structure."""

    pi: np.ndarray
    weights: np.ndarray
    status: str
    unconstrained: bool  # the unconstrained minimiser was feasible and is returned as is
    seconds: float  # the solve (unconstrained minimiser, feasibility, conic solver), not the set-up
    solver_seconds: float  # Clarabel's own solve time (nan when it did not run or is not reported)
    structure: _Structure


def _solution(
    stats: Stats,
    model: Arm,
    *,
    margin: float = MARGIN,
    prior: np.ndarray | None = None,
    prior_weight: float = 0.0,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
    weights: str | np.ndarray | None = None,
    friction: bool = True,
    mass: bool = True,
    shortcut: bool = True,
    backend: str = "clarabel",
) -> _Solution:
    """The one implementation behind `solve_constrained` and `fit_constrained` (options as there)."""
    if backend not in ("clarabel", "cvxpy"):
        raise ValueError(f"backend must be 'clarabel' or 'cvxpy', not {backend!r}")
    check_stats(stats, model)
    w = joint_weights(stats, weights)
    H, h = normal_equations(stats, w)
    prior, Dp = _prior(stats, model, w, prior, prior_weight)
    structure = _structure(model, float(margin), bool(friction), bool(mass), _bounds_key(model, bounds))
    t0 = time.perf_counter()
    if shortcut:
        # Convex problem: a feasible unconstrained minimiser is the answer (returned exactly, like OLS).
        free = solve_normal(H + np.diag(Dp), h + Dp * prior)
        if structure.consistency.feasible(free):
            status = "optimal (unconstrained minimiser feasible)"
            return _Solution(free, w, status, True, time.perf_counter() - t0, float("nan"), structure)
    solve = _solve_clarabel if backend == "clarabel" else _solve_cvxpy
    pi, status, solver_seconds = solve(structure, H, h, stats.n, Dp, prior)
    if pi is None:
        raise RuntimeError(f"constrained fit failed: solver status {status}")
    return _Solution(pi, w, status, False, time.perf_counter() - t0, solver_seconds, structure)


def _prior(
    stats: Stats, model: Arm, w: np.ndarray, prior: np.ndarray | None, prior_weight: float
) -> tuple[np.ndarray, np.ndarray]:
    """(π0, D) (P,) each: the prior and its curvature per parameter (module doc), checked."""
    if prior_weight < 0:
        raise ValueError("prior_weight must be ≥ 0")
    if prior_weight > 0 and prior is None:
        raise ValueError("prior_weight > 0 needs a prior")
    P = model.n_params
    prior = np.zeros(P) if prior is None else np.asarray(prior, dtype=float)
    if prior.shape != (P,):
        raise ValueError(f"prior has shape {prior.shape}, the model {model.names} needs ({P},)")
    if prior_weight > 0:
        scale = np.maximum(np.abs(prior), 1e-3 * max(np.abs(prior).max(), 1e-12))
        return prior, prior_weight * joint_weights_energy(stats, w) / scale**2
    return prior, np.zeros(P)  # what the formula gives at λ = 0, without its arithmetic


def _bounds_key(model: Arm, bounds: tuple[np.ndarray, np.ndarray] | None) -> tuple | None:
    """Checked bounds as a hashable cache key ((lb...), (ub...)), a non-finite bound being no bound (±inf)."""
    if bounds is None:
        return None
    P = model.n_params
    lb, ub = (np.broadcast_to(np.asarray(v, dtype=float), (P,)) for v in bounds)
    if np.any(lb > ub):
        bad = [n for n, lo, hi in zip(model.names, lb, ub) if lo > hi]
        raise ValueError(f"lower bound above upper bound for {', '.join(bad)}")
    return (
        tuple(np.where(np.isfinite(lb), lb, -np.inf).tolist()),
        tuple(np.where(np.isfinite(ub), ub, np.inf).tolist()),
    )


# ---------------------------------------------------------------------------------------------- Clarabel
@dataclass(frozen=True, eq=False)
class _Structure:
    """Everything of the conic program that depends on (arm, margin, friction, mass, bounds) only.

    The declaration (`Consistency`) and, from it, Clarabel's constraints A π + s = b, s ∈ cones (its named
    blocks stacked); Clarabel's settings per tolerance; the CSC pattern of the upper triangle of the P×P
    quadratic term (Clarabel reads only that triangle).
    """

    consistency: Consistency
    method: str  # "constrained", or "bounded" without mass and sign constraints
    A: sparse.csc_matrix  # (m, P)
    b: np.ndarray  # (m,)
    cones: tuple  # Clarabel cone objects, one per block
    settings: tuple  # clarabel.DefaultSettings per tolerance of TOLERANCES
    q_rows: np.ndarray  # upper-triangle entries (rows, cols) of Q in CSC (column-major) order
    q_cols: np.ndarray
    q_indices: np.ndarray  # CSC row indices and column pointers of that triangle
    q_indptr: np.ndarray


@functools.lru_cache(maxsize=64)
def _structure(
    model: Arm, margin: float, friction: bool, mass: bool, bounds: tuple[tuple[float, ...], tuple[float, ...]] | None
) -> _Structure:
    """The cached `_Structure` (keyed on the frozen arm and the options; bounds as tuples)."""
    P = model.n_params
    declared = Consistency.of(model, margin, friction, mass, bounds)
    blocks = declared.blocks()
    A = np.vstack([blk.A for blk in blocks]) if blocks else np.zeros((0, P))
    b = np.concatenate([blk.b for blk in blocks]) if blocks else np.zeros(0)
    cones = tuple(
        clarabel.PSDTriangleConeT(blk.size) if blk.cone == "psd" else clarabel.NonnegativeConeT(blk.size)
        for blk in blocks
    )
    rows, cols = np.triu_indices(P)
    order = np.lexsort((rows, cols))  # column-major: the CSC layout of the upper triangle
    rows, cols = rows[order], cols[order]
    pattern = sparse.csc_matrix((np.ones(rows.size), (rows, cols)), shape=(P, P))
    method = "constrained" if (friction or mass) else "bounded"
    settings = tuple(_settings(tol) for tol in TOLERANCES)
    return _Structure(
        declared, method, sparse.csc_matrix(A), b, cones, settings, rows, cols, pattern.indices, pattern.indptr
    )


def _settings(tol: float) -> clarabel.DefaultSettings:
    """Clarabel's settings at one tolerance (gap and feasibility), quiet, at most 500 iterations."""
    s = clarabel.DefaultSettings()
    s.verbose = False
    s.tol_gap_abs = s.tol_gap_rel = s.tol_feas = tol
    s.max_iter = 500
    return s


def _solve_clarabel(
    structure: _Structure, H: np.ndarray, h: np.ndarray, n: int, Dp: np.ndarray, prior: np.ndarray
) -> tuple[np.ndarray | None, str, float]:
    """min ½ πᵀQπ + cᵀπ s.t. the named blocks, by Clarabel directly: (π or None, status, solver s).

    Q = 2(H + diag(D + ρ))/n and c = −2(h + D π0)/n: the module doc's objective per sample, with the
    tie-break ρ of `tie_break` when the data leave directions free. Clarabel takes the quadratic term as
    it is, so no square root of H is needed here (the cvxpy statement uses one).
    """
    st = structure
    P = H.shape[0]
    Q = 2.0 * (H + np.diag(Dp + tie_break(H))) / max(n, 1)
    c = -2.0 * (h + Dp * prior) / max(n, 1)
    # A new matrix on the cached pattern each call (cheap): nothing data-dependent outlives the call.
    Qs = sparse.csc_matrix((Q[st.q_rows, st.q_cols], st.q_indices, st.q_indptr), shape=(P, P))
    status, total = "not solved", 0.0
    for settings in st.settings:
        solution = clarabel.DefaultSolver(Qs, c, st.A, st.b, list(st.cones), settings).solve()
        total += solution.solve_time
        status = str(solution.status)
        if status == "Solved":
            break
    if status not in ("Solved", "AlmostSolved"):
        return None, status, total
    return np.asarray(solution.x, dtype=float), status, total


# ---------------------------------------------------------------------------------------------- cvxpy
def _square_root(H: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, d) with ‖Rπ − d‖² = πᵀHπ − 2hᵀπ + const, from the eigen-decomposition (H may be singular)."""
    lam, V = np.linalg.eigh(H)
    keep = lam > lam.max() * 1e-14
    R = np.sqrt(lam[keep])[:, None] * V[:, keep].T
    d = (V[:, keep].T @ h) / np.sqrt(lam[keep])
    return R, d


@functools.lru_cache(maxsize=32)
def _program(structure: _Structure):
    """The conic program of the module doc as a parametrised cvxpy problem, compiled once per structure.

    The objective ‖R π − d‖² + ‖√D π − √D π0‖² + ‖√ρ π‖² (RᵀR = H: P variables whatever the number of
    samples) takes the data as cvxpy Parameters, so re-solving with new statistics skips cvxpy's
    canonicalisation (DPP); the constraints are `Consistency.cvxpy`, the same declaration Clarabel gets.
    """
    import cvxpy as cp  # deferred: cvxpy takes about a second to import and only this test oracle needs it

    P = structure.consistency.n_params
    pi = cp.Variable(P, name="pi")
    par = {
        "R": cp.Parameter((P, P), name="R"),
        "d": cp.Parameter(P, name="d"),
        "prior_term": cp.Parameter(P, name="prior_term"),
        "sqrt_dp": cp.Parameter(P, nonneg=True, name="sqrt_dp"),
        "sqrt_ridge": cp.Parameter(P, nonneg=True, name="sqrt_ridge"),
    }
    objective = (
        cp.sum_squares(par["R"] @ pi - par["d"])
        + cp.sum_squares(cp.multiply(par["sqrt_dp"], pi) - par["prior_term"])
        + cp.sum_squares(cp.multiply(par["sqrt_ridge"], pi))
    )  # parameter inside: keeps it DPP
    problem = cp.Problem(cp.Minimize(objective), structure.consistency.cvxpy(pi))
    assert problem.is_dpp()  # otherwise every solve would recompile (tens of ms)
    return problem, pi, par


def _solve_cvxpy(
    structure: _Structure, H: np.ndarray, h: np.ndarray, n: int, Dp: np.ndarray, prior: np.ndarray
) -> tuple[np.ndarray | None, str, float]:
    """Fill the cached program's parameters and solve it with Clarabel: (π or None, status, solver s)."""

    problem, pi, par = _program(structure)
    P = H.shape[0]
    R, d = _square_root(H, h)
    scale = 1.0 / max(n, 1)  # objective per sample: keeps the solver's numbers O(τ²)
    par["R"].value = np.vstack([R, np.zeros((P - R.shape[0], P))]) * np.sqrt(scale)
    par["d"].value = np.concatenate([d, np.zeros(P - d.size)]) * np.sqrt(scale)
    par["sqrt_dp"].value = np.sqrt(Dp * scale)
    par["prior_term"].value = par["sqrt_dp"].value * prior  # √D (π − π0) = √D π − √D π0 stays DPP
    # Data that leave directions free: the tie-break makes the minimiser unique (see `tie_break`).
    par["sqrt_ridge"].value = np.sqrt(tie_break(H) * scale)
    pi_hat, status = solve_cvxpy(problem, pi)
    if pi_hat is None:
        return None, status, float("nan")
    return pi_hat, status, float(problem.solver_stats.solve_time or np.nan)


def solve_cvxpy(problem, pi, tolerances: tuple[float, ...] = ()) -> tuple[np.ndarray | None, str]:
    """Solve a cvxpy `problem` in the variable `pi` with Clarabel: tight tolerances first (the answer should
    match OLS to 1e-8 when nothing binds), looser ones if a badly conditioned problem cannot reach them.
    `tolerances` default to this module's `TOLERANCES`. Returns (π or None, the solver's status)."""
    import cvxpy as cp  # heavy (about a second): only the tests' oracle and the URDF prior need it

    status = "not solved"
    for tol in tolerances or TOLERANCES:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # "may be inaccurate": judged by status below
                problem.solve(solver="CLARABEL", tol_gap_abs=tol, tol_gap_rel=tol, tol_feas=tol, max_iter=500)
        except cp.error.SolverError as exc:
            status = f"solver error: {exc}"
            continue
        status = str(problem.status)
        if pi.value is not None and status == "optimal":
            break
    if pi.value is None or status not in ("optimal", "optimal_inaccurate"):
        return None, status
    return np.asarray(pi.value, dtype=float), status
