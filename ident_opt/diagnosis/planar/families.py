"""One candidate model family per catalogue cause, fitted on the training part.

Each cause's module in `ident_opt.effects` declares its *family* of models τ̂ = o(θ) + X(θ) β (see
`linear.py`), built from the `PlanarArm` extensions where the effect is linear in its parameters, plus a few
nonlinear parameters θ searched by variable projection (`Effect.families`, `docs/effects.md`). It is fitted
against one or both nominal models:

- ``datasheet``: the problem file's π held fixed; only the effect's own parameters are fitted (this is
  where parameter-level causes show: armature, payload, mis-scaled or asymmetric friction).
- ``rigid_fit``: every π of the nominal structure refitted together with the effect (structural causes
  that no choice of π absorbs: friction shape, elasticity, delay, offsets); π by the diagnosis's estimator
  (`Context.rigid`), the effect's coefficients by variable projection (`_estimated`).

After the search, a family may polish θ with IPOPT (`PlanarFamily.polish`: a proposal re-solved and kept only
if it lowers the training objective; its estimates before and after land in the candidate's
`detail["polish"]`, the JSON's extra keys) or refine θ and β jointly (`PlanarFamily.refine`). IPOPT sees at most
`POLISH_ROWS` samples (evenly strided: CasADi builds the expression graph per sample, so a 2 kHz trial
would otherwise cost seconds just to set up).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import ClassVar

import numpy as np

from ident_opt.arm.datasheet import PlanarRobot
from ident_opt.arm.planar import PHYSICAL, PlanarArm
from ident_opt.data.dataset import Dataset
from ident_opt.diagnosis import scoring
from ident_opt.effects import CATALOGUE
from ident_opt.effects.families import PlanarFamily
from ident_opt.fitting.estimators import INSTRUMENTED, fit_for
from ident_opt.fitting.iv import InstrumentStats, instrument_kinematics
from ident_opt.fitting.stats import Stats
from ident_opt.numerics import least_squares as linear
from ident_opt.numerics import signals

#: The nominal structure under the physical convention (the datasheet has the joint-2 armature ia2).
NOMINAL = PHYSICAL
#: Rows used by the nonlinear search: longer trials are strided down to about this many samples
#: (the final linear solve always uses every sample).
SEARCH_ROWS = 12000
#: Later rounds search again only the causes the first round found promising (`rounds._fit_round`): the planar
#: searches and IPOPT polishes are the diagnosis's main cost.
SEARCH_AGAIN = False
#: The least share of a joint's torque variance a named cause removes (`scoring.shortfall`): the planar floor.
MARGIN_VARIANCE = scoring.MARGIN_VARIANCE
#: Most re-solves of a family whose columns depend on its coefficients (`PlanarFamily.coupled`).
COUPLING_STEPS = 5
#: Relative step of the central differences in θ (`joint_errors`).
THETA_STEP = 1e-4


@dataclass
class Context:
    """What every candidate needs: the robot, the training and held-out parts, joint weights 1/σ_j²."""

    robot: PlanarRobot
    train: Dataset
    test: Dataset
    weights: np.ndarray
    datasheet: dict[str, float]
    dt: float
    rest: np.ndarray  # rest-stretch labels of the training part (`signals.rest_runs`)
    armature: tuple[float, float] = (0.0, 0.0)  # the datasheet's reflected rotor inertia per joint [kg m²]
    #: How a refitted π is estimated (`fitting.estimators`: the recommended fit; `rigid`); None: jointly with the
    #: effect's coefficients by weighted least squares (the studies that compare causes' families use that).
    estimator: str | None = None
    #: What the candidates compute once per data view and ask for again at every grid point (e.g. an elastic
    #: joint's drive, `effects.elasticity.elastic_drive`), by key.
    cache: dict = field(default_factory=dict, repr=False, compare=False)

    #: The nominal structure (`NOMINAL`): what an effect's candidate extends.
    nominal: ClassVar[PlanarArm] = NOMINAL

    @staticmethod
    def model(extensions: tuple[str, ...]) -> PlanarArm:
        """The planar arm with `extensions` (`ident_opt.effects`): a candidate's model."""
        return PlanarArm(tuple(extensions))

    def rigid(self, model: PlanarArm, Y: np.ndarray, target: np.ndarray, Z: np.ndarray | None = None) -> np.ndarray:
        """π (P,) of `model` by the context's estimator on τ = `target` (N, 2) [N m] with regressor Y (N, 2, P) along
        the training part (instruments Z (N, 2, P) for an instrumented estimator), rest stretches compared about
        their means and the joints weighted as every candidate is: the one place the planar diagnosis fits π."""
        Yd, t = signals.demean_runs(Y, self.rest), signals.demean_runs(target, self.rest)
        stats = Stats.from_regressor(Yd, t)
        if self.estimator in INSTRUMENTED:
            stats = InstrumentStats.from_regressors(Yd, signals.demean_runs(Z, self.rest), t)
        return fit_for(self.robot, self.estimator, stats, model, weights=self.weights).pi

    @cached_property
    def instrumented(self) -> Dataset | None:
        """The training part at its instruments' kinematics (velocities at rest held at 0, as `data.dataset.at_rest`
        holds the measured ones), or None when the estimator takes no instruments; built once per context."""
        if self.estimator not in INSTRUMENTED:
            return None
        dq, ddq = instrument_kinematics(self.train)
        return replace(self.train, dq=np.where(self.train.dq == 0.0, 0.0, dq), ddq=ddq)


@dataclass
class Candidate:
    """A fitted extension: its catalogue estimate, parameters (with standard errors) and a predictor."""

    cause: str
    baseline: str
    estimate: dict
    parameters: dict[str, float]
    se: dict[str, float]
    n_added: int
    predict: Callable[[Dataset], np.ndarray]
    detail: dict = field(default_factory=dict)
    #: `errors()`: standard errors of every coefficient and every θ jointly, residual correlation counted
    #: (`joint_errors`); `se` holds the coefficients' with θ taken as known and independent residuals (what
    #: the searches use). Computed on demand: only the reported model needs them.
    errors: Callable[[], dict[str, float]] | None = None


def model_of(family: PlanarFamily, theta: dict) -> PlanarArm:
    """The PlanarArm of `family` at θ: its own (`PlanarFamily.model`), or the nominal structure when it adds no
    model extension."""
    return family.model(theta) if family.model is not None else NOMINAL


_CACHE: dict = {}


def _regressor(model: PlanarArm, ds: Dataset, rows: slice) -> np.ndarray:
    """model.regressor on ds[rows], remembered for the last few (model, data) pairs: the searches over a
    delay or a mode re-use the same regressor hundreds of times."""
    key = (model, id(ds), ds.n, rows.start, rows.stop, rows.step)
    if key not in _CACHE:
        if len(_CACHE) > 8:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = (ds, model.regressor(ds.q[rows], ds.dq[rows], ds.ddq[rows]))
    return _CACHE[key][1]


def design(
    family: PlanarFamily, ds: Dataset, theta: dict, baseline: str, ctx: Context, rows: slice = slice(None)
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(o, X, names) of `family` at θ on `ds` (rows `rows`), against `baseline` (see the module docstring)."""
    model = model_of(family, theta)
    if family.angles is not None:  # the model, and every extra column, at the true angles q + δ (no cache)
        ds = replace(ds, q=ds.q + family.angles(theta))
        Y = model.regressor(ds.q[rows], ds.dq[rows], ds.ddq[rows])
    else:
        Y = _regressor(model, ds, rows)
    n = Y.shape[0]
    if baseline == "datasheet":
        pi = model.vector(ctx.datasheet)
        free = [i for i, n in enumerate(model.names) if n in (family.free or ())]
        fixed = [i for i in range(model.n_params) if i not in free]
        offset = Y[:, :, fixed] @ pi[fixed]
        X, names = Y[:, :, free], [model.names[i] for i in free]
    else:
        offset, X, names = np.zeros((n, 2)), Y, list(model.names)
    if family.extra is not None:
        cols, extra_names = family.extra(ds, theta, ctx.dt, ctx)
        X = np.concatenate([X, cols[rows]], axis=2)
        names = names + extra_names
    if family.transform is not None:
        offset, X, names = family.transform(offset, X, names, theta, ctx.dt * (rows.step or 1))
    return offset, X, names


def search_axes(family: PlanarFamily, baseline: str, ctx: Context) -> list[linear.Axis]:
    """The family's θ axes, centred where its `center` says (e.g. an offset read from the gravity columns)."""
    axes = family.axes(1.0 / ctx.dt)
    if family.center is None:
        return axes
    c = family.center(ctx, baseline)
    return [linear.Axis(a.name, a.low + c[a.name], a.high + c[a.name], a.points, a.log) for a in axes]


def _solve(family: PlanarFamily, ctx: Context, o, X, names, tau, labels, with_se: bool) -> linear.LinearSolve:
    """β by WLS (nonnegative where the family says), data and columns compared about each rest stretch's
    mean (`signals.demean_runs`: within a rest stretch only variations count)."""
    signed = [i for i, n in enumerate(names) if n in family.nonnegative]
    target = signals.demean_runs(tau - o, labels)
    return linear.solve_nonnegative(
        np.zeros_like(target), signals.demean_runs(X, labels), target, ctx.weights, signed, with_se
    )


def _polish(family: PlanarFamily, baseline: str, ctx: Context, axes: list, theta: dict, o, X, names, ls) -> tuple:
    """`family.polish` from the search's answer, kept only if β re-solved at the proposal fits better.
    Returns (θ, o, X, fit, the polish record or None)."""
    bounds = {a.name: (a.low, a.high) for a in axes}
    proposal, nlp = family.polish(baseline, ctx, o, X, ls.beta, theta, bounds)
    if nlp is None:
        return theta, o, X, ls, None
    searched = {**dict(zip(names, map(float, ls.beta))), **theta}
    nlp["before"] = family.estimate(searched, dict.fromkeys(searched, 0.0), ctx)
    nlp["cost_before"], nlp["kept"] = ls.cost, False
    if proposal is not None:
        proposal = {**theta, **proposal}
        o2, X2, _ = design(family, ctx.train, proposal, baseline, ctx)
        ls2 = _solve(family, ctx, o2, X2, names, ctx.train.tau, ctx.rest, True)
        nlp["cost_after"] = ls2.cost
        if ls2.cost < ls.cost:  # β re-solved exactly at the polished θ; kept only if it fits better
            theta, o, X, ls, nlp["kept"] = proposal, o2, X2, ls2, True
    return theta, o, X, ls, nlp


def _couple(family: PlanarFamily, baseline: str, ctx: Context, theta: dict, o, X, names, ls) -> tuple:
    """Columns that depend on the coefficients (`PlanarFamily.coupled`): re-solve until what they read settles.
    Returns (the coupled θ entries, o, X, fit)."""
    coupling: dict = {}
    for _ in range(COUPLING_STEPS):
        update = family.coupled(dict(zip(names, map(float, ls.beta))))
        if all(abs(v - coupling.get(k, 0.0)) <= 1e-6 * (1.0 + abs(v)) for k, v in update.items()):
            break
        coupling = update
        o, X, _ = design(family, ctx.train, {**theta, **coupling}, baseline, ctx)
        ls = _solve(family, ctx, o, X, names, ctx.train.tau, ctx.rest, True)
    return coupling, o, X, ls


def _estimated(
    family: PlanarFamily, baseline: str, ctx: Context, theta: dict, columns: tuple, beta: np.ndarray
) -> np.ndarray:
    """β against the `rigid_fit` baseline with the model's π estimated by the context's estimator (`Context.rigid`)
    rather than jointly by least squares (as is for the datasheet baseline, or a context without an estimator):
    π on τ − o − X_e β_e (X_e the effect's own columns, β_e from the joint fit: least squares for any β_e is
    variable projection), then β_e again on τ − o − Y π (sign constraints kept). With no column of its own this is
    the nominal rigid fit exactly, so every candidate is compared with it like with like. An instrumented
    estimator's instruments are the same design at the instruments' kinematics."""
    if baseline != "rigid_fit" or ctx.estimator is None:
        return beta
    o, X, names = columns
    model = model_of(family, theta)
    P = model.n_params  # the design against rigid_fit starts with the model's π (`design`)
    Xe, tau = X[:, :, P:], ctx.train.tau
    Z = None
    at = ctx.instrumented
    if at is not None:
        Z = design(family, at, theta, "rigid_fit", ctx)[1][:, :, :P]
    pi = ctx.rigid(model, X[:, :, :P], tau - o - np.einsum("njk,k->nj", Xe, beta[P:]), Z)
    out = beta.copy()
    out[:P] = pi
    if Xe.shape[2]:
        offset = o + np.einsum("njk,k->nj", X[:, :, :P], pi)
        out[P:] = _solve(family, ctx, offset, Xe, names[P:], tau, ctx.rest, False).beta
    return out


def fit(family: PlanarFamily, baseline: str, ctx: Context) -> Candidate:
    """Fit one family against one baseline on the training part (θ by variable projection, β by WLS)."""
    stride = max(1, -(-ctx.train.n // SEARCH_ROWS))  # ceil: at most SEARCH_ROWS rows
    # A delay needs a uniform grid: stride by whole samples and delay on the strided grid.
    rows = slice(None, None, stride)
    train_sub, rest_sub = ctx.train.tau[rows], ctx.rest[rows]

    def cost(theta: dict) -> float:
        o, X, names = design(family, ctx.train, theta, baseline, ctx, rows)
        return _solve(family, ctx, o, X, names, train_sub, rest_sub, False).cost

    axes = search_axes(family, baseline, ctx)
    theta = {**family.fixed, **(linear.search(lambda th: cost({**family.fixed, **th}), axes) if axes else {})}
    o, X, names = design(family, ctx.train, theta, baseline, ctx)
    ls = _solve(family, ctx, o, X, names, ctx.train.tau, ctx.rest, True)
    nlp = None
    if family.polish is not None:
        theta, o, X, ls, nlp = _polish(family, baseline, ctx, axes, theta, o, X, names, ls)
    coupling: dict = {}
    if family.coupled is not None:
        coupling, o, X, ls = _couple(family, baseline, ctx, theta, o, X, names, ls)
    beta, polished = ls.beta.copy(), []
    if family.refine is not None:
        beta, theta, polished = family.refine(ctx, o, X, names, beta, theta)
    beta = _estimated(family, baseline, ctx, {**theta, **coupling}, (o, X, names), beta)
    params = dict(zip(names, map(float, beta)))
    se = dict(zip(names, map(float, ls.se)))
    if family.units is not None:
        params, se = physical_units(family.units(params), X, names, params, se, ctx.weights)
    params.update(theta)
    estimate, detail = family.estimate(params, se, ctx)
    if polished:
        detail["ipopt"] = polished
    if nlp is not None:
        nlp["after"] = family.estimate(params, se, ctx)
        for key in ("before", "after"):  # (estimate, detail) -> one flat dict: f, ζ, k, c, inertia
            est, det = nlp[key]
            nlp[key] = {**est, **{k: v for k, v in det.items() if k != "se"}}
        detail["polish"] = nlp
    nominal_free = len(NOMINAL.names) if baseline == "rigid_fit" else 0
    n_added = len(names) - nominal_free + len(theta)
    columns_theta = {**theta, **coupling}

    def predict(ds: Dataset) -> np.ndarray:
        o, X, _ = design(family, ds, columns_theta, baseline, ctx)
        return o + np.einsum("njk,k->nj", X, beta)

    _check(family, predict, theta, ctx, params, detail)

    def errors() -> dict[str, float]:
        joint = joint_errors(family, baseline, ctx, columns_theta, list(theta), (o, X, names), beta, ls.se)
        if family.units is None:
            return joint
        coefficients = dict(zip(names, map(float, beta)))
        return physical_units(family.units(coefficients), X, names, coefficients, joint, ctx.weights)[1]

    return Candidate(family.cause, baseline, estimate, params, se, n_added, predict, detail, errors)


def _check(family: PlanarFamily, predict, theta: dict, ctx: Context, params: dict, detail: dict) -> None:
    """The family's test of its fitted candidate (`PlanarFamily.check`) into `detail`: what it found, and
    `unresolved` with why when it fails."""
    if family.check is None:
        return
    found, reason = family.check(predict, theta, ctx, params)
    detail.update(found)
    if reason is not None:
        detail["unresolved"] = reason


def joint_errors(
    family: PlanarFamily,
    baseline: str,
    ctx: Context,
    theta: dict,
    keys: list[str],
    columns: tuple,
    beta: np.ndarray,
    se_linear: np.ndarray,
) -> dict[str, float]:
    """Standard errors of the coefficients β and of the searched θ (`keys`) together, on the training part.

    Gauss–Newton at the optimum (variable projection's covariance): the Jacobian J of the prediction is X for
    β and a central difference for each θ, compared about each rest stretch's mean as the fit is. The
    residuals are not independent (the torque is low-passed, and what the model misses is slow), so the
    covariance is the Newey–West sandwich H⁻¹ S H⁻¹, H = Jᵀ W J, S the long-run covariance of the per-sample
    scores g_t = Σ_j w_j J_tj r_tj with Bartlett weights out to `linear.hac_lag` samples (`linear.sandwich`). A
    θ such as an encoder offset thus gets the uncertainty the noise leaves it, and β's errors include what the
    uncertain θ adds. Columns held at 0 (a sign constraint, a negligible column) keep their conditional error, take
    no part.
    Bias from what the model lacks is not noise: no standard error covers it."""
    o, X, names = columns
    free = [i for i, e in enumerate(se_linear) if np.isfinite(e) and e > 0]
    cols = [X[:, :, free]]
    for k in keys:
        h = THETA_STEP * max(abs(float(theta[k])), 1e-3)
        side = []
        for v in (theta[k] + h, theta[k] - h):
            ov, Xv, _ = design(family, ctx.train, {**theta, k: v}, baseline, ctx)
            side.append(ov + np.einsum("njk,k->nj", Xv, beta))
        cols.append(((side[0] - side[1]) / (2 * h))[:, :, None])
    J = signals.demean_runs(np.concatenate(cols, axis=2), ctx.rest)
    r = signals.demean_runs(ctx.train.tau - o - np.einsum("njk,k->nj", X, beta), ctx.rest)
    err = linear.sandwich(J, r, ctx.weights)
    out = dict(zip(names, map(float, se_linear)))
    out.update({names[i]: float(e) for i, e in zip(free, err)})
    out.update({k: float(e) for k, e in zip(keys, err[len(free) :])})
    return out


def physical_units(
    units: tuple[np.ndarray, tuple[str, ...]],
    X: np.ndarray,
    names: list[str],
    params: dict[str, float],
    se: dict[str, float],
    weights: np.ndarray,
) -> tuple[dict, dict]:
    """Coefficients fitted against a rescaled logged torque, in joint-torque units.

    With τ_logged,j = τ_j / s_j, a coefficient whose column lives on joint j's row only is fitted as β/s_j,
    so β = s_j × the fitted one (exact). A column on both rows (a payload's mass) is scaled by s averaged
    over the rows with the share of the column's weighted energy on each (first order in s1 − s2).
    `units`: (s (2,), the rescaling family's own names, left as they are)."""
    s, own = units
    energy = np.einsum("njk,njk,j->jk", X, X, weights)  # (2, K): each column's weighted energy per row
    total = energy.sum(axis=0)
    factor = np.where(total > 0, s @ (energy / np.where(total > 0, total, 1.0)), 1.0)
    params, se = dict(params), dict(se)
    for k, name in enumerate(names):
        if name not in own:
            params[name] *= float(factor[k])
            se[name] *= float(factor[k])
    return params, se


# ---------------------------------------------------------------------------------------------- families
def families(ctx: Context) -> list[PlanarFamily]:
    """Every catalogue cause's families (`Effect.families`, given the context), in catalogue order."""
    return [family for effect in CATALOGUE.values() for family in effect.families(ctx)]
