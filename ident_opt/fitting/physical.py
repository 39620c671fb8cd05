"""The plausible fit of an arm with per-link pseudo-inertias (a URDF arm): consistent, and near its CAD model.

Consistent is not yet plausible. Every link's pseudo-inertia J_i ⪰ 0 only says some density realises its
(m, h, Ī); the data see only the base parameters, so along the directions they cannot see a consistent fit
is free to put tens or hundreds of kilograms into an arm whose URDF says 14 kg. This fit adds what the CAD
model knows, on the standard parameters, with the base-parameter fit (the same statistics) as data term:

    minimise   (1/n) Σ_j w_j RSS_j(π)                                        data, per sample [N² m²]
             + λ · Ē · Σ_i [ tr(J_i0⁻¹ J_i(π)) − log det J_i(π) + log det J_i0 − 4 ]
    subject to the arm's consistency (`ident_opt.consistency`: J_i ⪰ margin·I, friction, armature ≥ 0),
               (1 − r) m_i0 ≤ m_i ≤ (1 + r) m_i0                            mass within ± r of the CAD's
               m_i (c_i0 − δ) ≤ h_i ≤ m_i (c_i0 + δ)                          centre of mass in a box [m]

The prior is the log-det (geometric) divergence of Lee, Wensing & Park (2020) between each link's
pseudo-inertia and the CAD one J_i0 (its eigenvalues floored at 1e-6 of its largest, for point masses):
zero at the CAD link, invariant to the frame and the units, and a barrier that keeps J_i ≻ 0. Its weight λ
(`prior_weight`) is dimensionless: Ē = Σ_j w_j s_j / n is the mean measured torque energy per sample
[N² m²], so at λ = 1 a unit divergence costs as much as all the measured torque. A small λ (default 1e-7)
is enough to pin the directions the data do not see. r (`mass_range`) and δ (`com_box`, metres per axis)
are optional (None: no bound).

Solved by Clarabel (PSD and exponential cones: log det J = max Σ_j log Z_jj over [[J, Z], [Zᵀ, diag Z]] ⪰ 0,
Z lower triangular), stated directly with its constraint rows cached per arm and options; the same program
through cvxpy (compiled once, data as Parameters) is the tests' oracle (`backend="cvxpy"`).
"""

from __future__ import annotations

import functools
import time
from typing import NamedTuple

import clarabel
import numpy as np
from scipy import sparse

from ident_opt.arm.chain import ChainArm
from ident_opt.arm.rnea import N_LINK
from ident_opt.consistency import MARGIN, Bound, Consistency, svec
from ident_opt.fitting.constrained import ACTIVE_TOL, solve_cvxpy
from ident_opt.fitting.fit import LinearFit, check_stats, finish, joint_weights, normal_equations
from ident_opt.fitting.stats import Stats

#: The default weight λ of the log-det prior (dimensionless, module doc).
PRIOR_WEIGHT = 1e-7
#: The default relative mass range r around the CAD masses, and centre-of-mass box half-width δ [m].
MASS_RANGE = 0.5
COM_BOX = 0.1
#: A bound missed by at most this (the parameter's unit) is solver round-off: the value is set to the bound.
ROUND_OFF = 1e-8
#: Eigenvalue floor of a CAD pseudo-inertia in the prior, relative to its largest eigenvalue.
PRIOR_FLOOR = 1e-6
#: Solver tolerances, tight first.
TOLERANCES = (1e-9, 1e-7)


def _square_root(H: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, d) (P, P), (P,) with ‖Rπ − d‖² = πᵀHπ − 2hᵀπ + const (H may be singular: rows of zero)."""
    lam, V = np.linalg.eigh(H)
    keep = lam > max(lam.max(), 0.0) * 1e-14
    R = np.zeros_like(H)
    d = np.zeros(len(h))
    R[: keep.sum()] = np.sqrt(lam[keep])[:, None] * V[:, keep].T
    d[: keep.sum()] = (V[:, keep].T @ h) / np.sqrt(lam[keep])
    return R, d


@functools.lru_cache(maxsize=8)
def _program(arm: ChainArm, margin: float, mass: bool, com: bool):
    """The cvxpy problem of the module doc for this arm (data, prior, bounds as Parameters), compiled once."""
    import cvxpy as cp  # deferred: cvxpy takes about a second to import and only this fit needs it

    P, n_links = arm.n_params, arm.n_joints
    pi = cp.Variable(P, name="pi")
    par = {
        "R": cp.Parameter((P, P), name="R"),
        "d": cp.Parameter(P, name="d"),
        "weight": cp.Parameter(nonneg=True, name="weight"),
        "J0inv": [cp.Parameter((4, 4), symmetric=True, name=f"J0inv_{i}") for i in range(n_links)],
        "m_lo": cp.Parameter(n_links, name="m_lo"),
        "m_hi": cp.Parameter(n_links, name="m_hi"),
        "c_lo": cp.Parameter((n_links, 3), name="c_lo"),
        "c_hi": cp.Parameter((n_links, 3), name="c_hi"),
    }
    A = arm.pseudo_inertia_map()
    constraints = Consistency.of(arm, margin).cvxpy(pi)
    prior = 0
    for i in range(n_links):
        p = pi[N_LINK * i : N_LINK * (i + 1)]
        J = sum(p[k] * A[k] for k in range(N_LINK))
        prior += cp.trace(par["J0inv"][i] @ J) - cp.log_det(J)
        m, h = p[0], p[1:4]
        if mass:
            constraints += [m >= par["m_lo"][i], m <= par["m_hi"][i]]
        if com:
            constraints += [h >= m * par["c_lo"][i], h <= m * par["c_hi"][i]]
    objective = cp.sum_squares(par["R"] @ pi - par["d"]) + par["weight"] * prior
    problem = cp.Problem(cp.Minimize(objective), constraints)
    return problem, pi, par


class _Data(NamedTuple):
    """The numbers of one solve: data term (H/n, h/n), the prior's weight w·Ē and each CAD J0⁻¹, the bounds."""

    H: np.ndarray  # (P, P) [N² m² per unit²] per sample
    h: np.ndarray  # (P,)
    weight: float
    J0inv: np.ndarray  # (links, 4, 4)
    m_lo: np.ndarray  # (links,) [kg]
    m_hi: np.ndarray
    c_lo: np.ndarray  # (links, 3) [m]
    c_hi: np.ndarray


def fit_physical(
    stats: Stats,
    arm: ChainArm,
    *,
    prior: np.ndarray | None = None,
    prior_weight: float = PRIOR_WEIGHT,
    mass_range: float | None = MASS_RANGE,
    com_box: float | None = COM_BOX,
    margin: float = MARGIN,
    weights: str | np.ndarray | None = None,
    backend: str = "clarabel",
) -> LinearFit:
    """The plausible consistent fit of the module doc from the statistics of `arm`'s regressor.

    prior (P,) = the URDF's inertials (`ChainArm.cad_parameters`); prior_weight λ > 0 [dimensionless];
    mass_range r (± fraction of each CAD mass) and com_box δ [m] (None: unbounded); margin: J_i ⪰ margin·I.
    backend "clarabel" (the conic program stated directly, cached per arm: tens of ms) or "cvxpy" (the same
    program through cvxpy: the tests' oracle). `details` holds the prior's weight, each link's divergence
    from the CAD link and its mass [kg].
    """
    check_stats(stats, arm)
    if prior_weight <= 0:
        raise ValueError("prior_weight must be > 0 (the log-det prior is what makes this fit plausible)")
    if backend not in ("clarabel", "cvxpy"):
        raise ValueError(f"backend must be 'clarabel' or 'cvxpy', not {backend!r}")
    prior = arm.cad_parameters() if prior is None else np.asarray(prior, dtype=float)
    w = joint_weights(stats, weights)
    data, J0 = _program_data(arm, stats, w, prior, prior_weight, mass_range, com_box)
    t0 = time.perf_counter()
    solve = _solve_clarabel if backend == "clarabel" else _solve_cvxpy
    pi, status = solve(arm, float(margin), mass_range is not None, com_box is not None, data)
    if pi is None:
        raise RuntimeError(f"plausible fit failed: solver status {status}")
    seconds = time.perf_counter() - t0
    value = _onto_bounds(pi, Consistency.of(arm, margin))
    slacks = Consistency.of(arm, margin).slacks(value)
    active = [name for name, v in slacks.items() if v < ACTIVE_TOL]
    active += _bounds_at(arm, value, data, mass_range is not None, com_box is not None)
    fit = finish(stats, arm, value, w, "consistent", status, active, seconds)
    fit.details.update(
        prior_weight=prior_weight,
        mass_range=mass_range,
        com_box_m=com_box,
        divergence={
            link: log_det_divergence(J, J0[i]) for i, (link, J) in enumerate(zip(arm.links, arm.pseudo_inertias(value)))
        },
        link_masses=arm.link_masses(value),
    )
    return fit


#: A link's mass or first moment within this relative distance of its bound counts as at the bound (active).
BOUND_TOL = 1e-6


def _bounds_at(arm: ChainArm, pi: np.ndarray, data: _Data, mass: bool, com: bool) -> list[str]:
    """The mass range and centre-of-mass box bounds π sits on, named like constraints: `mass_min_<link>`,
    `mass_max_<link>`, `com_<x|y|z>_min_<link>`, `com_<x|y|z>_max_<link>` (h within m·(c0 ± δ))."""
    links = np.asarray(pi[: arm.n_link_params], dtype=float).reshape(-1, N_LINK)
    out = []
    for i, link in enumerate(arm.links):
        m, h = links[i, 0], links[i, 1:4]
        if mass:
            for side, bound in (("min", data.m_lo[i]), ("max", data.m_hi[i])):
                if abs(m - bound) <= BOUND_TOL * max(1.0, abs(bound)):
                    out.append(f"mass_{side}_{link}")
        if com:
            for axis, name in enumerate("xyz"):
                for side, bound in (("min", data.c_lo[i, axis]), ("max", data.c_hi[i, axis])):
                    if abs(h[axis] - m * bound) <= BOUND_TOL * max(1.0, abs(m * bound)):
                        out.append(f"com_{name}_{side}_{link}")
    return out


def _program_data(
    arm: ChainArm,
    stats: Stats,
    w: np.ndarray,
    prior: np.ndarray,
    prior_weight: float,
    mass_range: float | None,
    com_box: float | None,
) -> tuple[_Data, np.ndarray]:
    """The numbers of the program (module doc) for these statistics, joint weights `w` and prior π0: its data term
    per sample, the prior's weight λ Ē, each link's J0⁻¹, mass bounds [kg] and centre-of-mass box [m]; and the
    regularised CAD pseudo-inertias J0 (L, 4, 4)."""
    H, h = normal_equations(stats, w)
    n = max(stats.n, 1)
    J0 = np.array([_regularised(J) for J in arm.pseudo_inertias(prior)])
    masses = prior[: arm.n_link_params : N_LINK]
    com0 = prior[: arm.n_link_params].reshape(-1, N_LINK)[:, 1:4] / np.maximum(masses, 1e-12)[:, None]
    r = 0.0 if mass_range is None else float(mass_range)
    delta = 0.0 if com_box is None else float(com_box)
    data = _Data(
        H / n,
        h / n,
        prior_weight * float(w @ stats.s) / n,
        np.linalg.inv(J0),
        (1 - r) * masses,
        (1 + r) * masses,
        com0 - delta,
        com0 + delta,
    )
    return data, J0


def _solve_cvxpy(arm: ChainArm, margin: float, mass: bool, com: bool, data: _Data) -> tuple[np.ndarray | None, str]:
    """The program through cvxpy (compiled once per arm and options): (π or None, status)."""

    problem, pi, par = _program(arm, margin, mass, com)
    par["R"].value, par["d"].value = _square_root(data.H, data.h)
    par["weight"].value = data.weight
    for i, Jinv in enumerate(data.J0inv):
        par["J0inv"][i].value = 0.5 * (Jinv + Jinv.T)
    par["m_lo"].value, par["m_hi"].value = data.m_lo, data.m_hi
    par["c_lo"].value, par["c_hi"].value = data.c_lo, data.c_hi
    return solve_cvxpy(problem, pi, TOLERANCES)


# ---------------------------------------------------------------------------------------------- Clarabel
#: Per link, the extra variables of the log-det: the lower triangle of Z (10) and u (4), log Z_jj ≥ u_j.
_EXTRA = 14
_TRIL = tuple((r, c) for c in range(4) for r in range(c, 4))  # Z's lower-triangle entries, in x's order


@functools.lru_cache(maxsize=8)
def _conic(arm: ChainArm, margin: float, mass: bool, com: bool) -> tuple:
    """What Clarabel needs that depends on the arm and options only: the fixed constraint rows (A, b), their
    cones, and per link the column of each variable (module doc: log det J = max Σ_j u_j over
    [[J, Z], [Zᵀ, diag Z]] ⪰ 0 with Z lower triangular and (u_j, 1, Z_jj) in the exponential cone)."""
    P, links = arm.n_params, arm.n_joints
    nx = P + _EXTRA * links
    blocks, cones = [], []
    for blk in Consistency.of(arm, margin).blocks():  # pseudo-inertias ⪰ margin, friction and armature ≥ 0
        blocks.append((np.hstack([blk.A, np.zeros((blk.A.shape[0], nx - P))]), blk.b))
        cones.append(clarabel.PSDTriangleConeT(blk.size) if blk.cone == "psd" else clarabel.NonnegativeConeT(blk.size))
    A_link = arm.pseudo_inertia_map()
    for i in range(links):
        C = np.zeros((nx, 8, 8))  # [[J, Z], [Zᵀ, diag Z]] = Σ_v x_v C_v
        C[N_LINK * i : N_LINK * (i + 1), :4, :4] = A_link
        z0 = P + _EXTRA * i
        for k, (r, c) in enumerate(_TRIL):
            C[z0 + k, r, 4 + c] = C[z0 + k, 4 + c, r] = 1.0
            if r == c:
                C[z0 + k, 4 + c, 4 + c] = 1.0
        blocks.append((-svec(C).T, np.zeros(36)))
        cones.append(clarabel.PSDTriangleConeT(8))
        for j in range(4):
            rows = np.zeros((3, nx))
            rows[0, z0 + 10 + j] = -1.0  # s = (u_j, 1, Z_jj)
            rows[2, z0 + _TRIL.index((j, j))] = -1.0
            blocks.append((rows, np.array([0.0, 1.0, 0.0])))
            cones.append(clarabel.ExponentialConeT())
    A = np.vstack([a for a, _ in blocks])
    b = np.concatenate([v for _, v in blocks])
    settings = []
    for tol in TOLERANCES:
        st = clarabel.DefaultSettings()
        st.verbose = False
        st.tol_gap_abs = st.tol_gap_rel = st.tol_feas = tol
        st.max_iter = 500
        settings.append(st)
    return A, b, tuple(cones), tuple(settings)


def _bound_rows(arm: ChainArm, mass: bool, com: bool, data: _Data, nx: int) -> tuple[np.ndarray, np.ndarray]:
    """The mass and centre-of-mass rows (s = b − A x ≥ 0): m_lo ≤ m ≤ m_hi, m c_lo ≤ h ≤ m c_hi."""
    rows, rhs = [], []
    for i in range(arm.n_joints):
        m = N_LINK * i
        if mass:
            lo, hi = np.zeros(nx), np.zeros(nx)
            lo[m], hi[m] = -1.0, 1.0
            rows += [lo, hi]
            rhs += [-data.m_lo[i], data.m_hi[i]]
        if com:
            for k in range(3):
                lo, hi = np.zeros(nx), np.zeros(nx)
                lo[m + 1 + k], lo[m] = -1.0, data.c_lo[i, k]
                hi[m + 1 + k], hi[m] = 1.0, -data.c_hi[i, k]
                rows += [lo, hi]
                rhs += [0.0, 0.0]
    return np.array(rows).reshape(-1, nx), np.array(rhs)


def _solve_clarabel(arm: ChainArm, margin: float, mass: bool, com: bool, data: _Data) -> tuple[np.ndarray | None, str]:
    """min ½ xᵀ Q x + qᵀ x over x = [π; Z, u per link] with Clarabel directly: (π or None, status).

    Q = 2 H/n on π; q = −2 h/n + w·Ē tr(J0⁻¹ A_p) on the link parameters and −w·Ē on every u (module doc)."""
    A_fixed, b_fixed, cones, settings = _conic(arm, margin, mass, com)
    P, nx = arm.n_params, A_fixed.shape[1]
    A_bounds, b_bounds = _bound_rows(arm, mass, com, data, nx)
    A = sparse.csc_matrix(np.vstack([A_fixed, A_bounds]))
    b = np.concatenate([b_fixed, b_bounds])
    all_cones = [*cones, clarabel.NonnegativeConeT(len(b_bounds))] if len(b_bounds) else list(cones)
    Q = np.zeros((nx, nx))
    Q[:P, :P] = 2.0 * data.H
    q = np.zeros(nx)
    q[:P] = -2.0 * data.h
    A_link = arm.pseudo_inertia_map()
    for i, Jinv in enumerate(data.J0inv):
        q[N_LINK * i : N_LINK * (i + 1)] += data.weight * np.einsum("ij,pji->p", Jinv, A_link)
        z0 = P + _EXTRA * i
        q[z0 + 10 : z0 + _EXTRA] = -data.weight
    Qs = sparse.triu(sparse.csc_matrix(Q), format="csc")
    status = "not solved"
    for st in settings:
        solution = clarabel.DefaultSolver(Qs, q, A, b, all_cones, st).solve()
        status = str(solution.status)
        if status == "Solved":
            break
    if status not in ("Solved", "AlmostSolved"):
        return None, status
    return np.asarray(solution.x[:P], dtype=float), status


def _regularised(J0: np.ndarray) -> np.ndarray:
    """A CAD pseudo-inertia with its eigenvalues floored at `PRIOR_FLOOR` × the largest: a point mass or a
    rod (rank-deficient J0, e.g. a URDF's zero inertia tensor) has no log-det divergence otherwise."""
    lam, V = np.linalg.eigh(J0)
    return (V * np.maximum(lam, PRIOR_FLOOR * max(lam.max(), 1e-12))) @ V.T


def _onto_bounds(pi: np.ndarray, consistency: Consistency) -> np.ndarray:
    """π with the sign and box bounds it misses by solver round-off (≤ `ROUND_OFF`) set to the bound exactly."""
    out = pi.copy()
    for c in consistency.constraints:
        if isinstance(c, Bound) and -ROUND_OFF <= c.slack(out) < 0:
            out[c.index] = c.value
    return out


def log_det_divergence(J: np.ndarray, J0: np.ndarray) -> float:
    """tr(J0⁻¹ J) − log det(J0⁻¹ J) − 4 ≥ 0 (0 iff J = J0); inf if J is not positive definite."""
    sign, logdet = np.linalg.slogdet(np.linalg.solve(J0, J))
    if sign <= 0:
        return float("inf")
    return float(np.trace(np.linalg.solve(J0, J)) - logdet - 4.0)
