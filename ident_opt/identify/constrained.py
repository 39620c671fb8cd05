"""Physically consistent least squares: a small conic program (cvxpy + Clarabel) on the statistics.

    minimise    Σ_j w_j RSS_j(π) + λ Σ_p D_p (π_p − π0_p)²                (RSS from G, b, s; no data)
    subject to  M0(π) + M1(π) ⪰ margin·I     "mass_pd_q2_0"    M(q) at cos q2 = +1
                M0(π) − M1(π) ⪰ margin·I     "mass_pd_q2_pi"   M(q) at cos q2 = −1
                π_p ≥ 0 for every friction parameter p    "friction_<p>"
                π_p ≥ 0 for every armature parameter p    "armature_<p>"    (rotor inertia N² J)
                lb ≤ π ≤ ub (optional)                    "lower_<p>", "upper_<p>"

M(q) = M0 + M1 cos q2 with M0, M1 affine in π (`ArmModel.mass_matrix_maps`), and λ_min(M0 + c M1) is
concave in c, so the two 2×2 LMIs are exactly "M(q) ⪰ margin·I for every q" — also with armature.
The quadratic is written as ‖R π − d‖² with RᵀR = H (a square root of the P×P matrix), so the conic
program has P variables whatever the number of samples.

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
plus standard errors, diagnostics and the active set. What depends only on the model and the options
(constraint matrix, sparsity pattern, cones, solver settings) is assembled once and cached (`_structure`);
a call then costs a few tenths of a millisecond whatever the number of samples, most of it Clarabel's.

Two backends solve the same program. `backend="clarabel"` (default) assembles the constraints as plain
numeric blocks A π + s = b, s ∈ cone, one named block per constraint (`constraint_blocks`), and calls
Clarabel directly: a fraction of a millisecond. `backend="cvxpy"` writes it in cvxpy (compiled once per
structure, parameters re-filled); it is the readable statement of the problem and the tests' cross-check,
but cvxpy's bookkeeping costs several milliseconds per solve.
"""

from __future__ import annotations

import functools
import time
import warnings
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ident_opt.identify.fit import LinearFit, _check, _normal, _solve, finish, joint_weights
from ident_opt.identify.stats import Stats
from ident_opt.robot import ArmModel

#: A constraint whose slack is below this (SI units of the constrained quantity) is reported active.
ACTIVE_TOL = 1e-6


def friction_names(model: ArmModel) -> list[str]:
    """The friction parameters (viscous, Coulomb incl. per-direction, Stribeck): all must be ≥ 0."""
    return [n for n in model.names if n[:2] in ("fv", "fc", "fs")]


def sign_constraints(model: ArmModel) -> dict[str, str]:
    """Constraint name → parameter for every parameter that must be ≥ 0: friction ("friction_<p>", it
    dissipates) and reflected rotor inertia ("armature_<p>", N² J_rotor ≥ 0; M ≻ 0 alone would allow a
    negative armature offset by the link inertias)."""
    out = {f"friction_{n}": n for n in friction_names(model)}
    out.update({f"armature_{n}": n for n in model.names if n.startswith("ia")})
    return out


def constraint_slacks(
    model: ArmModel,
    pi: np.ndarray,
    margin: float = 0.0,
    friction: bool = True,
    mass: bool = True,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict[str, float]:
    """Each named constraint's slack at π (≥ 0 feasible, ≈ 0 active); PSD slack = λ_min − margin."""
    out: dict[str, float] = {}
    if mass:
        A0, A1 = model.mass_matrix_maps
        M0, M1 = np.tensordot(pi, A0, 1), np.tensordot(pi, A1, 1)
        out["mass_pd_q2_0"] = float(np.linalg.eigvalsh(M0 + M1)[0] - margin)
        out["mass_pd_q2_pi"] = float(np.linalg.eigvalsh(M0 - M1)[0] - margin)
    if friction:
        for label, name in sign_constraints(model).items():
            out[label] = float(pi[model.names.index(name)])
    if bounds is not None:
        lb, ub = (np.broadcast_to(np.asarray(v, dtype=float), pi.shape) for v in bounds)
        for p, name in enumerate(model.names):
            if np.isfinite(lb[p]):
                out[f"lower_{name}"] = float(pi[p] - lb[p])
            if np.isfinite(ub[p]):
                out[f"upper_{name}"] = float(ub[p] - pi[p])
    return out


def fit_constrained(
    stats: Stats,
    model: ArmModel,
    *,
    margin: float = 1e-6,
    prior: np.ndarray | None = None,
    prior_weight: float = 0.0,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
    weights: str | np.ndarray | None = None,
    friction: bool = True,
    mass: bool = True,
    shortcut: bool = True,
    backend: str = "clarabel",
) -> LinearFit:
    """Physically consistent π (see module doc): M(q) ⪰ margin·I ∀q [kg m²], friction and armature ≥ 0
    (`friction=False` drops both sign constraints), optional
    bounds (lb, ub) and prior π0 with weight λ. `weights` as in `fit_ols`. `shortcut=False` always runs
    the conic solver (tests use it to check the solver against OLS). `backend`: "clarabel" (direct,
    fast) or "cvxpy" (same program through cvxpy). `status` is the solver's.

    π is `solve_constrained`'s (the same call); this adds standard errors, diagnostics and the active set.
    """
    sol = _solution(
        stats,
        model,
        margin=margin,
        prior=prior,
        prior_weight=prior_weight,
        bounds=bounds,
        weights=weights,
        friction=friction,
        mass=mass,
        shortcut=shortcut,
        backend=backend,
    )
    method = "constrained" if (friction or mass) else "bounded"
    if sol.unconstrained:
        return finish(stats, model, sol.pi, sol.weights, method, sol.status, [], sol.seconds)
    slacks = constraint_slacks(model, sol.pi, margin, friction, mass, bounds)
    active = [name for name, v in slacks.items() if v < ACTIVE_TOL]
    fit = finish(stats, model, sol.pi, sol.weights, method, sol.status, active, sol.seconds)
    fit.details["clarabel_seconds"] = sol.solver_seconds  # the solver alone, without cvxpy's parameter update
    return fit


def solve_constrained(
    stats: Stats,
    model: ArmModel,
    *,
    margin: float = 1e-6,
    prior: np.ndarray | None = None,
    prior_weight: float = 0.0,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
    weights: str | np.ndarray | None = None,
    friction: bool = True,
    mass: bool = True,
    shortcut: bool = True,
    backend: str = "clarabel",
) -> np.ndarray:
    """π only (no standard errors, no diagnostics): the constrained counterpart of `ols.solve_ols`.

    Arguments and units as in `fit_constrained`, whose π this is (one implementation). Everything that
    depends only on (model, margin, friction, mass, bounds) — constraint matrix, sparsity patterns, cones,
    solver settings — is built once and cached (`_structure`), so a call is: the P×P normal matrix H, the
    unconstrained minimiser and its feasibility (returned exactly if feasible), else one Clarabel solve.
    """
    return _solution(
        stats,
        model,
        margin=margin,
        prior=prior,
        prior_weight=prior_weight,
        bounds=bounds,
        weights=weights,
        friction=friction,
        mass=mass,
        shortcut=shortcut,
        backend=backend,
    ).pi


class _Solution(NamedTuple):
    """What `fit_constrained` needs beyond π: joint weights, solver status, timings [s]."""

    pi: np.ndarray
    weights: np.ndarray
    status: str
    unconstrained: bool  # the unconstrained minimiser was feasible and is returned as is
    seconds: float  # the solve (unconstrained minimiser, feasibility, conic solver), not the set-up
    solver_seconds: float  # Clarabel's own solve time (nan when it did not run or is not reported)


def _solution(
    stats: Stats,
    model: ArmModel,
    *,
    margin: float,
    prior: np.ndarray | None,
    prior_weight: float,
    bounds: tuple[np.ndarray, np.ndarray] | None,
    weights: str | np.ndarray | None,
    friction: bool,
    mass: bool,
    shortcut: bool,
    backend: str,
) -> _Solution:
    """The one implementation behind `solve_constrained` and `fit_constrained` (arguments as there)."""
    if backend not in ("clarabel", "cvxpy"):
        raise ValueError(f"backend must be 'clarabel' or 'cvxpy', not {backend!r}")
    _check(stats, model)
    if prior_weight < 0:
        raise ValueError("prior_weight must be ≥ 0")
    if prior_weight > 0 and prior is None:
        raise ValueError("prior_weight > 0 needs a prior")
    w = joint_weights(stats, weights)
    H, h = _normal(stats, w)
    P = model.n_params
    prior = np.zeros(P) if prior is None else np.asarray(prior, dtype=float)
    if prior.shape != (P,):
        raise ValueError(f"prior has shape {prior.shape}, the model {model.names} needs ({P},)")
    key = None
    if bounds is not None:
        lb, ub = (np.broadcast_to(np.asarray(v, dtype=float), (P,)) for v in bounds)
        if np.any(lb > ub):
            bad = [n for n, lo, hi in zip(model.names, lb, ub) if lo > hi]
            raise ValueError(f"lower bound above upper bound for {', '.join(bad)}")
        # A non-finite bound is no bound (as in `constraint_blocks`): ±inf in the hashable cache key.
        key = (
            tuple(np.where(np.isfinite(lb), lb, -np.inf).tolist()),
            tuple(np.where(np.isfinite(ub), ub, np.inf).tolist()),
        )
    structure = _structure(model, float(margin), bool(friction), bool(mass), key)
    if prior_weight > 0:
        scale = np.maximum(np.abs(prior), 1e-3 * max(np.abs(prior).max(), 1e-12))
        Dp = prior_weight * joint_weights_energy(stats, w) / scale**2  # prior curvature per parameter
    else:
        Dp = np.zeros(P)  # what the formula gives at λ = 0, without its arithmetic

    t0 = time.perf_counter()
    if shortcut:
        # Convex problem: a feasible unconstrained minimiser is the answer (returned exactly, like OLS).
        free = _solve(H + np.diag(Dp), h + Dp * prior)
        if structure.feasible(free):
            return _Solution(
                free, w, "optimal (unconstrained minimiser feasible)", True, time.perf_counter() - t0, float("nan")
            )
    if backend == "clarabel":
        pi, status, solver_seconds = _solve_clarabel(structure, H, h, stats.n, Dp, prior)
    else:
        pi, status, solver_seconds = _solve_conic(model, H, h, stats.n, margin, Dp, prior, friction, mass, bounds)
    if pi is None:
        raise RuntimeError(f"constrained fit failed: solver status {status}")
    return _Solution(pi, w, status, False, time.perf_counter() - t0, solver_seconds)


def joint_weights_energy(stats: Stats, w: np.ndarray) -> float:
    """Σ_j w_j s_j: the weighted measured torque energy [N² m²] (the prior's scale)."""
    return float(w @ stats.s)


def fit_bounded(
    stats: Stats, model: ArmModel, lb: np.ndarray, ub: np.ndarray, weights: str | np.ndarray | None = None
) -> LinearFit:
    """Box-bounded least squares lb ≤ π ≤ ub (no consistency constraints), from the statistics."""
    return fit_constrained(stats, model, bounds=(lb, ub), weights=weights, friction=False, mass=False)


#: Relative size of the tie-break on rank-deficient data (far below any standard error).
TIE_BREAK = 1e-7


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


@dataclass(frozen=True)
class Block:
    """One named constraint as numbers: A π + s = b with s in `cone` ("psd2": 2×2 PSD in Clarabel's
    svec order [m11, √2 m12, m22]; "nonneg": s ≥ 0 elementwise)."""

    name: str
    A: np.ndarray
    b: np.ndarray
    cone: str


def _svec(M: np.ndarray) -> np.ndarray:
    """Scaled vectorisation of symmetric 2×2 matrices (..., 2, 2) → (..., 3), ⟨X, Y⟩ = svec X · svec Y."""
    return np.stack([M[..., 0, 0], np.sqrt(2.0) * M[..., 0, 1], M[..., 1, 1]], axis=-1)


def constraint_blocks(
    model: ArmModel,
    margin: float = 1e-6,
    friction: bool = True,
    mass: bool = True,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> list[Block]:
    """The constraints of the module doc as named numeric blocks (same names as `constraint_slacks`).

    mass_pd_q2_0 / _pi:  s = svec(M0 ± M1 − margin·I) ∈ PSD:  A = −svec(A0 ± A1) per column, b = −margin svec I
    friction_<p>, armature_<p>:  s = π_p ≥ 0:                 A = −e_pᵀ, b = 0
    lower_<p> / upper_<p>: s = π_p − lb_p ≥ 0 / ub_p − π_p ≥ 0
    """
    P = model.n_params
    eye = np.eye(P)
    blocks = []
    if mass:
        A0, A1 = model.mass_matrix_maps
        for name, sign in (("mass_pd_q2_0", 1.0), ("mass_pd_q2_pi", -1.0)):
            blocks.append(Block(name, -_svec(A0 + sign * A1).T, -margin * _svec(np.eye(2)), "psd2"))
    if friction:
        for label, name in sign_constraints(model).items():
            p = model.names.index(name)
            blocks.append(Block(label, -eye[p : p + 1], np.zeros(1), "nonneg"))
    if bounds is not None:
        lb, ub = (np.broadcast_to(np.asarray(v, dtype=float), (P,)) for v in bounds)
        for p, name in enumerate(model.names):
            if np.isfinite(lb[p]):
                blocks.append(Block(f"lower_{name}", -eye[p : p + 1], np.array([-lb[p]]), "nonneg"))
            if np.isfinite(ub[p]):
                blocks.append(Block(f"upper_{name}", eye[p : p + 1], np.array([ub[p]]), "nonneg"))
    return blocks


@dataclass(frozen=True)
class _Structure:
    """Everything of the conic program that depends on (model, margin, friction, mass, bounds) only.

    Constraints A π + s = b, s ∈ cones (the stacked named blocks of `constraint_blocks`); Clarabel's
    settings per tolerance; the CSC pattern of the upper triangle of the P×P quadratic term (Clarabel reads
    only that triangle); and what the feasibility test of the unconstrained minimiser needs.
    """

    A: object  # scipy.sparse.csc_matrix (m, P)
    b: np.ndarray  # (m,)
    cones: tuple  # Clarabel cone objects, one per block
    settings: tuple  # (tolerance, clarabel.DefaultSettings), tightest first
    q_rows: np.ndarray  # upper-triangle entries (rows, cols) of Q in CSC (column-major) order
    q_cols: np.ndarray
    q_indices: np.ndarray  # CSC row indices and column pointers of that triangle
    q_indptr: np.ndarray
    margin: float  # [kg m²]
    mass: bool
    maps: tuple[np.ndarray, np.ndarray]  # (A0, A1) of `ArmModel.mass_matrix_maps`, each as (P, 4)
    sign: np.ndarray  # indices of the parameters that must be ≥ 0
    lb: np.ndarray  # (P,) lower/upper bounds, ±inf where none
    ub: np.ndarray

    def feasible(self, pi: np.ndarray) -> bool:
        """Every slack of `constraint_slacks` ≥ 0 at π (the same arithmetic, without building the dict)."""
        if self.mass:
            # M0 = Σ_p π_p A0[p]: the product np.tensordot(π, A0, 1) computes, without its bookkeeping.
            M0, M1 = (np.dot(pi[None, :], a).reshape(2, 2) for a in self.maps)
            if np.linalg.eigvalsh(np.stack([M0 + M1, M0 - M1]))[:, 0].min() - self.margin < 0:
                return False
        # π_p − lb_p ≥ 0 ⇔ π_p ≥ lb_p exactly in IEEE arithmetic (and holds against −inf, as no bound).
        return bool(np.all(pi[self.sign] >= 0) and np.all(pi >= self.lb) and np.all(pi <= self.ub))


@functools.lru_cache(maxsize=64)
def _structure(
    model: ArmModel,
    margin: float,
    friction: bool,
    mass: bool,
    bounds: tuple[tuple[float, ...], tuple[float, ...]] | None,
) -> _Structure:
    """The cached `_Structure` (keyed on the frozen model and the options; bounds as tuples)."""
    import clarabel
    from scipy import sparse

    P = model.n_params
    blocks = constraint_blocks(model, margin, friction, mass, bounds)
    A = np.vstack([blk.A for blk in blocks]) if blocks else np.zeros((0, P))
    b = np.concatenate([blk.b for blk in blocks]) if blocks else np.zeros(0)
    cones = tuple(
        clarabel.PSDTriangleConeT(2) if blk.cone == "psd2" else clarabel.NonnegativeConeT(len(blk.b)) for blk in blocks
    )
    settings = []
    for tol in (1e-11, 1e-8):  # tight first (OLS to 1e-8 when nothing binds), looser if ill-conditioned
        s = clarabel.DefaultSettings()
        s.verbose = False
        s.tol_gap_abs = s.tol_gap_rel = s.tol_feas = tol
        s.max_iter = 500
        settings.append((tol, s))
    rows, cols = np.triu_indices(P)
    order = np.lexsort((rows, cols))  # column-major: the CSC layout of the upper triangle
    rows, cols = rows[order], cols[order]
    pattern = sparse.csc_matrix((np.ones(rows.size), (rows, cols)), shape=(P, P))
    lb, ub = (np.full(P, -np.inf), np.full(P, np.inf)) if bounds is None else (np.array(v) for v in bounds)
    sign = [model.names.index(n) for n in sign_constraints(model).values()] if friction else []
    return _Structure(
        sparse.csc_matrix(A),
        b,
        cones,
        tuple(settings),
        rows,
        cols,
        pattern.indices,
        pattern.indptr,
        margin,
        mass,
        tuple(a.reshape(P, 4) for a in model.mass_matrix_maps),
        np.array(sign, dtype=int),
        lb,
        ub,
    )


def _solve_clarabel(
    structure: _Structure, H: np.ndarray, h: np.ndarray, n: int, Dp: np.ndarray, prior: np.ndarray
) -> tuple[np.ndarray | None, str, float]:
    """min ½ πᵀQπ + cᵀπ s.t. the named blocks, by Clarabel directly: (π or None, status, solver s).

    Q = 2(H + diag(D + ρ))/n and c = −2(h + D π0)/n: the module doc's objective per sample, with the
    tie-break ρ of `tie_break` when the data leave directions free. Clarabel takes the quadratic term as
    it is, so no square root of H is needed here (the cvxpy statement uses one).
    """
    import clarabel
    from scipy import sparse

    st = structure
    P = H.shape[0]
    Q = 2.0 * (H + np.diag(Dp + tie_break(H))) / max(n, 1)
    c = -2.0 * (h + Dp * prior) / max(n, 1)
    # A new matrix on the cached pattern each call (cheap): nothing data-dependent outlives the call.
    Qs = sparse.csc_matrix((Q[st.q_rows, st.q_cols], st.q_indices, st.q_indptr), shape=(P, P))
    status, total = "not solved", 0.0
    for _, settings in st.settings:
        solution = clarabel.DefaultSolver(Qs, c, st.A, st.b, list(st.cones), settings).solve()
        total += solution.solve_time
        status = str(solution.status)
        if status == "Solved":
            break
    if status not in ("Solved", "AlmostSolved"):
        return None, status, total
    return np.asarray(solution.x, dtype=float), status, total


def _square_root(H: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, d) with ‖Rπ − d‖² = πᵀHπ − 2hᵀπ + const, from the eigen-decomposition (H may be singular)."""
    lam, V = np.linalg.eigh(H)
    keep = lam > lam.max() * 1e-14
    R = np.sqrt(lam[keep])[:, None] * V[:, keep].T
    d = (V[:, keep].T @ h) / np.sqrt(lam[keep])
    return R, d


@functools.lru_cache(maxsize=32)
def _program(model: ArmModel, friction: bool, mass: bool, lower: tuple[int, ...], upper: tuple[int, ...]):
    """The conic program of the module doc as a parametrised cvxpy problem, compiled once per structure.

    Data enter only through cvxpy Parameters (R, d, prior, its weights, margin, bounds), so re-solving
    with new statistics skips cvxpy's canonicalisation (DPP) and costs little more than Clarabel itself.
    """
    import cvxpy as cp

    P = model.n_params
    pi = cp.Variable(P, name="pi")
    par = {
        "R": cp.Parameter((P, P), name="R"),
        "d": cp.Parameter(P, name="d"),
        "prior_term": cp.Parameter(P, name="prior_term"),
        "sqrt_dp": cp.Parameter(P, nonneg=True, name="sqrt_dp"),
        "sqrt_ridge": cp.Parameter(P, nonneg=True, name="sqrt_ridge"),
        "margin": cp.Parameter(name="margin"),
    }
    objective = (
        cp.sum_squares(par["R"] @ pi - par["d"])
        + cp.sum_squares(cp.multiply(par["sqrt_dp"], pi) - par["prior_term"])
        + cp.sum_squares(cp.multiply(par["sqrt_ridge"], pi))
    )  # parameter inside: keeps it DPP
    constraints = []
    if mass:
        A0, A1 = model.mass_matrix_maps
        M0 = sum(pi[p] * A0[p] for p in range(P))
        M1 = sum(pi[p] * A1[p] for p in range(P))
        constraints += [M0 + M1 >> par["margin"] * np.eye(2), M0 - M1 >> par["margin"] * np.eye(2)]
    if friction:
        constraints.append(pi[[model.names.index(name) for name in sign_constraints(model).values()]] >= 0)
    if lower:
        par["lb"] = cp.Parameter(len(lower), name="lb")
        constraints.append(pi[list(lower)] >= par["lb"])
    if upper:
        par["ub"] = cp.Parameter(len(upper), name="ub")
        constraints.append(pi[list(upper)] <= par["ub"])
    problem = cp.Problem(cp.Minimize(objective), constraints)
    assert problem.is_dpp()  # otherwise every solve would recompile (tens of ms)
    return problem, pi, par


def _solve_conic(
    model: ArmModel,
    H: np.ndarray,
    h: np.ndarray,
    n: int,
    margin: float,
    Dp: np.ndarray,
    prior: np.ndarray,
    friction: bool,
    mass: bool,
    bounds: tuple[np.ndarray, np.ndarray] | None,
) -> tuple[np.ndarray | None, str, float]:
    """Fill the cached program's parameters and solve it with Clarabel: (π or None, status, solver s)."""
    import cvxpy as cp

    P = model.n_params
    lb, ub = (
        (np.full(P, -np.inf), np.full(P, np.inf))
        if bounds is None
        else (np.broadcast_to(np.asarray(v, dtype=float), (P,)) for v in bounds)
    )
    lower = tuple(int(i) for i in np.flatnonzero(np.isfinite(lb)))
    upper = tuple(int(i) for i in np.flatnonzero(np.isfinite(ub)))
    problem, pi, par = _program(model, friction, mass, lower, upper)
    R, d = _square_root(H, h)
    scale = 1.0 / max(n, 1)  # objective per sample: keeps the solver's numbers O(τ²)
    par["R"].value = np.vstack([R, np.zeros((P - R.shape[0], P))]) * np.sqrt(scale)
    par["d"].value = np.concatenate([d, np.zeros(P - d.size)]) * np.sqrt(scale)
    par["sqrt_dp"].value = np.sqrt(Dp * scale)
    par["prior_term"].value = par["sqrt_dp"].value * prior  # √D (π − π0) = √D π − √D π0 stays DPP
    # Data that leave directions free: the tie-break makes the minimiser unique (see `tie_break`).
    par["sqrt_ridge"].value = np.sqrt(tie_break(H) * scale)
    par["margin"].value = margin
    if lower:
        par["lb"].value = lb[list(lower)]
    if upper:
        par["ub"].value = ub[list(upper)]
    status = "not solved"
    # Tight tolerances first (the answer should match OLS to 1e-8 when nothing binds); looser ones if a
    # badly conditioned (e.g. rank-deficient) problem cannot reach them.
    for tol in (1e-11, 1e-8):
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
        return None, status, float("nan")
    return np.asarray(pi.value, dtype=float), status, float(problem.solver_stats.solve_time or np.nan)
