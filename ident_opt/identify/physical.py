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

Solved with Clarabel through cvxpy (the PSD and exponential cones of the log-det), compiled once per arm and
options (data, prior and bounds enter as cvxpy Parameters).
"""

from __future__ import annotations

import functools
import time
import warnings

import numpy as np

from ident_opt.consistency import MARGIN, Bound, Consistency
from ident_opt.identify.constrained import ACTIVE_TOL
from ident_opt.identify.fit import LinearFit, check_stats, finish, joint_weights, normal_equations
from ident_opt.identify.stats import Stats
from ident_opt.rnea import N_LINK
from ident_opt.urdf_arm import UrdfArm

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
def _program(arm: UrdfArm, margin: float, mass: bool, com: bool):
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


def fit_physical(
    stats: Stats,
    arm: UrdfArm,
    *,
    prior: np.ndarray | None = None,
    prior_weight: float = PRIOR_WEIGHT,
    mass_range: float | None = MASS_RANGE,
    com_box: float | None = COM_BOX,
    margin: float = MARGIN,
    weights: str | np.ndarray | None = None,
) -> LinearFit:
    """The plausible consistent fit of the module doc from the statistics of `arm`'s regressor.

    prior (P,) = the URDF's inertials (`UrdfArm.cad_parameters`); prior_weight λ > 0 [dimensionless];
    mass_range r (± fraction of each CAD mass) and com_box δ [m] (None: unbounded); margin: J_i ⪰ margin·I.
    `details` holds the prior's weight, each link's divergence from the CAD link and its mass [kg].
    """
    import cvxpy as cp  # deferred: see `_program`

    check_stats(stats, arm)
    if prior_weight <= 0:
        raise ValueError("prior_weight must be > 0 (the log-det prior is what makes this fit plausible)")
    prior = arm.cad_parameters() if prior is None else np.asarray(prior, dtype=float)
    w = joint_weights(stats, weights)
    H, h = normal_equations(stats, w)
    n = max(stats.n, 1)
    problem, pi, par = _program(arm, float(margin), mass_range is not None, com_box is not None)
    R, d = _square_root(H / n, h / n)
    par["R"].value, par["d"].value = R, d
    par["weight"].value = prior_weight * float(w @ stats.s) / n
    J0 = np.array([_regularised(J) for J in arm.pseudo_inertias(prior)])
    masses = prior[: arm.n_link_params : N_LINK]
    com0 = prior[: arm.n_link_params].reshape(-1, N_LINK)[:, 1:4] / np.maximum(masses, 1e-12)[:, None]
    for i, J in enumerate(J0):
        par["J0inv"][i].value = np.linalg.inv(J)
    r = 0.0 if mass_range is None else float(mass_range)
    delta = 0.0 if com_box is None else float(com_box)
    par["m_lo"].value, par["m_hi"].value = (1 - r) * masses, (1 + r) * masses
    par["c_lo"].value, par["c_hi"].value = com0 - delta, com0 + delta
    t0 = time.perf_counter()
    status = "not solved"
    for tol in TOLERANCES:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)
                problem.solve(solver="CLARABEL", tol_gap_abs=tol, tol_gap_rel=tol, tol_feas=tol, max_iter=500)
        except cp.error.SolverError as exc:
            status = f"solver error: {exc}"
            continue
        status = str(problem.status)
        if pi.value is not None and status == "optimal":
            break
    if pi.value is None or status not in ("optimal", "optimal_inaccurate"):
        raise RuntimeError(f"plausible fit failed: solver status {status}")
    seconds = time.perf_counter() - t0
    value = _onto_bounds(np.asarray(pi.value, dtype=float), Consistency.of(arm, margin))
    slacks = Consistency.of(arm, margin).slacks(value)
    active = [name for name, v in slacks.items() if v < ACTIVE_TOL]
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
