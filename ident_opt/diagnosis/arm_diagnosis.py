"""The four questions on an arm with n joints (`docs/effects.md`, "Arms with n joints"): the planar diagnosis's
rounds, scoring and JSON (`loop`), with the candidates of `arm_fit` and the arm's own nominal models.

- The two nominal models: the **datasheet** (the problem's nominal arm, `Robot.datasheets()[Robot.datasheet]`:
  the URDF's inertials with the problem's joint values) and the **rigid fit** (π by the recommended fit unless
  --estimator says otherwise, `fitting.recommend.chosen`, given as `rigid_fit`; the robot's default estimator when
  none is given; through `fitting.estimators.fit_for`, on the training part; joints weighted by 1/σ_j² from a
  first least-squares pass). Every candidate refits π with the same estimator (`arm_fit.ArmContext.rigid`).
- The split, the torque filter and the rest stretches are the planar diagnosis's (`loop.parts`). After the
  zero-phase filter the data hold nothing above its cut-off, so the diagnosis reads them every `decimation`-th
  sample (at about `DIAGNOSIS_HZ`, at most `MAX_SAMPLES` in all): a 7-joint minute at 1 kHz is diagnosed on 12 000
  samples, and `nmse_before` / `nmse_after` are measured on that subsample of the held-out part (the measured
  torque as logged, the same samples before and after).
- Scoring and naming as on the planar arm: a refitted π counts its rank (the number of base parameters the data
  determine) as its parameters.
"""

from __future__ import annotations

import time

import numpy as np

from ident_opt.arm.base import Robot
from ident_opt.data.dataset import Dataset
from ident_opt.diagnosis import arm_fit, evidence, loop, signals
from ident_opt.diagnosis.loop import Diagnosis, Fitted

#: Filter periods (1/cut-off) dropped at each end of a trial (`inner`).
EDGE_PERIODS = 3.0
#: The rate [Hz] the diagnosis reads a trial at, once low-passed (a whole-number decimation towards it).
DIAGNOSIS_HZ = 200.0
#: Most samples (training and held-out together) the diagnosis reads; longer trials are decimated further, down to
#: `MIN_RATIO` × the torque filter's cut-off.
MAX_SAMPLES = 24000
MIN_RATIO = 4.0


def decimation(rate_hz: float, cutoff_hz: float | None, samples: int) -> int:
    """Read every k-th sample: towards `DIAGNOSIS_HZ`, and towards `MAX_SAMPLES` in all, never below `MIN_RATIO` ×
    the filter's cut-off (none without a filter: the data then hold everything up to their Nyquist rate)."""
    if cutoff_hz is None or not np.isfinite(cutoff_hz):
        return 1
    floor = MIN_RATIO * cutoff_hz
    k = max(1, int(rate_hz // max(DIAGNOSIS_HZ, floor)))
    while samples / (k + 1) >= 1 and samples / k > MAX_SAMPLES and rate_hz / (k + 1) >= floor:
        k += 1
    return k


def inner(ds: Dataset, torque_filter_hz) -> Dataset:
    """The trial without its first and last `EDGE_PERIODS` periods of the filter's cut-off: there the zero-phase
    filters of the derivatives and the torque run out of data (a trial that ends in motion gets accelerations
    tens of times too large in its last samples)."""
    cutoff = ds.cutoff_hz if torque_filter_hz == "auto" or torque_filter_hz is None else torque_filter_hz
    if not cutoff:
        return ds
    edge = EDGE_PERIODS / cutoff
    keep = (ds.t >= ds.t[0] + edge) & (ds.t <= ds.t[-1] - edge)
    return ds.subset(np.nonzero(keep)[0]) if keep.sum() > ds.n // 2 else ds


def _every(ds: Dataset, k: int) -> Dataset:
    return ds if k == 1 else ds.subset(np.arange(0, ds.n, k))


def weights_of(ctx: arm_fit.ArmContext) -> np.ndarray:
    """1/σ_j² [1/(N m)²] of the training residual of the least-squares rigid fit (the projection off the rigid
    columns, every joint weighted alike)."""
    tr = ctx.train
    Q = ctx.basis(tr)
    y = ctx.rows(tr.tau[:, :, None], tr)[:, 0]
    r = (y - Q @ (Q.T @ y)).reshape(tr.n, ctx.n)
    var = np.mean(r**2, axis=0)
    return 1.0 / np.maximum(var, 1e-12 * np.maximum(np.var(tr.tau, axis=0), 1e-30))


def diagnose(
    robot: Robot,
    trial: Dataset,
    unseen: Dataset | None = None,
    train_fraction: float = 0.7,
    progress: bool = True,
    torque_filter_hz: float | str | None = signals.TORQUE_FILTER_HZ,
    rigid_fit=None,
) -> Diagnosis:
    """Diagnose `trial` (and `unseen`, if given, as the held-out data) of an n-joint arm; see the module docstring
    and `loop.diagnose`. `rigid_fit`: a `fitting.recommend.Recommendation` (estimator, why), None: the robot's
    default estimator."""
    estimator = robot.default_estimator if rigid_fit is None else rigid_fit.estimator
    t0 = time.perf_counter()
    trial, unseen = (None if d is None else inner(d, torque_filter_hz) for d in (trial, unseen))
    train, test, raw_test, how = loop.parts(trial, unseen, train_fraction, torque_filter_hz, robot.joint_names)
    rate = 1.0 / float(np.median(np.diff(train.t)))
    cutoff = train.cutoff_hz if torque_filter_hz == "auto" else torque_filter_hz
    k = decimation(rate, cutoff, train.n + test.n)
    train, test, raw_test = (_every(d, k) for d in (train, test, raw_test))
    if k > 1:
        how += f"; one sample in {k} kept ({rate / k:g} Hz) after the {cutoff:g} Hz low-pass"
    arm, pi_ds = robot.datasheets()[robot.datasheet]
    dt = float(np.median(np.diff(train.t)))
    ctx = arm_fit.ArmContext(
        robot,
        arm,
        train,
        test,
        np.ones(robot.n_joints),
        np.asarray(pi_ds, dtype=float),
        dt,
        None,
        estimator,
        cutoff,
    )
    ctx.rest = ctx.labels(train)
    ctx.reweight(weights_of(ctx))
    pi_rigid = ctx.rigid(ctx.regressor(train), train.tau, train)
    ctx.pi_rigid, ctx.rank = pi_rigid, ctx.basis(train).shape[1]
    rest_test = ctx.labels(test)

    Y_test = ctx.regressor(test)
    nominal_pi = {"datasheet": ctx.datasheet, "rigid_fit": pi_rigid}
    nominal_pred = {b: Y_test @ pi for b, pi in nominal_pi.items()}
    nominal, nominal_mse = loop.nominal_entries(
        nominal_pi, nominal_pred, test, rest_test, arm.as_dict, estimator, rigid_fit
    )
    nominal["rigid_fit"]["rank"] = ctx.rank
    t_nominal = time.perf_counter()
    var = np.var(test.tau, axis=0)

    engine = arm_fit.Engine(ctx)

    version = loop.versions(test, rest_test, nominal_mse["datasheet"], ctx.rank)

    def row(v: Fitted, score: float, current: dict, gap=None) -> dict:
        floor, partner = engine.MARGIN_VARIANCE, engine.PARTNER
        return loop._row(v, score, current, raw_test.tau, test, rest_test, var, dt, gap, floor, partner)

    current = {b: version(None, b, nominal_pred[b], (), None, {}) for b in nominal_pred}
    rounds = loop._rounds(robot, ctx, current, version, row, var, progress, engine)
    t_fit = time.perf_counter()

    def forward_after(final: Fitted | None, baseline: str) -> list:
        """The extended model's rigid part (its π: refitted, or the datasheet's) integrated, the rest of its
        torque teacher-forced (`evidence.forward_error`)."""
        if final is None:
            return evidence.forward_error(arm, nominal_pi[baseline], test, dt)
        params = final.cand.parameters
        pi = arm.vector(params) if all(name in params for name in arm.names) else ctx.datasheet
        rigid = Y_test @ pi
        return evidence.forward_error(arm, pi, test, dt, extension=final.pred - rigid)

    result = loop.conclude(
        rounds,
        (nominal, nominal_pi, nominal_pred),
        (train, test, raw_test, how, trial if unseen is not None else None),
        arm,
        forward_after,
        {"nominal": t_nominal - t0, "candidates": t_fit - t_nominal, "t0": t0},
        robot.joint_names,
        evidence.pose_r2_any,
        rest_test,
    )
    result.margin_variance = engine.MARGIN_VARIANCE
    result.partner = engine.PARTNER
    result.evidence["screening"] = {
        "elastic_joints": [robot.joint_names[j] for j in ctx.evidence.get("elastic_joints", [])],
        "decimation": k,
        "weights": ctx.weights.tolist(),
    }
    return result
