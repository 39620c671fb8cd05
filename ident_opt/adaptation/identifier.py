"""Online adaptation: after every sample, the parameters an offline re-fit on all data so far would give.

The parametric part of each model is linear in its parameters θ: τ = D(q, dq, ddq) θ with a design D (n, P) per
sample (n joints) — the rigid-body regressor Y (or its base columns, `fitting.base`) for DM/PBR/CPBR,
block-diagonal kinematic features for RR. So each model keeps the sufficient statistics of its design (`Stats`):
a new sample is a rank-n update, and the re-solve on them is exactly the batch solve on all data seen so far:

| model | estimator on the statistics                                  | per-sample cost             |
|-------|--------------------------------------------------------------|-----------------------------|
| RR    | ridge: (Σ_j G_j + λ diag(penalty)) θ = Σ_j b_j               | one P×P solve               |
| DM    | fixed (the datasheet π, as in the paper)                      | none                        |
| PBR   | box-bounded LS, warm-started active set (`fitting.bounded`) | one P×P solve, usually      |
| CPBR  | the arm's consistency (`estimators.ONLINE` of its estimator)  | see below                   |

PBR follows OLS (`models.fitted`). On an arm whose regressor determines every parameter (the planar two-link
arm) it is bounded least squares on π with the bounds of the parameters' kinds; on an arm identified through its
base parameters (an n-joint URDF arm) it is bounded least squares on the base parameters, with a lower bound 0 on
exactly those base parameters that are non-negative for every consistent arm (`consistency.necessarily_nonnegative`:
friction, armature, and each combination of link parameters whose coefficients lie in the dual of the
pseudo-inertia cone). Those sign bounds hold exactly after every sample. The base parameters' information is
ill-conditioned (κ(Y)² of 1e7 to 1e12 on real trials), so their statistics are kept as a square-root factor of the
rows (`fitting.bounded.FactorBoundedLS`: a QR of (P + n) × P per sample, never YᵀY), as the generated update keeps
them too.

CPBR follows the fit the run chose (a `fitting.recommend.Choice`: `ident-opt online` passes the recommended one,
or --estimator's; None: the arm's default estimator, `Robot.default_estimator`; through `models.fitted`, the one
place that names it). Where that estimator has an exact online counterpart
(`estimators.ONLINE`: the planar arm's constrained fit → M(q) ≻ 0 ∀q + friction ≥ 0,
`fitting.bounded_consistent.WarmConsistentLS`) it is re-solved after every sample. An
n-joint arm's consistent fit (per-link pseudo-inertia LMIs, with its log-det prior) is a conic program of tens to
hundreds of milliseconds: it is re-solved from scratch on the exact statistics every `CONSISTENT_EVERY` samples
(`Cadence`; the LMIs then hold exactly, and its parameters stay as they are in between), while PBR gives the exact
sign-bounded parameters after every sample; the replay measures how far those are from the consistent re-solve.
The robust fit (instrumental variables) is re-solved at the cadence too, with the training part's instruments and the
online samples as their own (`Instruments`).

The GMR residual model r = τ − Dθ was trained offline with θ0. When θ moves by Δθ = θ − θ0 the residual
it should model moves by −D(x)Δθ; the paper's mean-only consistency transform shifts each component's
output mean by −D(μx_k)Δθ (recomputed from the offline means every step, so it never drifts). With
`cross_covariance=True` the first-order terms are updated too: with J_k = ∂(D(x)Δθ)/∂x at μx_k,
Σrx_k ← Σrx_k − J_k Σxx_k and Σrr_k ← Σrr_k − J_k Σxr_k − Σrx_k J_kᵀ + J_k Σxx_k J_kᵀ (the covariance of
r − D(x)Δθ linearised at μx_k), which makes each component's conditional mean follow −D(x)Δθ to first
order in x − μx_k instead of only at μx_k.

Measured on exp1 (first 70 % offline, the rest replayed; nMSE per joint j1/j2): the cross-covariance
update does not measurably help — pbr+gmr 0.0868/0.6205 with it vs 0.0880/0.6187 without (K = 2, chosen
on blocked validation), 0.0821/0.7209 vs 0.0818/0.7186 (K = 4), 0.0917/0.8120 vs 0.0907/0.8094 (K = 10):
mixed signs, about 1 %, against 0.0876/0.6313 frozen. The reason is structural: the better the transform
keeps the hybrid prediction unchanged, the more it cancels the adaptation itself (for RR, whose design
is linear in x, the first-order update is exact and rr+gmr online equals frozen to the last digit). So
it is off by default (`cross_covariance=False`, CLI `--cross-covariance`), kept only to reproduce this.

`update(sample)` first predicts the sample's torque with the current model (an honest one-step-ahead
prediction: the sample's torque is not used), then folds the sample in and re-solves.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ident_opt.arm.base import Arm
from ident_opt.columns import kinematic_columns
from ident_opt.consistency import necessarily_nonnegative
from ident_opt.errors import InputError
from ident_opt.fitting import estimators
from ident_opt.fitting.base import BaseParameters, base_parameters
from ident_opt.fitting.bounded import Bounds, FactorBoundedLS, WarmBoundedLS, default_bounds
from ident_opt.fitting.bounded_consistent import WarmConsistentLS
from ident_opt.fitting.fit import LinearFit
from ident_opt.fitting.iv import InstrumentStats
from ident_opt.fitting.recommend import Choice
from ident_opt.fitting.stats import Stats
from ident_opt.models.gmr import Support, conditioning, input_log_density
from ident_opt.models.hybrid import RidgeModel, datasheet_keys, datasheet_model, features, fitted, make_gmr

#: z-value of the central 95 % interval of a Gaussian.
Z95 = 1.959963984540054
#: Samples over which the parametric model's one-step residual variance is averaged (exponential weights).
PARAMETRIC_MEMORY = 500.0
ALPHA = 1.0 / PARAMETRIC_MEMORY
#: Largest torque difference [× the torque's RMS] between the recursive ridge and RidgeCV on the training data.
RIDGE_AGREEMENT = 1e-6
#: Samples between two from-scratch re-solves of an estimator without an exact online counterpart (`Cadence`).
CONSISTENT_EVERY = 500

#: (q (N, n), dq (N, n), ddq (N, n)) -> design (N, n, P): τ = D θ per sample.
Design = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True, eq=False)
class ArmDesign:
    """τ = D θ with D the columns `columns` of an arm's regressor Y (every column when None): the design of a model
    whose parameters are the arm's π, or its base parameters (the independent columns, `fitting.base`)."""

    arm: Arm
    columns: tuple[int, ...] | None = None

    @property
    def n_joints(self) -> int:
        """n, the rows of D per sample."""
        return self.arm.n_joints

    @property
    def names(self) -> tuple[str, ...]:
        """θ's names: the arm's parameters, or those naming the kept columns."""
        names = self.arm.names
        return names if self.columns is None else tuple(names[i] for i in self.columns)

    def __call__(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """D (N, n, P) at N samples [rad, rad/s, rad/s²]."""
        Y = self.arm.regressor(q, dq, ddq)
        return Y if self.columns is None else Y[:, :, self.columns]

    def expression(self) -> ca.SX:
        """D (n×P, dense) as a CasADi expression of the arm's symbols q, dq, ddq."""
        Y = self.arm.symbols["Y"]
        return ca.densify(Y if self.columns is None else Y[:, list(self.columns)])

    def jacobian(self) -> Callable[[np.ndarray], np.ndarray]:
        """x = [q dq ddq] (3n,) -> ∂D/∂x (n, 3n, P), from the CasADi expressions (exact; sign(dq) columns have
        derivative 0, where a finite difference would blow up at dq = 0)."""
        s = self.arm.symbols
        x = ca.vertcat(s["q"], s["dq"], s["ddq"])
        theta = ca.SX.sym("theta", len(self.names))
        # D(x) θ is linear in θ, so ∂(D θ)/∂x evaluated at θ = e_p is column p of ∂D/∂x.
        f = ca.Function("dD_dx", [x, theta], [ca.jacobian(ca.mtimes(self.expression(), theta), x)])
        eye = np.eye(len(self.names))

        def jacobian(xv: np.ndarray) -> np.ndarray:
            return np.stack([np.array(f(xv, eye[p])) for p in range(len(eye))], axis=-1)

        return jacobian


@dataclass
class Prediction:
    """One sample's predicted torque [N m] (n,), its parametric part, and the predictive standard
    deviation [N m] (n,) (GMR's Cov[r | x], or the residual RMS of the fit when there is no GMR);
    `extrapolating`: x lies outside the GMR's training support (`gmr.Support`; only with a guard)."""

    tau: np.ndarray
    parametric: np.ndarray
    std: np.ndarray
    extrapolating: bool = False

    @property
    def lower(self) -> np.ndarray:
        """Lower end of the 95 % interval [N m]."""
        return self.tau - Z95 * self.std

    @property
    def upper(self) -> np.ndarray:
        """Upper end of the 95 % interval [N m]."""
        return self.tau + Z95 * self.std


@dataclass
class Estimator:
    """How θ follows from the statistics: ``fixed``, ``ridge`` (with `penalty` (P,) = λ per column, 0 for
    an unpenalised intercept), ``bounded`` (with `bounds`), ``factor`` (the same with the statistics kept as a
    square-root factor of the rows, `fitting.bounded.FactorBoundedLS`: base parameters of an n-joint arm),
    ``consistent`` (with `solver`, an object with `.solve(H, h) -> θ`, e.g. `WarmConsistentLS`) or ``cadence`` (with
    `solver` a `Cadence`: a from-scratch fit every `Cadence.every` samples, θ held in between)."""

    kind: str
    penalty: np.ndarray | None = None
    bounds: Bounds | None = None
    solver: object | None = None

    def make_solver(self) -> Callable[[np.ndarray, np.ndarray], np.ndarray] | None:
        """A callable (H, h) -> θ keeping whatever warm-start state the estimator needs."""
        if self.kind in ("fixed", "cadence", "factor"):  # none on (H, h): `OnlineIdentifier.add` asks these itself
            return None
        if self.kind == "ridge":
            D = np.diag(self.penalty)
            return lambda H, h: np.linalg.solve(H + D, h)
        if self.kind == "bounded":
            return WarmBoundedLS(self.bounds).solve
        if self.kind == "consistent":
            return self.solver.solve
        raise ValueError(f"unknown estimator {self.kind!r}")


class OnlineIdentifier:
    """One model (parametric part + optional GMR residual) adapted sample by sample.

    design: D(q, dq, ddq) (N, n, P); theta0: the offline parameters; stats0: the offline statistics
    of the design (the data θ0 was fitted on); gmr: a fitted `ident_opt.models.gmr.GMR` on x = [q dq ddq],
    r = τ − Dθ0, or None; cross_covariance: also apply the first-order covariance update (module doc);
    design_jacobian: x (3n,) -> ∂D/∂x (n, 3n, P), needed only for `cross_covariance`; rows: the offline design
    rows and torques (D (N, n, P), τ (N, n)) a ``factor`` estimator starts from (the statistics alone would lose the
    accuracy it keeps).
    """

    def __init__(
        self,
        design: Design,
        estimator: Estimator,
        theta0: np.ndarray,
        stats0: Stats,
        gmr=None,
        cross_covariance: bool = False,
        design_jacobian: Callable[[np.ndarray], np.ndarray] | None = None,
        support: Support | None = None,
        rows: tuple[np.ndarray, np.ndarray] | None = None,
    ):
        self.design = design
        self.estimator = estimator
        self.theta0 = np.asarray(theta0, dtype=float).copy()
        self.theta = self.theta0.copy()
        self._stats = stats0.copy()
        self._pending: list[tuple[np.ndarray, np.ndarray]] = []  # samples not yet in `_stats`
        self._H, self._h, _ = self._stats.combined()
        self._solve = estimator.make_solver()
        self.n_updates = 0
        self.gmr0 = gmr  # the offline GMR, never modified (the transform starts from it every step)
        self._gmr = copy.deepcopy(gmr) if gmr is not None else None
        if gmr is not None:
            d = gmr.n_inputs
            mu_x = gmr.means_[:, :d]
            n = d // 3
            # D at each component's input mean, (K, n, P): the consistency transform's only data need.
            self._design_at_means = design(mu_x[:, :n], mu_x[:, n : 2 * n], mu_x[:, 2 * n :])
            self._jac_at_means = None
            if cross_covariance:
                if design_jacobian is None:
                    raise ValueError("cross_covariance needs design_jacobian")
                self._jac_at_means = np.stack([design_jacobian(m) for m in mu_x])  # (K, 2, 6, P)
        self._factor = None
        if estimator.kind == "factor":
            if rows is None:
                raise ValueError("a factor estimator starts from the offline rows")
            self._factor = FactorBoundedLS(estimator.bounds, *rows)
            self._factor.last = self._factor.solve()
            self.theta = self._factor.last.pi.copy()
        if self._solve is not None:
            self.theta = self._solve(self._H, self._h)  # the offline solution, by this estimator
        self.support = support
        self._fast = _FastGMR(gmr) if gmr is not None and not cross_covariance else None
        # The parametric model's own one-step residual variance per joint [N² m²]: starts at the offline fit's
        # mean square, then follows the one-step residuals (EW, ~`PARAMETRIC_MEMORY` samples).
        self.parametric_var = np.maximum(self._stats.rss(self.theta), 0.0) / max(self._stats.n, 1)
        self._kernel = None  # the generated C update, when attached (`use_kernel`)
        self._predictor = None  # the generated C prediction, when attached (`use_predictor`)
        self._stale = False  # the GMR's means lag θ (only with a compiled predictor)
        self.refresh_failures = 0  # cadence re-solves that failed (θ kept, the statistics have the samples)

    # ------------------------------------------------------------------ state
    @property
    def stats(self) -> Stats:
        """The per-joint statistics of all data seen (offline + online). Samples are folded in lazily, in
        one vectorised batch when asked for: the per-sample path only updates the combined (H, h)."""
        if self._pending:
            D = np.stack([d for d, _ in self._pending])
            tau = np.stack([t for _, t in self._pending])
            self._stats = self._stats + Stats.from_regressor(D, tau)
            self._pending.clear()
        return self._stats

    @property
    def parameters(self) -> np.ndarray:
        """The current θ (a copy)."""
        return self.theta.copy()

    @property
    def gmr(self):
        """The current (consistency-transformed) GMR, or None."""
        if self._stale:
            self._transform(self.theta - self.theta0)
            self._stale = False
        return self._gmr

    def residual_std(self) -> np.ndarray:
        """RMS residual of the current θ on all data seen, per joint [N m] (from the statistics)."""
        return np.sqrt(np.maximum(self.stats.rss(self.theta), 0.0) / max(self.stats.n, 1))

    # ------------------------------------------------------------------ prediction and update
    def predict(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, design: np.ndarray | None = None) -> Prediction:
        """The current model's torque for one sample (each (n,)); `design` (n, P) if already computed.

        With a `support` (extrapolation guard): outside the GMR's training support the prediction is the
        mixture of the GMR's (weight s) and the parametric model's alone (weight 1 − s, the residual 0 with
        the parametric model's own one-step residual variance): mean s·E[r|x], variance
        s·(Var[r|x] + E²) + (1 − s)·σ_par² − (s·E)²."""
        D = self.design(q[None], dq[None], ddq[None])[0] if design is None else design
        parametric = D @ self.theta
        if self._gmr is None:
            return Prediction(parametric, parametric, self.residual_std())
        x = np.concatenate([q, dq, ddq])
        if self._fast is not None:
            mean, var, log_p = self._fast.predict(x, self._gmr.means_)
        else:
            m, cov = self._gmr.predict(x[None])
            mean, var, log_p = m[0], np.diagonal(cov[0]).copy(), None
        if self.support is None:
            return Prediction(parametric + mean, parametric, np.sqrt(var))
        if log_p is None:
            log_p = float(input_log_density(self._gmr, x[None])[0])
        s = self.support.weight(log_p)
        if s < 1.0:
            shrunk = s * mean
            var = s * (var + mean * mean) + (1.0 - s) * self.parametric_var - shrunk * shrunk
            mean = shrunk
        return Prediction(parametric + mean, parametric, np.sqrt(np.maximum(var, 0.0)), log_p < self.support.threshold)

    def update(
        self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, tau: np.ndarray, design: np.ndarray | None = None
    ) -> Prediction:
        """Predict the sample (before seeing τ), then fold it in and re-solve; returns the prediction.
        q, dq, ddq [rad, rad/s, rad/s²], τ [N m], each (n,)."""
        D = self.design(q[None], dq[None], ddq[None])[0] if design is None else design
        prediction = self.predict(q, dq, ddq, D)
        self.add(D, tau)
        return prediction

    def add(self, D: np.ndarray, tau: np.ndarray) -> None:
        """Fold one sample (design D (n, P), τ (n,)) into the statistics and re-solve θ exactly. All or nothing:
        when the re-solve fails (raises) or gives a non-finite θ, nothing changes and `FloatingPointError`
        (or the solver's error) is raised. A cadence estimator (`Cadence`) re-solves every `every` samples
        instead; a failed re-solve there keeps θ (counted in `refresh_failures`), the sample stays folded in."""
        if self._kernel is not None:  # the generated C update (`online_kernel`): statistics, re-solve, residual
            k = self._kernel
            if D is not k.D:  # `step` wrote the regressor into the kernel's buffer already
                k.D[...] = D
            k.tau[...] = tau  # into the kernel's fixed buffers (their addresses are cached)
            status = k.rows(k.address, k.D_address, k.tau_address, self._pv_address, ALPHA)
            if status:
                raise FloatingPointError(f"the compiled update refused the sample (code {status}); nothing changed")
            self.theta = k.theta.copy()
            self._fold(k.D.copy(), k.tau.copy())  # the buffers are reused: the pending statistics keep copies
            return
        r = tau - D @ self.theta  # the parametric model's one-step residual
        if self._factor is not None:
            self.theta = self._factor.add(D, tau)  # raises, changing nothing, when the re-solve fails
            self.parametric_var += (r * r - self.parametric_var) * ALPHA
            self._fold(D, tau)
            return
        if self.estimator.kind == "cadence":
            if not np.isfinite(r).all():  # the statistics must stay finite for the next re-solve
                raise FloatingPointError("a non-finite regressor row or torque; the sample was not folded in")
            self.parametric_var += (r * r - self.parametric_var) * ALPHA
            self._fold(D, tau, moved=False)
            if self.n_updates % self.estimator.solver.every == 0:
                self._refresh()
            return
        if self._solve is not None:
            # The combined normal equations (the same rank-n term as the per-joint Stats), committed only after
            # the re-solve succeeded.
            H = self._H + D.T @ D
            h = self._h + D.T @ tau
            theta = self._solve(H, h)
            if not np.isfinite(theta).all():
                raise FloatingPointError("the re-solve gave a non-finite θ; the sample was not folded in")
            self._H, self._h, self.theta = H, h, theta
        self.parametric_var += (r * r - self.parametric_var) * ALPHA
        self._fold(D, tau, moved=self._solve is not None)

    def _refresh(self) -> None:
        """A cadence estimator's from-scratch re-solve on every sample seen (its θ changes only here)."""
        try:
            theta = self.estimator.solver.refresh(self.stats)
        except (RuntimeError, ValueError, np.linalg.LinAlgError, FloatingPointError):
            self.refresh_failures += 1
            return
        self.theta = theta
        self._moved()

    def _fold(self, D: np.ndarray, tau: np.ndarray, moved: bool = True) -> None:
        """Book-keeping after an accepted sample: the per-joint statistics (lazily), the count, the GMR transform
        (`moved`: θ changed with it)."""
        self._pending.append((D, tau))
        self.n_updates += 1
        if len(self._pending) >= 4096:  # bounded memory: fold the pending samples into the statistics
            _ = self.stats
        if moved:
            self._moved()

    def _moved(self) -> None:
        """θ changed: the GMR follows by the consistency transform (now, or when asked, with a compiled predictor)."""
        if self._gmr is not None:
            if self._predictor is None:
                self._transform(self.theta - self.theta0)
            else:  # the compiled prediction reads θ itself: the GMR's means are brought up to date when asked for
                self._stale = True

    def use_predictor(self, predictor) -> None:
        """Let `step` predict in generated C (`online_kernel.Predictor`: regressor, prediction, interval, guard)."""
        self._predictor = predictor

    def step(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> tuple[Prediction, np.ndarray]:
        """(the prediction, the design D (n, P)) of one sample: `predict` with the design computed here, in
        generated C when a predictor is attached (the same formulas)."""
        f = self._predictor
        if f is None:
            D = self.design(q[None], dq[None], ddq[None])[0]
            return self.predict(q, dq, ddq, D), D
        if f(q, dq, ddq) != 0:
            raise FloatingPointError("the compiled prediction failed")
        extrapolating = self.support is not None and f.logp[0] < self.support.threshold
        return Prediction(f.tau.copy(), f.par.copy(), f.std.copy(), bool(extrapolating)), f.Yt

    def use_kernel(self, kernel) -> None:
        """Let `add` run in generated C (`online_kernel.attach`): the statistics' factor lives in the C state from now
        on (the NumPy normal equations are dropped), θ is read back after each call."""
        self._kernel = kernel
        self._H = self._h = None
        self.parametric_var = np.ascontiguousarray(self.parametric_var, dtype=float)
        self._pv_address = self.parametric_var.ctypes.data

    def _transform(self, delta: np.ndarray) -> None:
        """Consistency transform for θ = θ0 + Δθ, from the offline GMR (module doc)."""
        d = self.gmr0.n_inputs
        self._gmr.means_[:, d:] = self.gmr0.means_[:, d:] - self._design_at_means @ delta
        if self._jac_at_means is None:
            return
        J = self._jac_at_means @ delta  # (K, n, 3n): ∂(D(x)Δθ)/∂x at μx_k
        S0 = self.gmr0.covariances_
        Sxx, Srx, Srr = S0[:, :d, :d], S0[:, d:, :d], S0[:, d:, d:]
        JSxx = J @ Sxx
        Jt = np.swapaxes(J, 1, 2)
        self._gmr.covariances_[:, d:, :d] = Srx - JSxx
        self._gmr.covariances_[:, :d, d:] = np.swapaxes(Srx - JSxx, 1, 2)
        self._gmr.covariances_[:, d:, d:] = Srr - J @ np.swapaxes(Srx, 1, 2) - Srx @ Jt + JSxx @ Jt


class _FastGMR:
    """One-sample GMR conditioning with the terms that do not change online precomputed (the mean-only
    consistency transform moves only the output means μr_k): E[r | x], diag Cov[r | x] and log p(x) of the
    input marginal, the same formulas as `gmr.conditional` without re-deriving Cholesky factors each call."""

    def __init__(self, gmr):
        c = conditioning(gmr.weights_, gmr.means_, gmr.covariances_, gmr.n_inputs)
        K, d, _ = c.W.shape
        self.K, self.d, self.o = K, d, c.A.shape[1]
        self.W_all = np.ascontiguousarray(np.swapaxes(c.W, 0, 1).reshape(d, K * d))
        self.offs = np.einsum("ki,kij->kj", c.mu_x, c.W).reshape(K * d)
        self.log_norm = c.log_norm
        self.A_all = np.ascontiguousarray(np.transpose(c.A, (2, 0, 1)).reshape(d, K * self.o))
        self.A_mu = np.einsum("kod,kd->ko", c.A, c.mu_x)  # (K, o)
        self.C_diag = np.einsum("kii->ki", c.C)  # (K, o)

    def predict(self, x: np.ndarray, means: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """(E[r | x] (o,), diag Cov[r | x] (o,), log p(x)) for one x (d,), with the current `means` (K, d + o)."""
        z = (x @ self.W_all - self.offs).reshape(self.K, self.d)
        log_p = self.log_norm - 0.5 * np.einsum("kd,kd->k", z, z)
        top = log_p.max()
        e = np.exp(log_p - top)
        total = e.sum()
        h = e / total
        m = (x @ self.A_all).reshape(self.K, self.o) + (means[:, self.d :] - self.A_mu)
        mean = h @ m
        dev = m - mean
        var = h @ (self.C_diag + dev * dev)
        return mean, var, float(top + np.log(total))


def batch_theta(
    estimator: Estimator,
    stats: Stats,
    theta_fixed: np.ndarray | None = None,
    rows: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """The from-scratch (cold-started) solution on `stats` (a ``factor`` estimator's on `rows`, the design rows and
    torques those statistics sum): what the online θ must equal (a cadence estimator's: at the samples where it
    re-solves)."""
    if estimator.kind == "fixed":
        return np.asarray(theta_fixed, dtype=float)
    if estimator.kind == "factor":
        return FactorBoundedLS(estimator.bounds, *rows).solve().pi
    if estimator.kind == "cadence":
        return estimator.solver.cold().refresh(stats)
    H, h, _ = stats.combined()
    fresh = Estimator(
        estimator.kind,
        estimator.penalty,
        estimator.bounds,
        estimator.solver.cold() if estimator.kind == "consistent" else None,
    )
    return fresh.make_solver()(H, h)


def arm_design_jacobian(model: Arm) -> Callable[[np.ndarray], np.ndarray]:
    """x = [q dq ddq] (3n,) -> ∂Y/∂x (n, 3n, P) of an arm's regressor (`ArmDesign.jacobian`)."""
    return ArmDesign(model).jacobian()


def lift(base: BaseParameters, stats: Stats) -> Stats:
    """The arm's statistics from those of its base parameters' design (exact: Y = Y_b K, so G = Kᵀ G_b K and
    b = Kᵀ b_b)."""
    K = base.K
    G = np.einsum("bp,jbc,cq->jpq", K, stats.G, K)
    return Stats(G, np.einsum("bp,jb->jp", K, stats.b), stats.s.copy(), stats.n)


@dataclass(frozen=True)
class Instruments:
    """An instrumented estimator's (`estimators.INSTRUMENTED`: the robust fit) statistics for the cadence: the
    training part's instrument statistics `offline` and its least-squares statistics `trained` (both on the arm's
    π; the instruments from the trial, `fitting.iv.InstrumentStats.from_data`). Samples arriving online carry no
    instruments (a stream has one derivative estimate): each enters as its own instrument (Z = Y), i.e. as least
    squares, so the re-solves keep the training part's correction of the noise bias and add the online samples as
    they are."""

    offline: InstrumentStats
    trained: Stats

    def with_online(self, seen: Stats) -> InstrumentStats:
        """The instrument statistics of every sample seen, from the arm's least-squares statistics of them all."""
        t = self.trained
        G, b = seen.G - t.G, seen.b - t.b
        return self.offline + InstrumentStats(G, b, G, Stats(G, b, seen.s - t.s, seen.n - t.n))


class Cadence:
    """An estimator without an exact online counterpart, followed by from-scratch re-solves: every `every` samples,
    `estimators.fit_for(robot, name, …)` on the exact statistics of every sample seen. The online statistics are
    those of the base parameters' design (Y_b, the independent columns); the arm's follow exactly, Y = Y_b K, so
    G = Kᵀ G_b K and b = Kᵀ b_b (`lift`). θ is the base parameters of the fit, K π; `fit` its `LinearFit` (π in
    the arm's own parameters, which the estimator keeps consistent)."""

    def __init__(
        self,
        robot,
        name: str,
        arm: Arm,
        base: BaseParameters,
        every: int = CONSISTENT_EVERY,
        instruments: Instruments | None = None,
    ):
        if every < 1:
            raise ValueError("a cadence needs every ≥ 1 samples")
        if (name in estimators.INSTRUMENTED) != (instruments is not None):
            raise ValueError(f"the {name} fit needs instruments exactly when it is instrumented")
        self.robot, self.name, self.arm, self.base, self.every = robot, name, arm, base, int(every)
        self.instruments = instruments
        self.fit: LinearFit | None = None
        self.refreshed = 0  # re-solves done
        self.seconds = 0.0  # spent in them
        self.least_eigenvalues: list[float] = []  # the fit's consistency measure at each re-solve

    def cold(self) -> Cadence:
        """The same estimator with no history (a from-scratch solve)."""
        return Cadence(self.robot, self.name, self.arm, self.base, self.every, self.instruments)

    def lift(self, stats: Stats) -> Stats:
        """The arm's statistics from those of its base parameters' design (`lift`)."""
        return lift(self.base, stats)

    def refresh(self, stats: Stats) -> np.ndarray:
        """θ = K π of the estimator's fit on `stats` (of the base design); raises what the fit raises."""
        t0 = time.perf_counter()
        lifted = self.lift(stats)
        if self.instruments is not None:
            lifted = self.instruments.with_online(lifted)
        fit = estimators.fit_for(self.robot, self.name, lifted, self.arm)
        if not np.isfinite(fit.pi).all():
            raise FloatingPointError(f"the {self.name} fit gave non-finite parameters")
        self.fit, self.refreshed = fit, self.refreshed + 1
        self.seconds += time.perf_counter() - t0
        self.least_eigenvalues.append(float(fit.min_mass_eigenvalue))
        return self.base.project(fit.pi)


def base_bounds(arm: Arm, base: BaseParameters) -> Bounds:
    """Bounds on the arm's base parameters that every consistent arm satisfies: 0 below those that are
    non-negative for every consistent π (`consistency.necessarily_nonnegative`: exactly those, where the arm's LMIs
    separate per link), else below those whose definition adds parameters of non-negative kind with positive
    coefficients only; free otherwise."""
    definite = necessarily_nonnegative(arm, base.K)
    if definite is None:
        signed = np.array([p.nonnegative for p in arm.parameters])
        K = np.where(np.abs(base.K) > 1e-9 * np.abs(base.K).max(axis=1, keepdims=True), base.K, 0.0)
        definite = np.array([bool(np.all(signed[row != 0]) and np.all(row[row != 0] > 0)) for row in K])
    lower = np.where(definite, 0.0, -np.inf)
    return Bounds(lower, np.full(base.rank, np.inf))


# ---------------------------------------------------------------------------------------------- the models
def model_keys(robot) -> tuple[str, ...]:
    """Online model keys in report order: RR, the robot's nominal models (dm, dm_…), pbr and cpbr (`models.fitted`):
    rr, dm, dm_physical, pbr, cpbr on the planar arm; rr, dm, pbr, cpbr on an n-joint URDF arm."""
    return ("rr", *datasheet_keys(robot), *fitted(robot))


def kinematic_design(q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """RR's design (N, n, n (3n + 1)): joint j's row holds [1, q1 … qn, dq1 … dqn, ddq1 … ddqn] in block j (its own
    intercept and weights), so θ = [c1, w1, …, cn, wn] and the ridge on the statistics is n ridges."""
    F = np.hstack([np.ones((len(q), 1)), q, dq, ddq])
    n, width = q.shape[1], F.shape[1]
    D = np.zeros((len(q), n, n * width))
    for j in range(n):
        D[:, j, j * width : (j + 1) * width] = F
    return D


def _kinematic_jacobian(n: int) -> Callable[[np.ndarray], np.ndarray]:
    """x -> ∂D/∂x of `kinematic_design` (n, 3n, n (3n + 1)): constant, the design is linear in x."""
    width = 3 * n + 1
    J = np.zeros((n, 3 * n, n * width))
    for j in range(n):
        for i in range(3 * n):
            J[j, i, j * width + 1 + i] = 1.0
    return lambda _x: J


@dataclass
class Start:
    """What one online model starts from: its design, estimator, offline θ0 and parameter names; `jacobian` makes
    x -> ∂D/∂x when asked (the cross-covariance update); `base`: the base parameters θ is about, when θ is not
    the arm's π (an n-joint arm's PBR and CPBR), else None."""

    key: str
    design: Design
    estimator: Estimator
    theta0: np.ndarray
    names: tuple[str, ...]
    jacobian: Callable[[], Callable[[np.ndarray], np.ndarray]]
    base: BaseParameters | None = None


def offline_start(
    key: str,
    problem,
    train,
    bounds: Bounds | None = None,
    margin: float = 1e-6,
    every: int = CONSISTENT_EVERY,
    choice: Choice | None = None,
) -> Start:
    """The offline fit of one model on the training trial (`ident_opt.models.hybrid` for RR's penalty and the
    datasheet π): rr — ridge with the per-joint penalty RidgeCV picks; dm, dm_… — the datasheet (fixed);
    pbr, cpbr — their estimator (`models.fitted`) followed online as `estimators.ONLINE` says (module doc): box-
    bounded LS (`fitting.bounded.default_bounds`, or `base_bounds` on the base parameters, unless `bounds`), or
    M(q) ⪰ margin·I for all q [kg m²] with the same box; an estimator without an online counterpart is re-solved
    from scratch every `every` samples (`Cadence`). `choice`: the fit cpbr is (None: the arm's consistent fit)."""
    robot = problem.robot
    if key == "rr":
        return _ridge_start(train)
    datasheets = datasheet_keys(robot)
    if key in datasheets:
        dm = datasheet_model(robot, datasheets[key])
        design = ArmDesign(dm.arm)
        return Start(key, design, Estimator("fixed"), dm.pi, design.names, design.jacobian)
    estimators_of = fitted(robot, choice.estimator if choice is not None else None)
    if key not in estimators_of:
        raise ValueError(f"unknown online model {key!r}; known: {', '.join(model_keys(robot))}")
    arm = robot.model(())
    base = base_parameters(arm)
    full = base.rank == arm.n_params
    design = ArmDesign(arm) if full else ArmDesign(arm, tuple(int(i) for i in base.independent))
    stats = Stats.from_data(arm, train.q, train.dq, train.ddq, train.tau)
    if not full:
        stats = base.stats(stats)
    name = estimators_of[key]
    if name not in estimators.ONLINE:
        instruments = None
        if name in estimators.INSTRUMENTED:
            instruments = Instruments(estimators.statistics(arm, [train], name), lift(base, stats))
        estimator = Estimator("cadence", solver=Cadence(robot, name, arm, base, every, instruments))
        theta0 = estimator.solver.refresh(stats)
    elif full:
        estimator = online_estimator(name, arm, bounds or default_bounds(arm), margin)
        theta0 = batch_theta(estimator, stats)
    else:  # the base parameters' information is ill-conditioned: their bounded LS on a square-root factor
        if estimators.ONLINE[name] != "bounded":
            raise ValueError(f"no online form of {name!r} on base parameters")
        estimator = Estimator("factor", bounds=bounds or base_bounds(arm, base))
        theta0 = batch_theta(estimator, stats, rows=(design(train.q, train.dq, train.ddq), train.tau))
    return Start(key, design, estimator, theta0, design.names, design.jacobian, None if full else base)


def online_estimator(name: str, arm: Arm, bounds: Bounds, margin: float = 1e-6) -> Estimator:
    """The online counterpart (`fitting.estimators.ONLINE`) of estimator `name` on `arm`'s model (on its π), within
    `bounds`; `margin` [kg m²] of M(q) ⪰ margin·I for the consistent one."""
    kind = estimators.ONLINE[name]
    return Estimator(
        kind, bounds=bounds, solver=WarmConsistentLS(arm, bounds, margin) if kind == "consistent" else None
    )


def _ridge_start(train) -> Start:
    """RR: the ridge RidgeCV fits offline, as θ = [c1, w1, …, cn, wn] of `kinematic_design`."""
    ridge = RidgeModel().fit(train)
    n = train.q.shape[1]
    features = kinematic_columns(n)[1:]
    alpha = np.broadcast_to(ridge.alpha_, (n,))
    penalty = np.concatenate([np.r_[0.0, np.full(len(features), a)] for a in alpha])  # intercepts unpenalised
    theta0 = np.concatenate([np.r_[ridge.intercept_[j], ridge.coef_[j]] for j in range(n)])
    names = tuple(f"{w}_{j + 1}" for j in range(n) for w in ("c", *features))
    return Start(
        "rr", kinematic_design, Estimator("ridge", penalty=penalty), theta0, names, lambda: _kinematic_jacobian(n)
    )


def start_identifier(
    start: Start, train, gmr=None, cross_covariance: bool = False, guard: bool = False
) -> OnlineIdentifier:
    """The online identifier of `start` with the statistics of the training trial; `gmr` (unfitted, e.g.
    `models.make_gmr(problem.residual)`) is fitted here on x = [q dq ddq] → r = τ − Dθ0; `guard`: the
    extrapolation guard (`gmr.Support` of the GMR on the training inputs; `OnlineIdentifier.predict`)."""
    D = start.design(train.q, train.dq, train.ddq)
    stats0 = Stats.from_regressor(D, train.tau)
    support = None
    if gmr is not None:
        gmr.fit(features(train), train.tau - D @ start.theta0)
        support = Support.fit(gmr, features(train)) if guard else None
    online = OnlineIdentifier(
        start.design,
        start.estimator,
        start.theta0,
        stats0,
        gmr=gmr,
        cross_covariance=cross_covariance,
        design_jacobian=start.jacobian() if cross_covariance else None,
        support=support,
        rows=(D, train.tau),
    )
    if start.estimator.kind == "ridge":
        # The recursive ridge reproduces the offline ridge on the same data (a check, not a fit), judged on the
        # torques: on collinear features (the KUKA's 21, κ ≈ 1e8) the normal equations and RidgeCV's SVD agree
        # to ~κ·ε in the weights only, while their torques agree to ~1e-8 of the torque's RMS.
        gap = np.abs(D @ (online.theta - start.theta0)).max()
        if not gap <= RIDGE_AGREEMENT * np.sqrt(np.mean(train.tau**2)):
            raise RuntimeError("ridge on the statistics differs from the offline RidgeCV fit")
    return online


def serving_identifier(
    model: str,
    problem,
    train,
    components: int | None = None,
    cross_covariance: bool = False,
    guard: bool = True,
    compiled: bool = True,
    every: int = CONSISTENT_EVERY,
    choice: Choice | None = None,
) -> tuple[Start, OnlineIdentifier]:
    """The identifier `ident-opt online --stream` serves, fitted offline on `train`: `model` is a key of
    `model_keys`, with ``+gmr`` for its GMR residual (K = `components`, else the problem's; chosen on blocked
    validation: the model will predict later motions); `guard`: the GMR's extrapolation guard; `compiled`: the
    bounded update in generated C (`online_kernel.attach`) when a C compiler is available; `every`: a cadence
    estimator's samples between re-solves; `choice`: the fit cpbr is."""
    key, _, extra = model.partition("+")
    keys = model_keys(problem.robot)
    if key not in keys or extra not in ("", "gmr"):
        raise InputError(f"--model must be one of {', '.join(keys)}, optionally with +gmr; got {model!r}")
    start = offline_start(key, problem, train, every=every, choice=choice)
    gmr = make_gmr(problem.residual, components=components, validation="blocked") if extra else None
    ident = start_identifier(start, train, gmr, cross_covariance=cross_covariance, guard=guard)
    if compiled and isinstance(start.design, ArmDesign):
        from ident_opt.adaptation.kernel import attach  # deferred: imports the code generator (CasADi codegen)

        attach(ident, start.design)
    return start, ident
