"""The diagnosis engine of an arm with n joints (`engine.Engine`; `docs/effects.md`, "Arms with n joints"): the
candidates of `chain.families` and the arm's own nominal models, under the one loop's rounds, scoring and JSON
(`rounds`).

- The two nominal models: the **datasheet** (the problem's nominal arm, `Robot.datasheets()[Robot.datasheet]`:
  the URDF's inertials with the problem's joint values) and the **rigid fit** (π by the recommended fit unless
  --estimator says otherwise, `fitting.recommend.chosen`, given as `rigid_fit`; the robot's default estimator when
  none is given; through `fitting.estimators.fit_for`, on the training part; joints weighted by 1/σ_j² from a
  first least-squares pass). Every candidate refits π with the same estimator (`chain.context.ArmContext.rigid`).
- The split, the torque filter and the rest stretches are the planar diagnosis's (`split.parts`). After the
  zero-phase filter the data hold nothing above its cut-off, so the diagnosis reads them every `decimation`-th
  sample (at about `DIAGNOSIS_HZ`, at most `MAX_SAMPLES` in all): a 7-joint minute at 1 kHz is diagnosed on 12 000
  samples, and `nmse_before` / `nmse_after` are measured on that subsample of the held-out part (the measured
  torque as logged, the same samples before and after).
- Scoring and naming as on the planar arm: a refitted π counts its rank (the number of base parameters the data
  determine) as its parameters.
"""

from __future__ import annotations

import numpy as np

from ident_opt.arm.base import Robot
from ident_opt.data.dataset import Dataset
from ident_opt.diagnosis import evidence
from ident_opt.diagnosis.chain import families as candidates
from ident_opt.diagnosis.chain.search import ChainContext
from ident_opt.diagnosis.engine import Nominal, Parts
from ident_opt.diagnosis.result import Fitted
from ident_opt.diagnosis.split import parts

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


def weights_of(ctx: ChainContext) -> np.ndarray:
    """1/σ_j² [1/(N m)²] of the training residual of the least-squares rigid fit (the projection off the rigid
    columns, every joint weighted alike)."""
    tr = ctx.train
    Q = ctx.basis(tr)
    y = ctx.rows(tr.tau[:, :, None], tr)[:, 0]
    r = (y - Q @ (Q.T @ y)).reshape(tr.n, ctx.n)
    var = np.mean(r**2, axis=0)
    return 1.0 / np.maximum(var, 1e-12 * np.maximum(np.var(tr.tau, axis=0), 1e-30))


class ChainEngine:
    """The engine of an arm with n joints (module doc); built on the trials to diagnose."""

    margin_variance = candidates.Engine.MARGIN_VARIANCE
    partner = candidates.Engine.PARTNER
    search_again = candidates.Engine.SEARCH_AGAIN
    pose = staticmethod(evidence.pose_r2_any)

    def __init__(
        self,
        robot: Robot,
        trial: Dataset,
        unseen: Dataset | None,
        train_fraction: float,
        torque_filter_hz: float | str | None,
        estimator: str,
    ) -> None:
        self.robot = robot
        trial, unseen = (None if d is None else inner(d, torque_filter_hz) for d in (trial, unseen))
        train, test, raw_test, how = parts(trial, unseen, train_fraction, torque_filter_hz, robot.joint_names)
        rate = 1.0 / float(np.median(np.diff(train.t)))
        cutoff = train.cutoff_hz if torque_filter_hz == "auto" else torque_filter_hz
        self.decimation = k = decimation(rate, cutoff, train.n + test.n)
        train, test, raw_test = (_every(d, k) for d in (train, test, raw_test))
        if k > 1:
            how += f"; one sample in {k} kept ({rate / k:g} Hz) after the {cutoff:g} Hz low-pass"
        self.parts = Parts(train, test, raw_test, how, trial if unseen is not None else None)
        arm, pi_ds = robot.datasheets()[robot.datasheet]
        self.dt = float(np.median(np.diff(train.t)))
        ctx = ChainContext(
            robot,
            arm,
            train,
            test,
            np.ones(robot.n_joints),
            np.asarray(pi_ds, dtype=float),
            self.dt,
            None,
            estimator,
            cutoff,
        )
        ctx.rest = ctx.labels(train)
        ctx.reweight(weights_of(ctx))
        pi_rigid = ctx.rigid(ctx.regressor(train), train.tau, train)
        ctx.pi_rigid, ctx.rank = pi_rigid, ctx.basis(train).shape[1]
        self.ctx = ctx
        self.Y_test = ctx.regressor(test)
        pi = {"datasheet": ctx.datasheet, "rigid_fit": pi_rigid}
        pred = {b: self.Y_test @ p for b, p in pi.items()}
        self.nominal = Nominal(arm, pi, pred, ctx.rank, ctx.labels(test), {"rank": ctx.rank})
        self._engine: candidates.Engine | None = None

    @property
    def engine(self) -> candidates.Engine:
        """The candidate families, built once (with the evidence per joint) when first asked."""
        if self._engine is None:
            self._engine = candidates.Engine(self.ctx)
        return self._engine

    def families(self) -> list:
        return self.engine.families(self.robot)

    def fit(self, family, baseline: str):
        return candidates.fit(family, baseline, self.ctx)

    def compose(self, earlier: list[tuple], new):
        return candidates.compose(earlier, new)

    def frozen(self, family, theta: dict):
        return candidates.frozen(family, theta)

    def theta(self, family, cand) -> dict:
        return candidates.theta_of(family, cand, self.ctx)

    def forward_after(self, final: Fitted | None, baseline: str) -> list:
        """The extended model's rigid part (its π: refitted, or the datasheet's) integrated, the rest of its
        torque teacher-forced (`evidence.forward_error`)."""
        arm, test = self.nominal.model, self.parts.test
        if final is None:
            return evidence.forward_error(arm, self.nominal.pi[baseline], test, self.dt)
        params = final.cand.parameters
        pi = arm.vector(params) if all(name in params for name in arm.names) else self.ctx.datasheet
        rigid = self.Y_test @ pi
        return evidence.forward_error(arm, pi, test, self.dt, extension=final.pred - rigid)

    def screening(self) -> dict | None:
        """The joints screened for an elastic mode, the decimation and the joint weights."""
        return {
            "elastic_joints": [self.robot.joint_names[j] for j in self.ctx.evidence.get("elastic_joints", [])],
            "decimation": self.decimation,
            "weights": self.ctx.weights.tolist(),
        }
