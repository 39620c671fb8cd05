"""Gaussian mixture regression (GMR): a Gaussian mixture on the joint vector z = [x, r], conditioned on x.

The model is p(x, r) = Σ_k w_k N([x, r]; μ_k, Σ_k). Conditioning on x (d_in inputs) gives, per component,

    h_k(x)  = w_k N(x; μx_k, Σxx_k) / Σ_j w_j N(x; μx_j, Σxx_j)      (responsibility; log-sum-exp)
    m_k(x)  = μr_k + Σrx_k Σxx_k⁻¹ (x − μx_k)                        (component conditional mean)
    C_k     = Σrr_k − Σrx_k Σxx_k⁻¹ Σxr_k                            (component conditional covariance)

and for the mixture E[r | x] = Σ_k h_k m_k, Cov[r | x] = Σ_k h_k (C_k + (m_k − E)(m_k − E)ᵀ): the
within-component part plus the spread between the components' means.

In ident-opt, x = [q1 q2 dq1 dq2 ddq1 ddq2] (rad, rad/s, rad/s²) and r = the torque residual of both joints
(N·m): one joint mixture with two outputs, so the residuals of the two joints share responsibilities and
their correlation is modelled.

Fitting is scikit-learn's `GaussianMixture` on standardised data (each column scaled to zero mean, unit
variance; `reg_covar` is therefore relative to unit variance). The fitted attributes are transformed back
exactly to original units, and `predict` reads only `weights_`, `means_`, `covariances_` and `n_inputs`:
there is no cached derived state, so editing those attributes (e.g. the online consistency transform,
which shifts `means_[k, n_inputs:]`) takes effect at the next call.
"""

from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from sklearn.mixture import GaussianMixture
from threadpoolctl import ThreadpoolController, threadpool_limits

from ident_opt.errors import InputError

_LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass
class GMR:
    """Gaussian mixture regression of outputs R (N, d_out) on inputs X (N, d_in).

    n_components: a fixed K, or None to choose among `candidates` by `selection`:
    ``"validation"`` (mean squared error of E[r | x] on a held-out `validation_fraction` of the training
    data, outputs weighted by 1/variance, then refit on all of it) or ``"bic"`` (scikit-learn's BIC).
    validation: which samples are held out for that choice: ``"random"`` or ``"blocked"`` (the last
    `validation_fraction` of the rows as given, i.e. the latest in time for a trial in time order — the
    honest choice when the model will predict later motions).
    covariance: ``"full"`` (the default; linear regression inside each component) or ``"diag"`` (each
    component predicts its constant mean: a piecewise-constant GMR).
    After `fit`: `n_components_`, `selection_scores_` {K: score}, `n_train_` (samples used).
    """

    n_components: int | None = None
    candidates: tuple[int, ...] = (1, 2, 3, 4, 6, 8, 10)
    covariance: str = "full"
    reg_covar: float = 1e-4
    max_train_samples: int = 20000
    selection: str = "validation"
    validation_fraction: float = 0.25
    validation: str = "random"
    random_state: int = 0
    weights_: np.ndarray = field(init=False, repr=False, default=None)
    means_: np.ndarray = field(init=False, repr=False, default=None)
    covariances_: np.ndarray = field(init=False, repr=False, default=None)
    n_inputs: int = field(init=False, default=0)
    n_components_: int = field(init=False, default=0)
    selection_scores_: dict = field(init=False, default_factory=dict)
    n_train_: int = field(init=False, default=0)

    # ------------------------------------------------------------------ fitting
    def fit(self, X: np.ndarray, R: np.ndarray) -> GMR:
        """Fit the joint mixture on [X, R] (rows are samples); returns self."""
        # EM on N × D with D ≈ 8 is many small matrix products: BLAS threads only add overhead and, on a busy
        # machine, oversubscribe the cores (measured: a 10-component fit 0.14 s single-threaded, 1–5 s not).
        with threadpool_limits(limits=1):
            return self._fit(X, R)

    def _fit(self, X: np.ndarray, R: np.ndarray) -> GMR:
        X, R = _check_xr(X, R)
        if self.covariance not in ("full", "diag"):
            raise InputError(f"GMR covariance must be 'full' or 'diag', got {self.covariance!r}")
        if self.selection not in ("validation", "bic"):
            raise InputError(f"GMR selection must be 'validation' or 'bic', got {self.selection!r}")
        if self.validation not in ("random", "blocked"):
            raise InputError(f"GMR validation must be 'random' or 'blocked', got {self.validation!r}")
        rng = np.random.default_rng(self.random_state)
        Z = np.hstack([X, R])
        if len(Z) > self.max_train_samples:  # bounded cost: a random subsample, reproducible
            Z = Z[np.sort(rng.choice(len(Z), self.max_train_samples, replace=False))]
        self.n_inputs, self.n_train_ = X.shape[1], len(Z)
        shift, scale = Z.mean(axis=0), Z.std(axis=0)
        # A column constant up to rounding (e.g. a joint at rest for the whole window) must not be blown up
        # by a 1e-16 standard deviation: treat it as constant and keep unit scale; reg_covar keeps Σ invertible.
        scale[scale <= 1e-12 * np.maximum(1.0, np.abs(shift))] = 1.0
        Zs = (Z - shift) / scale

        if self.n_components is not None:
            k = int(self.n_components)
            self.selection_scores_ = {}
        else:
            k = self._select(Zs, rng)
        k = _checked_k(k, len(Zs))
        self.n_components_ = k
        gm = self._em(k, Zs)
        covs = gm.covariances_ if self.covariance == "full" else _diag_to_full(gm.covariances_)
        # Back to original units: z = shift + scale ⊙ zs, so μ = shift + scale ⊙ μs, Σ = D Σs D.
        self.weights_ = gm.weights_.copy()
        self.means_ = shift + gm.means_ * scale
        self.covariances_ = covs * scale[:, None] * scale[None, :]
        return self

    def _mixture(self, k: int):
        return GaussianMixture(
            n_components=k,
            covariance_type=self.covariance,
            reg_covar=self.reg_covar,
            random_state=self.random_state,
            max_iter=200,
        )

    def _em(self, k: int, Zs: np.ndarray) -> GaussianMixture:
        """EM with `k` components on the standardised samples `Zs`; InputError naming the `[residual]` settings
        when a component collapses (too many components for the samples, too small a regulariser)."""
        try:
            return self._mixture(k).fit(Zs)
        except ValueError as exc:
            if "ill-defined empirical covariance" not in str(exc):
                raise
            raise InputError(
                f"[residual]: the GMR with {k} components on {len(Zs)} training samples has a component with no "
                f"spread, which reg_covar = {self.reg_covar:g} is too small to keep invertible: use fewer "
                "components, more samples (max_train_samples) or a larger reg_covar (the default is 1e-4)"
            ) from None

    def _select(self, Zs: np.ndarray, rng: np.random.Generator) -> int:
        """The number of components with the best validation error (or BIC) among `candidates`."""
        # candidates larger than the data allow are skipped (a short trial), not an error
        candidates = sorted({int(k) for k in self.candidates if 1 <= int(k) <= len(Zs) // 2})
        if not candidates:
            raise InputError(
                f"GMR: no candidate number of components in {list(self.candidates)} fits {len(Zs)} training samples"
            )
        scores: dict[int, float] = {}
        if self.selection == "bic":
            for k in candidates:
                scores[k] = float(self._em(k, Zs).bic(Zs))
        else:
            n_val = max(1, round(self.validation_fraction * len(Zs)))
            if self.validation == "blocked":
                val, train = Zs[-n_val:], Zs[:-n_val]
            else:
                perm = rng.permutation(len(Zs))
                val, train = Zs[perm[:n_val]], Zs[perm[n_val:]]
            d = self.n_inputs
            for k in candidates:
                if k > len(train):
                    continue
                gm = self._em(k, train)
                covs = gm.covariances_ if self.covariance == "full" else _diag_to_full(gm.covariances_)
                mean = conditional_mean(gm.weights_, gm.means_, covs, d, val[:, :d])
                scores[k] = float(np.mean((val[:, d:] - mean) ** 2))  # standardised: variance-weighted
        self.selection_scores_ = scores
        return min(scores, key=scores.get)

    # ------------------------------------------------------------------ prediction
    def predict(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """E[r | x] (N, d_out) and the mixture's Cov[r | x] (N, d_out, d_out), in the outputs' units."""
        self._check_fitted()
        X = _check_x(X, self)
        with _single_threaded(len(X)):
            return conditional(self.weights_, self.means_, self.covariances_, self.n_inputs, X)

    def predict_mean(self, X: np.ndarray) -> np.ndarray:
        """E[r | x] (N, d_out) only (cheaper: no covariance)."""
        self._check_fitted()
        X = _check_x(X, self)
        with _single_threaded(len(X)):
            return conditional_mean(self.weights_, self.means_, self.covariances_, self.n_inputs, X)

    def predict_std(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """E[r | x] and the per-output predictive standard deviation sqrt(diag Cov[r | x]), both (N, d_out)."""
        mean, cov = self.predict(X)
        return mean, np.sqrt(np.einsum("nii->ni", cov))

    def _check_fitted(self) -> None:
        if self.weights_ is None:
            raise RuntimeError("GMR is not fitted: call fit(X, R) first")


# ---------------------------------------------------------------------------------------------- the math
@dataclass(frozen=True)
class Conditioning:
    """What conditioning on x needs, derived from (weights, means, covariances) for all K at once.

    W (K, d, d): whitening maps with ‖(x − μx_k) W_k‖² = Mahalanobis distance (W_k = L_k⁻ᵀ, Σxx_k = L_k L_kᵀ);
    log_norm (K,): log w_k − ½ log det(2π Σxx_k); A (K, d_out, d): regression Σrx_k Σxx_k⁻¹;
    C (K, d_out, d_out): component conditional covariances.
    """

    mu_x: np.ndarray
    mu_r: np.ndarray
    W: np.ndarray
    log_norm: np.ndarray
    A: np.ndarray
    C: np.ndarray


def conditioning(weights: np.ndarray, means: np.ndarray, covariances: np.ndarray, d: int) -> Conditioning:
    """Per-component conditioning terms (batched Cholesky over the K components)."""
    Sxx, Srx, Srr = covariances[:, :d, :d], covariances[:, d:, :d], covariances[:, d:, d:]
    L = np.linalg.cholesky(Sxx)
    L_inv = np.linalg.inv(L)  # K small triangular d×d inverses: negligible next to the N-sized work
    A = Srx @ np.swapaxes(L_inv, 1, 2) @ L_inv  # Σrx Σxx⁻¹ with Σxx⁻¹ = L⁻ᵀ L⁻¹
    C = Srr - A @ np.swapaxes(Srx, 1, 2)
    half_logdet = np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
    with np.errstate(divide="ignore"):  # a zero weight is a component that never responds
        log_norm = np.log(weights) - half_logdet - 0.5 * d * _LOG_2PI
    return Conditioning(means[:, :d], means[:, d:], np.swapaxes(L_inv, 1, 2), log_norm, A, C)


def _responsibilities_and_means(c: Conditioning, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """h (N, K) and the component conditional means m (N, K, d_out) for one chunk of X (N, d).

    Both are one matrix product each over all K: X @ [W_1 … W_K] and X @ [A_1ᵀ … A_Kᵀ].
    """
    K, d, _ = c.W.shape
    d_out = c.A.shape[1]
    W_all = np.swapaxes(c.W, 0, 1).reshape(d, K * d)  # columns grouped by component
    offs = np.einsum("ki,kij->kj", c.mu_x, c.W).reshape(K * d)
    Z = (X @ W_all - offs).reshape(len(X), K, d)  # whitened (x − μx_k)
    log_p = c.log_norm - 0.5 * np.einsum("nkd,nkd->nk", Z, Z)
    log_p -= log_p.max(axis=1, keepdims=True)  # log-sum-exp: exponentiate only non-positive numbers
    h = np.exp(log_p)
    h /= h.sum(axis=1, keepdims=True)
    A_all = np.transpose(c.A, (2, 0, 1)).reshape(d, K * d_out)  # column (k, o) is row o of A_k
    m_off = (c.mu_r - np.einsum("kod,kd->ko", c.A, c.mu_x)).reshape(K * d_out)
    m = (X @ A_all + m_off).reshape(len(X), K, d_out)
    return h, m


def conditional_mean(
    weights: np.ndarray, means: np.ndarray, covariances: np.ndarray, d: int, X: np.ndarray, chunk: int = 16384
) -> np.ndarray:
    """E[r | x] (N, d_out) of the mixture (weights (K,), means (K, D), covariances (K, D, D))."""
    c = conditioning(weights, means, covariances, d)
    out = np.empty((len(X), means.shape[1] - d))
    for s in range(0, len(X), chunk):  # bounded memory: O(chunk · K · d)
        h, m = _responsibilities_and_means(c, X[s : s + chunk])
        out[s : s + chunk] = np.einsum("nk,nko->no", h, m)
    return out


def conditional(
    weights: np.ndarray, means: np.ndarray, covariances: np.ndarray, d: int, X: np.ndarray, chunk: int = 16384
) -> tuple[np.ndarray, np.ndarray]:
    """E[r | x] (N, d_out) and Cov[r | x] (N, d_out, d_out) = Σ h_k (C_k + (m_k − E)(m_k − E)ᵀ)."""
    c = conditioning(weights, means, covariances, d)
    d_out = means.shape[1] - d
    mean, cov = np.empty((len(X), d_out)), np.empty((len(X), d_out, d_out))
    for s in range(0, len(X), chunk):
        h, m = _responsibilities_and_means(c, X[s : s + chunk])
        e = np.einsum("nk,nko->no", h, m)
        dev = m - e[:, None, :]
        mean[s : s + chunk] = e
        cov[s : s + chunk] = np.einsum("nk,kij->nij", h, c.C) + np.einsum("nk,nki,nkj->nij", h, dev, dev)
    return mean, cov


def input_log_density(gmr: GMR, X: np.ndarray, chunk: int = 16384) -> np.ndarray:
    """log p(x) (N,) of a fitted GMR's own input marginal p(x) = Σ_k w_k N(x; μx_k, Σxx_k) [nats, in the
    units of x]: where the mixture has seen data (high) and where it is guessing (low)."""
    X = _check_x(X, gmr)
    c = conditioning(gmr.weights_, gmr.means_, gmr.covariances_, gmr.n_inputs)
    K, d, _ = c.W.shape
    W_all = np.swapaxes(c.W, 0, 1).reshape(d, K * d)
    offs = np.einsum("ki,kij->kj", c.mu_x, c.W).reshape(K * d)
    out = np.empty(len(X))
    for s in range(0, len(X), chunk):
        Z = (X[s : s + chunk] @ W_all - offs).reshape(-1, K, d)
        log_p = c.log_norm - 0.5 * np.einsum("nkd,nkd->nk", Z, Z)
        top = log_p.max(axis=1)
        out[s : s + chunk] = top + np.log(np.exp(log_p - top[:, None]).sum(axis=1))
    return out


@dataclass(frozen=True)
class Support:
    """Where a GMR residual may be trusted: x is inside its training support when log p(x) of the GMR's input
    marginal (`input_log_density`) is at least `threshold` [nats], the `quantile` of the training inputs' own
    log-densities. Outside, the residual's weight s = exp(−(threshold − log p) / `width`) falls toward 0."""

    threshold: float
    width: float = 1.0
    quantile: float = 0.005

    @classmethod
    def fit(cls, gmr: GMR, X: np.ndarray, quantile: float = 0.005, width: float = 1.0) -> Support:
        """The support of `gmr` on its training inputs X (N, d)."""
        return cls(float(np.quantile(input_log_density(gmr, X), quantile)), width, quantile)

    def weight(self, log_p: float) -> float:
        """s in (0, 1]: 1 inside the support, exp(−deficit / width) outside."""
        deficit = self.threshold - log_p
        return 1.0 if deficit <= 0 else float(np.exp(-deficit / self.width))


# ---------------------------------------------------------------------------------------------- threads
@lru_cache(maxsize=1)
def _blas_controller():
    return ThreadpoolController()  # built once: entering its limit() then costs ~3 µs, not ~150 µs


def _single_threaded(n: int):
    """BLAS limited to one thread for large batches: the products are N × 6 by 6 × K·6, too thin for
    threads to pay off, and on a busy machine threads oversubscribe the cores (measured 3.5× slower at
    N = 2·10⁵, K = 10). Small batches (online, per-sample use) skip even the ~3 µs of switching."""
    return _blas_controller().limit(limits=1) if n >= 4096 else nullcontext()


# ---------------------------------------------------------------------------------------------- checks
def _diag_to_full(diag: np.ndarray) -> np.ndarray:
    """(K, D) variances → (K, D, D) diagonal covariance matrices."""
    return np.einsum("kd,de->kde", diag, np.eye(diag.shape[1]))


def _checked_k(k: int, n: int) -> int:
    if k < 1:
        raise InputError(f"GMR needs at least 1 component, got {k}")
    if k > n:
        raise InputError(f"GMR with {k} components needs at least {k} training samples, got {n}")
    return k


def _check_xr(X: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    X, R = np.asarray(X, dtype=float), np.asarray(R, dtype=float)
    if R.ndim == 1:
        R = R[:, None]
    if X.ndim != 2 or R.ndim != 2:
        raise InputError(f"GMR.fit needs X (N, d_in) and R (N, d_out); got shapes {X.shape} and {R.shape}")
    if len(X) != len(R):
        raise InputError(f"GMR.fit: X has {len(X)} rows but R has {len(R)}")
    if len(X) < 2:
        raise InputError("GMR.fit needs at least 2 samples")
    if not (np.isfinite(X).all() and np.isfinite(R).all()):
        raise InputError("GMR.fit: X and R must be finite (no NaN or inf)")
    return X, R


def _check_x(X: np.ndarray, model: GMR) -> np.ndarray:
    X = np.atleast_2d(np.asarray(X, dtype=float))
    if X.ndim != 2 or X.shape[1] != model.n_inputs:
        raise InputError(f"GMR.predict needs X of shape (N, {model.n_inputs}), got {X.shape}")
    return X
