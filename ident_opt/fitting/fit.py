"""The result of a linear-in-π fit, and OLS with what a practitioner needs to trust it.

Everything is computed from the sufficient statistics (`Stats`): per joint j, G_j = Σ Y_jᵀY_j,
b_j = Σ Y_jᵀτ_j, s_j = Σ τ_j², n. With joint weights w_j the normal equations are H π = h, where
H = Σ_j w_j G_j and h = Σ_j w_j b_j.

Standard errors use a residual variance per joint (joints have different noise and model error):
σ_j² = RSS_j / dof_j with dof_j = n − w_j tr(H⁺ G_j) (the joint's share of the hat matrix's trace, so the
dofs of J joints add up to J·n − rank), and Cov(π̂) = H⁺ (Σ_j w_j² σ_j² G_j) H⁺ (the sandwich; it reduces to H⁻¹ for
WLS with w_j = 1/σ_j²). They assume independent residuals: on densely sampled real trials, where
consecutive residuals are correlated, they are optimistic; read them as a lower bound.

Conditioning is judged on the column-equilibrated regressor (each column scaled to unit norm), so units
(kg m² next to N m) do not decide what counts as "poorly determined".

Physical consistency is judged by the one statement of it (`ident_opt.consistency`): M(q) ≻ 0 for every q
(`Arm.min_mass_eigenvalue` > 0) and the sign constraints of the parameters' declared kinds.

`check_stats`, `normal_equations` and `solve_normal` are shared with the other estimators.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np
import scipy.linalg

from ident_opt import consistency
from ident_opt.arm.base import Arm
from ident_opt.fitting.stats import Stats
from ident_opt.parameters import Parameter

#: Columns whose squared norm is below this fraction of the largest are "not excited".
UNEXCITED = 1e-12
#: Singular values of the equilibrated regressor below this fraction of the largest count as zero.
RANK_TOL = 1e-7
#: A parameter whose standard error exceeds this fraction of its magnitude is "poorly determined".
POOR_RELATIVE_SE = 0.5


@dataclass
class LinearFit:
    """Identified π with its uncertainty and diagnostics. Units: each parameter's own (`Parameter.unit`;
    a [kg m²], b [N m], fv [N m s/rad], fc [N m]); `sigma2`, `rss` [N² m²] and `weights` per joint."""

    pi: np.ndarray
    names: tuple[str, ...]
    se: np.ndarray
    sigma2: np.ndarray
    active: list[str] = field(default_factory=list)
    method: str = "ols"
    status: str = "optimal"
    weights: np.ndarray = field(default_factory=lambda: np.ones(0))
    n: int = 0
    rss: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cond: float = float("nan")  # condition number of the column-equilibrated regressor
    rank: int = 0
    unexcited: list[str] = field(default_factory=list)
    base: list[str] = field(default_factory=list)  # identifiable combinations when rank < P
    poorly_determined: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    min_mass_eigenvalue: float = float("nan")  # min over q of λ_min(M(q)) [kg m²]
    solve_seconds: float = float("nan")
    details: dict = field(default_factory=dict)  # estimator-specific extras (e.g. physical parameters)
    parameters: tuple[Parameter, ...] = ()  # the arm's declarations (their kinds decide the sign checks)

    def as_dict(self) -> dict[str, float]:
        """π by name."""
        return {name: float(v) for name, v in zip(self.names, self.pi)}

    def se_dict(self) -> dict[str, float | None]:
        """Standard errors by name; None where there is none (the data do not determine the parameter)."""
        return {name: float(v) if np.isfinite(v) else None for name, v in zip(self.names, self.se)}

    @property
    def sign_violations(self) -> dict[str, list[str]]:
        """Kind → its sign-constrained parameters that are negative (`consistency.sign_violations`)."""
        return consistency.sign_violations(self.parameters, self.pi)

    @property
    def friction_ok(self) -> bool:
        """All parameters of kind friction (viscous, Coulomb, Stribeck, ...) ≥ 0."""
        return "friction" not in self.sign_violations

    @property
    def armature_ok(self) -> bool:
        """All parameters of kind armature (reflected rotor inertias) ≥ 0."""
        return "armature" not in self.sign_violations

    @property
    def consistent(self) -> bool:
        """Physically consistent: M(q) ≻ 0 for every q and every sign constraint (friction, armature) holds."""
        return bool(self.min_mass_eigenvalue > 0 and not self.sign_violations)

    def summary(self) -> dict:
        """A JSON-friendly dict of everything (arrays as lists, π and SE by name)."""
        out = {k: v for k, v in asdict(self).items() if k not in ("pi", "se", "names", "parameters")}
        out = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in out.items()}
        out.update(parameters=self.as_dict(), se=self.se_dict(), consistent=self.consistent)
        return out


# ---------------------------------------------------------------------------------------------- weights
def joint_weights(stats: Stats, weights: str | np.ndarray | None) -> np.ndarray:
    """Per-joint weights (J,): None → all 1; "wls" → 1/σ_j² [1/(N² m²)] from a first OLS pass; an array as given."""
    ones = np.ones(stats.n_joints)
    if weights is None:
        return ones
    if isinstance(weights, str):
        if weights != "wls":
            raise ValueError(f"weights must be None, 'wls' or an array of {len(ones)}, not {weights!r}")
        first = solve_normal(*normal_equations(stats, ones))
        sigma2 = _sigma2(stats, first, ones)
        return 1.0 / np.maximum(sigma2, 1e-300)
    w = np.asarray(weights, dtype=float)
    if w.shape != ones.shape or not np.all(w > 0):
        raise ValueError(f"joint weights must be {len(ones)} positive numbers")
    return w


def normal_equations(stats: Stats, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(H, h) = (Σ_j w_j G_j, Σ_j w_j b_j): the normal equations H π = h of the weighted fit."""
    G, b, _ = stats.combined(w)
    return G, b


def _equilibration(H: np.ndarray) -> np.ndarray:
    """D with D H D having unit diagonal on excited columns (0 for columns with no energy)."""
    d = np.diag(H).copy()
    excited = d > UNEXCITED * max(d.max(), np.finfo(float).tiny)
    out = np.zeros_like(d)
    out[excited] = 1.0 / np.sqrt(d[excited])
    return out


def _pinv(H: np.ndarray) -> np.ndarray:
    """H⁺ computed on the equilibrated matrix, dropping directions below the rank tolerance."""
    D = _equilibration(H)
    Hs = D[:, None] * H * D[None, :]
    return D[:, None] * np.linalg.pinv(Hs, rcond=RANK_TOL**2, hermitian=True) * D[None, :]


def solve_normal(H: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Least-norm (in equilibrated units) solution π of H π = h."""
    return _pinv(H) @ h


def _sigma2(stats: Stats, pi: np.ndarray, w: np.ndarray) -> np.ndarray:
    H, _ = normal_equations(stats, w)
    Hp = _pinv(H)
    dof = stats.n - w * np.array([np.trace(Hp @ G_j) for G_j in stats.G])
    return np.maximum(stats.rss(pi), 0.0) / np.maximum(dof, 1.0)


# ---------------------------------------------------------------------------------------------- diagnostics
def base_combinations(H: np.ndarray, names: tuple[str, ...]) -> tuple[int, float, list[str], list[str]]:
    """(rank, condition number, unexcited names, base combinations) of the regressor behind H = YᵀY.

    Pivoted QR of a square root of the equilibrated H picks independent columns (the base parameters);
    each dependent column k satisfies Y_k = Σ_i c_ik Y_i, so what the data determine is
    π_i + Σ_k c_ik π_k. Only the non-trivial combinations are listed.
    """
    D = _equilibration(H)
    excited = D > 0
    unexcited = [n for n, e in zip(names, excited) if not e]
    Hs = D[:, None] * H * D[None, :]
    lam, V = np.linalg.eigh(Hs)
    lam = np.clip(lam, 0.0, None)
    s = np.sqrt(lam[::-1])  # singular values of the equilibrated regressor, descending
    keep = s > RANK_TOL * s[0] if s[0] > 0 else np.zeros_like(s, dtype=bool)
    rank = int(keep.sum())
    cond = float(s[0] / s[rank - 1]) if rank else float("inf")
    idx = np.flatnonzero(excited)
    if rank == len(names) or rank == 0:
        return rank, cond, unexcited, []
    # R: a P×P square root of Hs restricted to the excited columns (RᵀR = Hs), then pivoted QR.
    R = (np.sqrt(lam)[:, None] * V.T)[:, idx]
    _, Rq, perm = scipy.linalg.qr(R, pivoting=True)
    r = rank
    indep, dep = idx[perm[:r]], idx[perm[r:]]
    coef = np.linalg.solve(Rq[:r, :r], Rq[:r, r:])  # Y_dep (equilibrated) = Y_indep @ coef
    base = []
    for a, i in enumerate(indep):
        terms = [names[i]]
        for b_, k in enumerate(dep):
            c = coef[a, b_] * D[i] / D[k]  # back to physical units: π_i + c π_k
            if abs(coef[a, b_]) > 1e-6:
                terms.append(f"{c:+.4g}·{names[k]}")
        if len(terms) > 1:
            base.append(" ".join(terms))
    return rank, cond, unexcited, base


def finish(
    stats: Stats,
    model: Arm,
    pi: np.ndarray,
    w: np.ndarray,
    method: str,
    status: str = "optimal",
    active: list[str] | None = None,
    solve_seconds: float = float("nan"),
) -> LinearFit:
    """A LinearFit for `pi` with standard errors and diagnostics from the statistics (see module doc)."""
    names = model.names
    H, _ = normal_equations(stats, w)
    Hp = _pinv(H)
    sigma2 = _sigma2(stats, pi, w)
    meat = sum(w_j**2 * s2_j * G_j for w_j, s2_j, G_j in zip(w, sigma2, stats.G))
    # Correlated residuals (torques low-passed with the derivatives) carry fewer independent values than samples.
    cov = Hp @ meat @ Hp * max(1.0, stats.n / stats.effective if stats.effective else 1.0)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    # A parameter the data do not determine (its direction leaves the regressor's row space) has no standard
    # error: what sets it is the estimator (a prior, a bound, the least-norm choice), not the data. Not "± 0".
    undetermined = not_determined(H)
    se[undetermined] = np.nan
    fit = LinearFit(
        pi=np.asarray(pi, dtype=float),
        names=names,
        se=se,
        sigma2=sigma2,
        active=list(active or []),
        method=method,
        status=status,
        weights=w,
        n=stats.n,
        rss=stats.rss(pi),
        min_mass_eigenvalue=model.min_mass_eigenvalue(pi),
        solve_seconds=solve_seconds,
        parameters=model.parameters,
        **_diagnostics(H, names, pi, se),
    )
    if undetermined.any():
        fit.details["not_determined"] = [n for n, u in zip(names, undetermined) if u]
    if not fit.consistent:
        fit.warnings.append(_inconsistency(fit))
    return fit


def not_determined(H: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    """(P,) bool: the parameters whose unit direction is not in the row space of the regressor behind H = YᵀY
    (judged on the equilibrated H, `RANK_TOL`): the data alone do not fix them, whatever the others are."""
    D = _equilibration(H)
    Hs = D[:, None] * H * D[None, :]
    lam, V = np.linalg.eigh(Hs)
    null = V[:, lam <= RANK_TOL**2 * max(lam.max(), 0.0)] if lam.max() > 0 else V
    return np.linalg.norm(null, axis=1) > tol


def _diagnostics(H: np.ndarray, names: tuple[str, ...], pi: np.ndarray, se: np.ndarray) -> dict:
    """LinearFit's identifiability fields: rank, cond, unexcited, base (`base_combinations`), the poorly
    determined names and the warnings about both."""
    rank, cond, unexcited, base = base_combinations(H, names)
    warnings: list[str] = []
    # A parameter in a not-identifiable direction has no meaningful SE: flag it by name.
    free = set(unexcited)
    if rank < len(names):
        free |= {t.split("·")[-1] for b in base for t in b.split() if "·" in t}
        warnings.append(
            f"the data excite only {rank} of {len(names)} parameter directions; identifiable: "
            + ("; ".join(base) if base else "the excited columns")
            + (f"; not excited: {', '.join(unexcited)}" if unexcited else "")
        )
    poor = [n for n, v, e in zip(names, pi, se) if n in free or e > POOR_RELATIVE_SE * abs(v)]
    if poor:
        warnings.append("poorly determined (SE > 50% of |value| or not identifiable): " + ", ".join(poor))
    return {
        "rank": rank,
        "cond": cond,
        "unexcited": unexcited,
        "base": base,
        "poorly_determined": poor,
        "warnings": warnings,
    }


def _inconsistency(fit: LinearFit) -> str:
    """The warning for an inconsistent fit: which part of `ident_opt.consistency` it violates."""
    what = []
    if fit.min_mass_eigenvalue <= 0:
        what.append(f"M(q) is not positive definite (min eigenvalue {fit.min_mass_eigenvalue:.3g} kg m²)")
    what += [f"negative {kind}: " + ", ".join(names) for kind, names in fit.sign_violations.items()]
    return "physically inconsistent: " + "; ".join(what)


# ---------------------------------------------------------------------------------------------- OLS
def fit_ols(stats: Stats, model: Arm, weights: str | np.ndarray | None = None) -> LinearFit:
    """(Weighted) least squares π̂ = argmin Σ_j w_j Σ_k (τ_kj − Y_kj π)² from the statistics.

    `weights`: None (plain OLS), "wls" (w_j = 1/σ_j² from a first OLS pass: joints with less noise count
    more) or an array of positive numbers, one per joint. Least-norm (equilibrated) if the data do not
    excite every direction; the fit's `base` and `warnings` then say what is identifiable.
    """
    check_stats(stats, model)
    w = joint_weights(stats, weights)
    t0 = time.perf_counter()
    pi = solve_normal(*normal_equations(stats, w))
    elapsed = time.perf_counter() - t0
    return finish(stats, model, pi, w, "wls" if weights is not None else "ols", solve_seconds=elapsed)


def check_stats(stats: Stats, model: Arm) -> None:
    """Raise ValueError unless the statistics are for this arm (J = n_joints, P = n_params) and hold samples."""
    P = model.n_params
    if stats.G.shape != (model.n_joints, P, P):
        raise ValueError(
            f"statistics for {stats.G.shape[-1]} parameters and {stats.G.shape[0]} joints, "
            f"model {model.names} has {P} and {model.n_joints}"
        )
    if stats.n <= 0:
        raise ValueError("no samples in the statistics")
