"""The offline start of an online model and the identifier that serves it: each model's fit on the training part
(`offline_start`: rr, the nominal models, pbr and cpbr by their estimators, followed online as
`fitting.estimators.ONLINE` says), the identifier started from it (`start_identifier`), and the one `online --stream`
serves (`serving_identifier`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ident_opt.adaptation.estimator import (
    CONSISTENT_EVERY,
    Cadence,
    Estimator,
    Instruments,
    base_bounds,
    batch_theta,
    lift,
)
from ident_opt.adaptation.identifier import RIDGE_AGREEMENT, ArmDesign, Design, OnlineIdentifier
from ident_opt.arm.base import Arm
from ident_opt.columns import kinematic_columns
from ident_opt.errors import InputError
from ident_opt.fitting import estimators
from ident_opt.fitting.base import BaseParameters, base_parameters
from ident_opt.fitting.bounded import Bounds, default_bounds
from ident_opt.fitting.bounded_consistent import WarmConsistentLS
from ident_opt.fitting.recommend import Choice
from ident_opt.fitting.stats import Stats
from ident_opt.models.gmr import Support
from ident_opt.models.hybrid import RidgeModel, datasheet_keys, datasheet_model, features, fitted, make_gmr


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
