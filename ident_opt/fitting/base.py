"""Base parameters: the combinations of the standard parameters that joint torques can determine at all.

For an arm from a URDF many of the 10 inertial parameters per link never affect τ (a link's inertia about
an axis it cannot turn about) or affect it only together with others (what a child adds to its parent).
Which, is a property of the kinematics alone, found numerically:

1. stack the regressor W (N·n, P) at N random states (q uniform in [−π, π] rad, dq, ddq standard normal);
2. scale each column to unit norm (units differ: kg next to kg m²), drop zero columns;
3. QR with column pivoting, W D Π = Q R: the numerical rank B is the number of |R_ii| > `TOLERANCE` |R_00|,
   the first B pivots are the independent columns, the others satisfy W_dep = W_ind β with
   β = R₁₁⁻¹ R₁₂ (rescaled to physical units).

So Y π = Y_ind (π_ind + β π_dep): the base parameters are π_b = π_ind + β π_dep (B,), each named after its
independent standard parameter, with its `definition` as that combination. OLS on them is a least-squares
fit of Y_ind (full column rank on any exciting data) with standard errors; its map back to standard
parameters sets the dependent ones to 0 (any π with the same π_b predicts the same torques).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from ident_opt.arm.base import Arm
from ident_opt.fitting.fit import LinearFit, fit_ols
from ident_opt.fitting.iv import InstrumentStats
from ident_opt.fitting.stats import Stats
from ident_opt.parameters import Parameter

#: |R_ii| below this fraction of |R_00| (column-scaled pivoted QR) counts as a dependent column.
TOLERANCE = 1e-8
#: Random states stacked per identification of the base parameters, and their seed.
N_STATES = 200
SEED = 0
#: Coefficients of a definition below this (relative) are written as 0.
SMALL = 1e-9
#: A column whose norm is below this fraction of the largest one is round-off: a zero column.
ZERO_COLUMN = 1e-10


@dataclass(frozen=True, eq=False)
class BaseParameters:
    """The base parameters of an arm: π_b = K π (B,) with K (B, P) = [I on `independent`, β on `dependent`]."""

    standard_names: tuple[str, ...]
    independent: np.ndarray  # (B,) indices into π
    dependent: np.ndarray  # (P − B,)
    beta: np.ndarray  # (B, P − B): π_b = π[independent] + beta @ π[dependent]
    tolerance: float
    n_states: int

    @property
    def rank(self) -> int:
        """B, the number of base parameters (the numerical rank of the stacked random regressor)."""
        return len(self.independent)

    @property
    def names(self) -> tuple[str, ...]:
        """Each base parameter is named after its independent standard parameter."""
        return tuple(self.standard_names[i] for i in self.independent)

    @functools.cached_property
    def K(self) -> np.ndarray:
        """(B, P): π_b = K π."""
        K = np.zeros((self.rank, len(self.standard_names)))
        K[np.arange(self.rank), self.independent] = 1.0
        K[:, self.dependent] = self.beta
        return K

    def project(self, pi: np.ndarray) -> np.ndarray:
        """π_b (B,) of standard parameters π (P,)."""
        return self.K @ np.asarray(pi, dtype=float)

    def standard(self, pi_base: np.ndarray) -> np.ndarray:
        """A standard π (P,) with these base parameters: the dependent ones 0."""
        pi = np.zeros(len(self.standard_names))
        pi[self.independent] = pi_base
        return pi

    def definitions(self) -> dict[str, str]:
        """Base name → its definition as a combination of standard parameters, e.g. "izz_l2 + 1·iyy_l3"."""
        out = {}
        for b, i in enumerate(self.independent):
            scale = max(1.0, float(np.abs(self.beta[b]).max(initial=0.0)))
            terms = [self.standard_names[i]]
            for c, k in zip(self.beta[b], self.dependent):
                if abs(c) > SMALL * scale:
                    terms.append(f"{'+' if c > 0 else '-'} {abs(c):.10g}·{self.standard_names[k]}")
            out[self.standard_names[i]] = " ".join(terms)
        return out

    def stats(self, stats: Stats) -> Stats:
        """The statistics of the base regressor Y_ind (J, B, B)."""
        idx = self.independent
        return Stats(stats.G[:, idx][:, :, idx], stats.b[:, idx], stats.s.copy(), stats.n)

    def instruments(self, iv: InstrumentStats) -> InstrumentStats:
        """The instrument statistics of the base regressor and its instruments (Z_ind, Y_ind)."""
        idx = self.independent
        return InstrumentStats(iv.A[:, idx][:, :, idx], iv.c[:, idx], iv.K[:, idx][:, :, idx], self.stats(iv.stats))


def random_regressor(arm: Arm, n_states: int = N_STATES, seed: int = SEED) -> np.ndarray:
    """W (n_states·n, P): the arm's regressor stacked at random states (module doc)."""
    rng = np.random.default_rng(seed)
    size = (n_states, arm.n_joints)
    q = rng.uniform(-np.pi, np.pi, size)
    Y = arm.regressor(q, rng.standard_normal(size), rng.standard_normal(size))
    return Y.reshape(-1, arm.n_params)


@functools.lru_cache(maxsize=16)
def base_parameters(arm: Arm, n_states: int = N_STATES, tolerance: float = TOLERANCE) -> BaseParameters:
    """The arm's base parameters by pivoted QR of its column-scaled random regressor (module doc); cached."""
    W = random_regressor(arm, n_states)
    norms = np.linalg.norm(W, axis=0)
    nonzero = norms > ZERO_COLUMN * norms.max()  # a column of round-off (e.g. gravity on a vertical axis) is 0
    Ws = W[:, nonzero] / norms[nonzero]
    _, R, perm = scipy.linalg.qr(Ws, mode="economic", pivoting=True)
    diag = np.abs(np.diag(R))
    rank = int(np.sum(diag > tolerance * diag[0]))
    cols = np.flatnonzero(nonzero)
    ind, dep_nonzero = cols[perm[:rank]], cols[perm[rank:]]
    beta_scaled = scipy.linalg.solve_triangular(R[:rank, :rank], R[:rank, rank:])
    # W_dep / n_dep = (W_ind / n_ind) β_s  ⇒  W_dep = W_ind (β_s n_dep / n_ind)
    beta_nonzero = beta_scaled * norms[dep_nonzero][None, :] / norms[ind][:, None]
    zero = np.flatnonzero(~nonzero)
    order = np.argsort(ind)  # base parameters in π's order
    ind = ind[order]
    dependent = np.concatenate([dep_nonzero, zero])
    beta = np.hstack([beta_nonzero[order], np.zeros((rank, zero.size))])
    sort_dep = np.argsort(dependent)
    return BaseParameters(arm.names, ind, dependent[sort_dep], beta[:, sort_dep], tolerance, n_states)


@dataclass(frozen=True, eq=False)
class _BaseView:
    """The base parameters seen as an arm's parameter list, for `fit_ols` (no consistency of their own)."""

    names: tuple[str, ...]
    n_joints: int

    @property
    def parameters(self) -> tuple[Parameter, ...]:
        return tuple(Parameter(n, "", "base parameter") for n in self.names)

    @property
    def n_params(self) -> int:
        return len(self.names)

    def min_mass_eigenvalue(self, pi: np.ndarray) -> float:
        return float("nan")  # a base parameter set has no pseudo-inertias: see the standard fits


@dataclass
class BaseFit:
    """OLS on the base parameters: `fit` (in base parameters, with SEs), `pi` its standard map (P,)."""

    base: BaseParameters
    fit: LinearFit
    pi: np.ndarray

    def summary(self) -> dict[str, dict]:
        """Base name → {value, se, definition} (the JSON `base_parameters.<estimator>`)."""
        definitions = self.base.definitions()
        return {
            name: {"value": float(v), "se": float(e), "definition": definitions[name]}
            for name, v, e in zip(self.base.names, self.fit.pi, self.fit.se)
        }


def fit_base_ols(stats: Stats, arm: Arm, weights: str | np.ndarray | None = None) -> BaseFit:
    """(Weighted) OLS on the arm's base parameters from statistics of its standard regressor (module doc)."""
    base = base_parameters(arm)
    view = _BaseView(base.names, arm.n_joints)
    fit = fit_ols(base.stats(stats), view, weights=weights)  # type: ignore[arg-type]
    fit.warnings = [w for w in fit.warnings if not w.startswith("physically inconsistent")]
    return BaseFit(base, fit, base.standard(fit.pi))


def lifted_fit(arm: Arm, fit_on_base: Callable[[_BaseView], LinearFit]) -> LinearFit:
    """A fit on the arm's base parameters (`fit_on_base`, given the base parameters as a parameter list) as a fit
    of the arm's own parameters: π = the standard map (dependent parameters 0, `BaseParameters.standard`), each
    independent parameter with its base parameter's standard error and each dependent one with none (NaN: the
    data do not determine it alone). `details` holds the base parameters (value, SE, definition) and the names
    not determined."""
    base = base_parameters(arm)
    fit = fit_on_base(_BaseView(base.names, arm.n_joints))
    se = np.full(arm.n_params, np.nan)
    se[base.independent] = fit.se
    pi = base.standard(fit.pi)
    definitions = base.definitions()
    return LinearFit(
        pi=pi,
        names=arm.names,
        se=se,
        sigma2=fit.sigma2,
        method=fit.method,
        status=fit.status,
        weights=fit.weights,
        n=fit.n,
        rss=fit.rss,
        cond=fit.cond,
        rank=fit.rank,
        unexcited=list(fit.unexcited),
        poorly_determined=list(fit.poorly_determined),
        warnings=[w for w in fit.warnings if not w.startswith("physically inconsistent")],
        min_mass_eigenvalue=arm.min_mass_eigenvalue(pi),
        solve_seconds=fit.solve_seconds,
        details={
            "base_parameters": {
                name: {"value": float(v), "se": float(e), "definition": definitions[name]}
                for name, v, e in zip(base.names, fit.pi, fit.se)
            },
            "not_determined": [arm.names[i] for i in base.dependent],
        },
        parameters=arm.parameters,
    )


def fit_least_squares(stats: Stats, arm: Arm, weights: str | np.ndarray | None = None) -> LinearFit:
    """(Weighted) OLS of the arm's parameters: on the parameters themselves when the regressor determines every
    one of them (`fit.fit_ols`), else on the base parameters, lifted to the arm's (`lifted_fit`)."""
    base = base_parameters(arm)
    if base.rank == arm.n_params:
        return fit_ols(stats, arm, weights=weights)
    return lifted_fit(arm, lambda view: fit_ols(base.stats(stats), view, weights=weights))  # type: ignore[arg-type]
