"""The result of a linear-in-π fit, and OLS with what a practitioner needs to trust it.

Everything is computed from the sufficient statistics (`Stats`): per joint j, G_j = Σ Y_jᵀY_j,
b_j = Σ Y_jᵀτ_j, s_j = Σ τ_j², n. With joint weights w_j the normal equations are H π = h, where
H = Σ_j w_j G_j and h = Σ_j w_j b_j.

Standard errors use a residual variance per joint (the two joints have different noise and model error):
σ_j² = RSS_j / dof_j with dof_j = n − w_j tr(H⁺ G_j) (the joint's share of the hat matrix's trace, so the
dofs add up to 2n − rank), and Cov(π̂) = H⁺ (Σ_j w_j² σ_j² G_j) H⁺ (the sandwich; it reduces to H⁻¹ for
WLS with w_j = 1/σ_j²). They assume independent residuals: on densely sampled real trials, where
consecutive residuals are correlated, they are optimistic; read them as a lower bound.

Conditioning is judged on the column-equilibrated regressor (each column scaled to unit norm), so units
(kg m² next to N m) do not decide what counts as "poorly determined".
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
import scipy.linalg

from ident_opt.identify.stats import Stats
from ident_opt.robot import ArmModel

#: Columns whose squared norm is below this fraction of the largest are "not excited".
UNEXCITED = 1e-12
#: Singular values of the equilibrated regressor below this fraction of the largest count as zero.
RANK_TOL = 1e-7
#: A parameter whose standard error exceeds this fraction of its magnitude is "poorly determined".
POOR_RELATIVE_SE = 0.5


@dataclass
class LinearFit:
    """Identified π with its uncertainty and diagnostics. Units: a [kg m²], b [N m], fv [N m s/rad],
    fc [N m]; `sigma2` [N² m²] per joint."""

    pi: np.ndarray
    names: tuple[str, ...]
    se: np.ndarray
    sigma2: np.ndarray
    active: list[str] = field(default_factory=list)
    method: str = "ols"
    status: str = "optimal"
    weights: np.ndarray = field(default_factory=lambda: np.ones(2))
    n: int = 0
    rss: np.ndarray = field(default_factory=lambda: np.zeros(2))
    cond: float = float("nan")  # condition number of the column-equilibrated regressor
    rank: int = 0
    unexcited: list[str] = field(default_factory=list)
    base: list[str] = field(default_factory=list)  # identifiable combinations when rank < P
    poorly_determined: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    min_mass_eigenvalue: float = float("nan")  # min over q of λ_min(M(q)) [kg m²]
    solve_seconds: float = float("nan")
    details: dict = field(default_factory=dict)  # estimator-specific extras (e.g. physical parameters)

    def as_dict(self) -> dict[str, float]:
        """π by name."""
        return {name: float(v) for name, v in zip(self.names, self.pi)}

    def se_dict(self) -> dict[str, float]:
        """Standard errors by name."""
        return {name: float(v) for name, v in zip(self.names, self.se)}

    @property
    def friction_ok(self) -> bool:
        """All friction parameters (fv*, fc*, fs*) ≥ 0."""
        return all(v >= 0 for name, v in self.as_dict().items() if name.startswith("f"))

    @property
    def armature_ok(self) -> bool:
        """All reflected rotor inertias (ia*) ≥ 0."""
        return all(v >= 0 for name, v in self.as_dict().items() if name.startswith("ia"))

    @property
    def consistent(self) -> bool:
        """Physically consistent: M(q) ≻ 0 for every q, friction ≥ 0 and armature ≥ 0."""
        return bool(self.min_mass_eigenvalue > 0 and self.friction_ok and self.armature_ok)

    def summary(self) -> dict:
        """A JSON-friendly dict of everything (arrays as lists, π and SE by name)."""
        out = {k: v for k, v in asdict(self).items() if k not in ("pi", "se", "names")}
        out = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in out.items()}
        out.update(parameters=self.as_dict(), se=self.se_dict(), consistent=self.consistent)
        return out


# ---------------------------------------------------------------------------------------------- weights
def joint_weights(stats: Stats, weights: str | np.ndarray | None) -> np.ndarray:
    """Per-joint weights: None → (1, 1); "wls" → 1/σ_j² from a first OLS pass; an array (2,) as given."""
    if weights is None:
        return np.ones(2)
    if isinstance(weights, str):
        if weights != "wls":
            raise ValueError(f"weights must be None, 'wls' or an array of 2, not {weights!r}")
        first = _solve(*_normal(stats, np.ones(2)))
        sigma2 = _sigma2(stats, first, np.ones(2))
        return 1.0 / np.maximum(sigma2, 1e-300)
    w = np.asarray(weights, dtype=float)
    if w.shape != (2,) or not np.all(w > 0):
        raise ValueError("joint weights must be two positive numbers")
    return w


def _normal(stats: Stats, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def _solve(H: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Least-norm (in equilibrated units) solution of H π = h."""
    return _pinv(H) @ h


def _sigma2(stats: Stats, pi: np.ndarray, w: np.ndarray) -> np.ndarray:
    H, _ = _normal(stats, w)
    Hp = _pinv(H)
    dof = stats.n - w * np.array([np.trace(Hp @ stats.G[j]) for j in range(2)])
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
    model: ArmModel,
    pi: np.ndarray,
    w: np.ndarray,
    method: str,
    status: str = "optimal",
    active: list[str] | None = None,
    solve_seconds: float = float("nan"),
) -> LinearFit:
    """A LinearFit for `pi` with standard errors and diagnostics from the statistics (see module doc)."""
    names = model.names
    H, _ = _normal(stats, w)
    Hp = _pinv(H)
    sigma2 = _sigma2(stats, pi, w)
    meat = sum(w[j] ** 2 * sigma2[j] * stats.G[j] for j in range(2))
    cov = Hp @ meat @ Hp
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
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
        cond=cond,
        rank=rank,
        unexcited=unexcited,
        base=base,
        poorly_determined=poor,
        warnings=warnings,
        min_mass_eigenvalue=model.min_mass_eigenvalue(pi),
        solve_seconds=solve_seconds,
    )
    if not fit.consistent:
        what = []
        if fit.min_mass_eigenvalue <= 0:
            what.append(f"M(q) is not positive definite (min eigenvalue {fit.min_mass_eigenvalue:.3g} kg m²)")
        for ok, kind, prefix in ((fit.friction_ok, "friction", "f"), (fit.armature_ok, "armature", "ia")):
            if not ok:
                what.append(
                    f"negative {kind}: "
                    + ", ".join(n for n, v in fit.as_dict().items() if n.startswith(prefix) and v < 0)
                )
        fit.warnings.append("physically inconsistent: " + "; ".join(what))
    return fit


# ---------------------------------------------------------------------------------------------- OLS
def fit_ols(stats: Stats, model: ArmModel, weights: str | np.ndarray | None = None) -> LinearFit:
    """(Weighted) least squares π̂ = argmin Σ_j w_j Σ_k (τ_kj − Y_kj π)² from the statistics.

    `weights`: None (plain OLS), "wls" (w_j = 1/σ_j² from a first OLS pass: joints with less noise count
    more) or an array of two positive numbers. Least-norm (equilibrated) if the data do not excite every
    direction; the fit's `base` and `warnings` then say what is identifiable.
    """
    import time

    _check(stats, model)
    w = joint_weights(stats, weights)
    t0 = time.perf_counter()
    pi = _solve(*_normal(stats, w))
    elapsed = time.perf_counter() - t0
    return finish(stats, model, pi, w, "wls" if weights is not None else "ols", solve_seconds=elapsed)


def _check(stats: Stats, model: ArmModel) -> None:
    P = model.n_params
    if stats.G.shape != (2, P, P):
        raise ValueError(f"statistics for {stats.G.shape[-1]} parameters, model {model.names} has {P}")
    if stats.n <= 0:
        raise ValueError("no samples in the statistics")
