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
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ident_opt.adaptation.estimator import Estimator
from ident_opt.arm.base import Arm
from ident_opt.fitting.bounded import FactorBoundedLS
from ident_opt.fitting.stats import Stats
from ident_opt.models.gmr import Support, conditioning, input_log_density

#: z-value of the central 95 % interval of a Gaussian.
Z95 = 1.959963984540054
#: Samples over which the parametric model's one-step residual variance is averaged (exponential weights).
PARAMETRIC_MEMORY = 500.0
ALPHA = 1.0 / PARAMETRIC_MEMORY
#: Largest torque difference [× the torque's RMS] between the recursive ridge and RidgeCV on the training data.
RIDGE_AGREEMENT = 1e-6

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


def arm_design_jacobian(model: Arm) -> Callable[[np.ndarray], np.ndarray]:
    """x = [q dq ddq] (3n,) -> ∂Y/∂x (n, 3n, P) of an arm's regressor (`ArmDesign.jacobian`)."""
    return ArmDesign(model).jacobian()
