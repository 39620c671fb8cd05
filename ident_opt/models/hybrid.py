"""The paper's three torque models and ours, each alone or with a GMR residual, behind one interface.

Every model has `fit(train: Dataset) -> self` and `predict(data: Dataset) -> τ̂ (N, n)` [N m]; hybrids
(`+gmr`) also have `predict_interval(data) -> (τ̂, σ)` with σ (N, n) the predictive standard deviation of
each joint [N m] (from the GMR's mixture covariance). n is the arm's number of joints.

| key           | model                                                                                  |
|---------------|----------------------------------------------------------------------------------------|
| `rr`          | ridge regression on [q, dq, ddq] with an intercept (the paper's Model 1, black box)    |
| `dm`          | the arm's nominal model (`Robot.datasheets`, its first): the planar arm's datasheet in |
|               | the paper's convention with its printed G (its Model 2); an n-joint arm's URDF         |
| `dm_<name>`   | the arm's other nominal models: `dm_physical`, the planar datasheet read physically    |
| `pbr`         | OLS-identified rigid-body model (the paper's Model 3, gray box)                        |
| `cpbr`        | the arm's physically consistent fit (`Robot.default_estimator`: the planar arm's       |
|               | constrained fit, M(q) ≻ 0 for all q; an n-joint arm's plausible consistent fit)        |
| `<key>+gmr`   | the same plus a GMR on x = [q, dq, ddq] → r = τ − τ̂ (every joint in one mixture)       |
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from sklearn.linear_model import RidgeCV

from ident_opt.arm.base import Arm
from ident_opt.arm.planar import RIGID
from ident_opt.data.dataset import Dataset
from ident_opt.fitting import estimators
from ident_opt.models.gmr import GMR
from ident_opt.problem.spec import ResidualSpec

#: Ridge penalties searched by (efficient leave-one-out) cross-validation.
RIDGE_ALPHAS = tuple(np.logspace(-4, 4, 17))


def fitted(robot, recommended: str | None = None) -> dict[str, str]:
    """The identified rigid-body models: key -> estimator (`ident_opt.fitting.estimators`): pbr by OLS, cpbr by
    the recommended fit (`fitting.recommend`; None: the arm's physically consistent fit, `Robot.default_estimator`)."""
    return {"pbr": "ols", "cpbr": recommended or robot.default_estimator}


def datasheet_keys(robot) -> dict[str, str]:
    """Model key -> the name of the robot's nominal model (`Robot.datasheets`): its first is "dm" (the planar arm's
    paper-convention datasheet, the paper's Model 2), the others "dm_<name>" (the planar arm's "dm_physical")."""
    names = list(robot.datasheets())
    return {("dm" if i == 0 else f"dm_{name}"): name for i, name in enumerate(names)}


class TorqueModel(Protocol):
    """What every model offers."""

    key: str

    def fit(self, train: Dataset) -> TorqueModel: ...

    def predict(self, data: Dataset) -> np.ndarray: ...


def features(data: Dataset) -> np.ndarray:
    """The kinematic input x = [q1 … qn, dq1 … dqn, ddq1 … ddqn] (N, 3n) [rad, rad/s, rad/s²] of a trial (anything
    with q, dq, ddq (N, n)): the input of the ridge model and of every GMR residual."""
    return np.hstack([data.q, data.dq, data.ddq])


# ---------------------------------------------------------------------------------------------- parametric
@dataclass
class RidgeModel:
    """Model 1: τ̂ = Φ(q, dq, ddq) w + c, ridge penalty per joint chosen by leave-one-out CV."""

    key: str = "rr"
    alphas: tuple[float, ...] = RIDGE_ALPHAS
    alpha_: np.ndarray = field(init=False, default=None)
    coef_: np.ndarray = field(init=False, default=None)
    intercept_: np.ndarray = field(init=False, default=None)

    def fit(self, train: Dataset) -> RidgeModel:
        """Fit w, c and the penalty on the training trial."""
        reg = RidgeCV(alphas=self.alphas, alpha_per_target=True).fit(features(train), train.tau)
        self._reg = reg
        self.alpha_, self.coef_, self.intercept_ = np.atleast_1d(reg.alpha_), reg.coef_, reg.intercept_
        return self

    def predict(self, data: Dataset) -> np.ndarray:
        """τ̂ (N, n) [N m]."""
        return self._reg.predict(features(data))


@dataclass
class RigidModel:
    """A rigid-body model τ̂ = Y(q, dq, ddq) π with π fixed (datasheet) or identified (`estimator`).

    estimator: None (no fitting: `pi` is given) or a name of `ident_opt.fitting.estimators` (``"ols"``:
    Model 3, ``"constrained"``: physically consistent). After fit: `pi` (vector in `arm.names` order) and
    `fit_` (the estimator's `LinearFit`, if any).
    """

    key: str
    arm: Arm = RIGID
    pi: np.ndarray | None = None
    estimator: str | None = None
    options: dict = field(default_factory=dict)  # what the estimator takes from the arm's description
    fit_: object = field(init=False, default=None)

    def fit(self, train: Dataset) -> RigidModel:
        """Identify π on the training trial (a no-op for a datasheet model)."""
        if self.estimator is None:
            return self
        stats = estimators.statistics(self.arm, [train], self.estimator)
        self.fit_ = estimators.fit(self.estimator, stats, self.arm, **self.options)
        self.pi = np.asarray(self.fit_.pi, dtype=float)
        return self

    def predict(self, data: Dataset) -> np.ndarray:
        """τ̂ (N, n) [N m]."""
        return self.arm.predict(self.pi, data.q, data.dq, data.ddq)

    def params(self) -> dict[str, float]:
        """π by name."""
        return self.arm.as_dict(self.pi)


def datasheet_model(robot, name: str) -> RigidModel:
    """The robot's nominal model `name` (`Robot.datasheets`: "paper", "physical", "urdf"), keyed as in
    `datasheet_keys`, with its arm and π."""
    arm, pi = robot.datasheets()[name]
    key = next(k for k, n in datasheet_keys(robot).items() if n == name)
    return RigidModel(key, arm, pi)


# ---------------------------------------------------------------------------------------------- hybrid
@dataclass
class HybridModel:
    """A parametric model plus a GMR of its residual: τ̂ = τ̂_par(x) + E[r | x].

    `gmr` carries the settings (components or candidates, covariance, reg_covar, max_train_samples); its
    fitted state holds the chosen number of components.
    """

    base: TorqueModel
    gmr: GMR

    @property
    def key(self) -> str:
        return f"{self.base.key}+gmr"

    def fit(self, train: Dataset, fit_base: bool = True) -> HybridModel:
        """Fit the parametric part (unless already fitted, `fit_base=False`), then the GMR on its residual."""
        if fit_base:
            self.base.fit(train)
        residual = train.tau - self.base.predict(train)
        self.gmr.fit(features(train), residual)
        return self

    def predict(self, data: Dataset) -> np.ndarray:
        """τ̂ (N, n) [N m]."""
        return self.base.predict(data) + self.gmr.predict_mean(features(data))

    def predict_interval(self, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
        """τ̂ and the predictive standard deviation per joint, both (N, n) [N m]."""
        mean, std = self.gmr.predict_std(features(data))
        return self.base.predict(data) + mean, std


def make_gmr(
    spec: ResidualSpec,
    components: int | None = None,
    covariance: str | None = None,
    random_state: int = 0,
    validation: str = "random",
) -> GMR:
    """A GMR with the problem's `[residual]` settings (components: a fixed K overrides the spec's;
    validation: how the components are chosen, see `GMR`)."""
    return GMR(
        n_components=components if components is not None else spec.components,
        candidates=spec.candidates,
        covariance=covariance or spec.covariance,
        reg_covar=spec.reg_covar,
        max_train_samples=spec.max_train_samples,
        random_state=random_state,
        validation=validation,
    )


def parametric_models(robot, constrained: bool = True, recommended: str | None = None) -> list:
    """Fresh, unfitted parametric models in report order: rr, the nominal models (dm, dm_…), pbr (, cpbr: the
    `recommended` fit), the fitted ones on the arm's rigid model (`Robot.model(())`) with the options its
    description gives them."""
    arm = robot.model(())
    models = {key: name for key, name in fitted(robot, recommended).items() if constrained or key != "cpbr"}
    return [
        RidgeModel(),
        *(datasheet_model(robot, name) for name in datasheet_keys(robot).values()),
        *(
            RigidModel(key, arm, estimator=name, options=estimators.options_for(robot, name))
            for key, name in models.items()
        ),
    ]
