"""Weighted least squares on stacked joint rows, and variable projection for a few nonlinear parameters.

Every candidate model here has the form  τ̂(θ, β) = o(θ) + X(θ) β : a fixed part o (N, 2) [N m], columns
X (N, 2, k) and linear coefficients β, with at most a couple of nonlinear parameters θ (a Stribeck velocity,
a delay, a mode's frequency and damping). For fixed θ the best β is a weighted least-squares solve,

    β̂(θ) = argmin Σ_j w_j Σ_k (τ_kj − o_kj − X_kj β)²,

so the search over θ is low-dimensional (variable projection): a grid, then a bounded scalar refinement per
coordinate. Standard errors of β assume independent residuals with a per-joint variance (optimistic on
densely sampled data, where residuals are correlated: read them as a lower bound).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar


@dataclass
class LinearSolve:
    """β̂ with standard errors, the weighted RSS and the per-joint RSS [N² m²]."""

    beta: np.ndarray
    se: np.ndarray
    cost: float
    rss: np.ndarray


def solve(offset: np.ndarray, X: np.ndarray, tau: np.ndarray, weights: np.ndarray, with_se: bool = True) -> LinearSolve:
    """Weighted least squares of τ − o on the columns X (see the module docstring). k = 0 is allowed;
    `with_se=False` skips the standard errors (inside searches)."""
    target = tau - offset
    k = X.shape[2]
    sw = np.sqrt(np.asarray(weights, dtype=float))
    if k == 0:
        rss = np.sum(target**2, axis=0)
        return LinearSolve(np.zeros(0), np.zeros(0), float(weights @ rss), rss)
    A = (X * sw[None, :, None]).reshape(-1, k)
    y = (target * sw[None, :]).reshape(-1)
    # Normal equations on unit-norm columns (units differ by orders of magnitude); k is small, so the
    # k×k solve is cheap and the O(N k²) Gram product dominates.
    scale = np.linalg.norm(A, axis=0)
    # A column of ~1e-12 of the largest column or of the target, or less (e.g. a Stribeck shape far from its
    # hump), is below what double precision resolves next to them: held at β = 0 with an infinite standard
    # error, rather than given a coefficient of 1e100 that overflows on other data.
    dead = scale <= 1e-12 * max(scale.max(), float(np.linalg.norm(y)))
    if dead.any():
        A[:, dead] = 0.0  # A is this call's own array (X times the weights)
        scale[dead] = 1.0
    As = A / scale
    H, h = As.T @ As, As.T @ y
    try:
        beta_s = np.linalg.solve(H, h)
    except np.linalg.LinAlgError:
        beta_s = np.linalg.lstsq(H, h, rcond=None)[0]
    beta = beta_s / scale
    resid = target - np.einsum("njk,k->nj", X, beta)
    rss = np.sum(resid**2, axis=0)
    if not with_se:
        return LinearSolve(beta, np.full(k, np.nan), float(weights @ rss), rss)
    dof = max(A.shape[0] - int(np.count_nonzero(~dead)), 1)
    s2 = float(weights @ rss) / dof
    cov = s2 * np.linalg.pinv(H) / np.outer(scale, scale)
    se = np.where(dead, np.inf, np.sqrt(np.clip(np.diag(cov), 0, None)))
    return LinearSolve(beta, se, float(weights @ rss), rss)


def solve_nonnegative(
    offset: np.ndarray,
    X: np.ndarray,
    tau: np.ndarray,
    weights: np.ndarray,
    nonnegative: Sequence[int],
    with_se: bool = True,
) -> LinearSolve:
    """`solve` with β_i ≥ 0 for i in `nonnegative` (a physical sign: a mass, an inertia, a static friction
    excess), by an active set: a column whose coefficient comes out negative is held at 0, the rest refit."""
    active = list(range(X.shape[2]))
    while True:
        ls = solve(offset, X[:, :, active], tau, weights, with_se)
        bad = [(b, i) for b, i in zip(ls.beta, active) if i in nonnegative and b < 0]
        if not bad:
            break
        active.remove(min(bad)[1])
    beta, se = np.zeros(X.shape[2]), np.zeros(X.shape[2])
    beta[active], se[active] = ls.beta, ls.se
    return LinearSolve(beta, se, ls.cost, ls.rss)


def sandwich(J: np.ndarray, r: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Standard errors (k,) of a weighted least-squares fit whose residuals are correlated in time and whose joints'
    variances need not be those the weights assume: the Newey–West sandwich H⁻¹ S H⁻¹, H = Jᵀ W J, S the long-run
    covariance of the per-sample scores g_t = Σ_j w_j J_tj r_tj with Bartlett weights out to `hac_lag` samples.
    J (N, n, k) the columns (or the prediction's Jacobian), r (N, n) the residuals, weights (n,)."""
    w = np.asarray(weights, dtype=float)
    scale = np.sqrt(np.einsum("njk,njk,j->k", J, J, w))
    scale[scale == 0] = 1.0
    J = J / scale
    H = np.einsum("njk,njl,j->kl", J, J, w)
    g = np.einsum("njk,nj,j->nk", J, r, w)  # (N, k) per-sample scores
    # Bartlett weights out to L lags = the products of sums over windows of L + 1 samples (in O(N k)).
    width = min(hac_lag(r), len(g) - 1) + 1
    sums = np.cumsum(np.vstack([np.zeros((1, g.shape[1])), g]), axis=0)
    B = sums[width:] - sums[:-width]
    S = B.T @ B / width
    Hi = np.linalg.pinv(H)
    return np.sqrt(np.clip(np.diag(Hi @ S @ Hi), 0.0, None)) / scale


def hac_lag(r: np.ndarray) -> int:
    """Bartlett lag [samples] for `sandwich`: 3 × the lag at which the residuals' autocorrelation (joints averaged)
    first falls below 1/e, at least 1, at most a tenth of the samples."""
    x = r - r.mean(axis=0)
    n = len(x)
    spectrum = np.fft.rfft(x, 2 * n, axis=0)
    acf = np.fft.irfft(np.abs(spectrum) ** 2, axis=0)[:n].sum(axis=1)
    acf = acf / acf[0] if acf[0] > 0 else acf
    below = np.nonzero(acf < np.exp(-1.0))[0]
    first = int(below[0]) if below.size else n
    return int(np.clip(3 * first, 1, max(1, n // 10)))


@dataclass
class Axis:
    """One nonlinear parameter: its name, search bounds and grid, searched on a log scale if `log`."""

    name: str
    low: float
    high: float
    points: int = 15
    log: bool = False

    def grid(self) -> np.ndarray:
        if self.log:
            return np.geomspace(self.low, self.high, self.points)
        return np.linspace(self.low, self.high, self.points)


def search(cost: Callable[[dict[str, float]], float], axes: Sequence[Axis], sweeps: int = 2) -> dict[str, float]:
    """Minimise cost(θ) over the box of `axes`: coordinate-wise grid sweeps, then a bounded Brent refinement
    of each coordinate around its best grid point (on a log scale for `log` axes)."""
    theta = {a.name: float(a.grid()[len(a.grid()) // 2]) for a in axes}
    for _ in range(sweeps if len(axes) > 1 else 1):
        for a in axes:
            values = [cost({**theta, a.name: float(v)}) for v in a.grid()]
            theta[a.name] = float(a.grid()[int(np.argmin(values))])
    for a in axes:
        g = a.grid()
        i = int(np.argmin(np.abs(g - theta[a.name])))
        lo, hi = g[max(i - 1, 0)], g[min(i + 1, len(g) - 1)]
        if hi <= lo:
            continue
        if a.log:
            res = minimize_scalar(
                lambda u, a=a: cost({**theta, a.name: float(np.exp(u))}),
                bounds=(np.log(lo), np.log(hi)),
                method="bounded",
                options={"xatol": 1e-3},
            )
            best = float(np.exp(res.x))
        else:
            res = minimize_scalar(
                lambda u, a=a: cost({**theta, a.name: float(u)}),
                bounds=(lo, hi),
                method="bounded",
                options={"xatol": 1e-4 * (a.high - a.low)},
            )
            best = float(res.x)
        if res.fun <= cost(theta):
            theta[a.name] = best
    return theta
