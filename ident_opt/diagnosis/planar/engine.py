"""The planar two-link arm's diagnosis engine (`engine.Engine`): the paper's grouped π under the physical convention
(`candidates.NOMINAL`), the candidate families of `candidates`, tuned on the MERIt trials.

Both nominal models are examined: the datasheet (no fitting) and the best rigid fit of the nominal structure (by
the recommended fit — the robot's default estimator unless the caller gives one — with joint weights 1/σ_j² from a
least-squares pass, `weights_of`, `nominal_fit`). Every candidate that refits π refits it with the same estimator.
"""

from __future__ import annotations

import numpy as np

from ident_opt.arm.datasheet import PlanarRobot, datasheet_pi, rigid_body
from ident_opt.data.dataset import Dataset
from ident_opt.diagnosis import evidence, scoring
from ident_opt.diagnosis.engine import FamilyFunctions, Nominal, OverFunctions, Parts, Request
from ident_opt.diagnosis.planar import compose as composition
from ident_opt.diagnosis.planar import families as candidates
from ident_opt.diagnosis.result import Fitted
from ident_opt.diagnosis.split import parts, prepare
from ident_opt.errors import InputError
from ident_opt.numerics import least_squares as linear
from ident_opt.numerics import signals

#: The estimators that refit the grouped π of any model the candidates build (extensions and columns included).
REFITS = ("ols", "constrained", "robust")


def weights_of(ds: Dataset) -> np.ndarray:
    """1/σ_j² [1/(N m)²] per joint, σ_j² the residual variance of the nominal structure's least-squares fit, on the
    same objective as every candidate (rest stretches compared about their mean)."""
    rest = signals.rest_runs(ds.dq)
    Y = signals.demean_runs(candidates.NOMINAL.regressor(ds.q, ds.dq, ds.ddq), rest)
    tau = signals.demean_runs(ds.tau, rest)
    first = linear.solve(np.zeros((ds.n, 2)), Y, tau, np.ones(2), with_se=False)
    return 1.0 / np.maximum(first.rss / ds.n, 1e-12 * np.maximum(np.var(ds.tau, axis=0), 1e-30))


def nominal_fit(ctx: candidates.Context) -> np.ndarray:
    """π̂ of the nominal structure by the context's estimator on the training part (`Context.rigid`): what every
    candidate that refits π reduces to without a column of its own."""
    tr, model = ctx.train, candidates.NOMINAL
    at = ctx.instrumented
    Z = model.regressor(at.q, at.dq, at.ddq) if at is not None else None
    return ctx.rigid(model, model.regressor(tr.q, tr.dq, tr.ddq), tr.tau, Z)


class PlanarEngine(OverFunctions):
    """The planar two-link arm's engine (module doc); built on the trials to diagnose."""

    functions = FamilyFunctions(candidates.fit, composition.compose, composition.frozen, composition.theta)

    margin_variance = candidates.MARGIN_VARIANCE
    partner = scoring.PARTNER
    search_again = candidates.SEARCH_AGAIN
    pose = staticmethod(evidence.pose_r2)

    def __init__(self, robot: PlanarRobot, request: Request) -> None:
        trial, unseen, estimator = request.trial, request.unseen, request.estimator
        torque_filter_hz = request.torque_filter_hz
        if estimator not in REFITS:  # e.g. nlp_physical: π from the rigid arm's physical parameters alone
            raise InputError(
                f"diagnose: the rigid fit {estimator!r} cannot carry a cause's parameters beside the grouped π, as "
                f"the planar diagnosis refits them together; use one of {', '.join(REFITS)}"
            )
        self.robot = robot
        self.request = request
        train, test, raw_test, how = parts(trial, unseen, request.train_fraction, torque_filter_hz, robot.joint_names)
        self.filter_hz = train.cutoff_hz if torque_filter_hz == "auto" else torque_filter_hz
        self.parts = Parts(train, test, raw_test, how, trial if unseen is not None else None)
        self.dt = float(np.median(np.diff(train.t)))
        self.datasheet_pi = datasheet_pi(robot, "physical")
        self.kept: list[str] = []  # the datasheet values an identified nominal did not replace
        if request.nominal is not None:
            names = candidates.NOMINAL.names
            pi, self.kept = request.nominal.vector(names, candidates.NOMINAL.vector(self.datasheet_pi))
            self.datasheet_pi = {**self.datasheet_pi, **dict(zip(names, pi.tolist()))}
        self.ctx = candidates.Context(
            robot,
            train,
            test,
            weights_of(train),
            self.datasheet_pi,
            self.dt,
            signals.rest_runs(train.dq),
            rigid_body(robot, "physical").armature,
            estimator,
        )
        model = candidates.NOMINAL
        pi = {"datasheet": model.vector(self.datasheet_pi), "rigid_fit": nominal_fit(self.ctx)}
        pred = {b: model.predict(p, test.q, test.dq, test.ddq) for b, p in pi.items()}
        self.nominal = Nominal(model, pi, pred, len(model.names), signals.rest_runs(test.dq))

    def families(self) -> list:
        return candidates.families(self.ctx)

    def forward_after(self, final: Fitted | None, baseline: str) -> list:
        """Question 4's motion error of the extended model: its rigid part (π refitted or the datasheet's)
        integrated, the rest of its torque teacher-forced along the measured motion (`evidence.forward_error`).
        Without a cause: the baseline's own error."""
        model, test = candidates.NOMINAL, self.parts.test
        if final is None:
            return evidence.forward_error(model, self.nominal.pi[baseline], test, self.dt)
        pi = model.vector({**self.datasheet_pi, **final.cand.parameters})
        rigid = model.predict(pi, test.q, test.dq, test.ddq)
        return evidence.forward_error(model, pi, test, self.dt, extension=final.pred - rigid)

    def other(self, trial: Dataset) -> tuple[Dataset, Dataset, np.ndarray]:
        """Another trial as the held-out part is read (`split.prepare`d): (prepared, its measured torque as logged,
        its rest-stretch labels)."""
        prepared = prepare(trial, self.request.torque_filter_hz)
        return prepared, trial, signals.rest_runs(prepared.dq)

    def nominal_prediction(self, baseline: str, ds: Dataset) -> np.ndarray:
        """The nominal model `baseline`'s torque (N, 2) [N m] along `ds`."""
        return candidates.NOMINAL.predict(self.nominal.pi[baseline], ds.q, ds.dq, ds.ddq)

    def leave_implausible(self, failing) -> None:
        """Nothing: the planar families fit both joints at once; an implausible candidate is rejected whole."""

    @property
    def moving_mass(self) -> float:
        """The links' mass [kg] the datasheet gives (`PlanarRobot.nominal_masses`)."""
        return float(sum(self.robot.nominal_masses))

    #: The planar arm's payload is a point mass at the tip of link 2 (no centre of mass to bound).
    reach = None

    def screening(self) -> dict | None:
        return None
