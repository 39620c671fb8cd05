"""The paper's three torque models and ours, each alone or with a GMR residual, behind one interface.

Every model has `fit(train: Dataset) -> self` and `predict(data: Dataset) -> τ̂ (N, 2)` [N m]; hybrids
(`+gmr`) also have `predict_interval(data) -> (τ̂, σ)` with σ (N, 2) the predictive standard deviation of
each joint [N m] (from the GMR's mixture covariance).

| key           | model                                                                                  |
|---------------|----------------------------------------------------------------------------------------|
| `rr`          | ridge regression on [q, dq, ddq] with an intercept (the paper's Model 1, black box)    |
| `dm`          | datasheet rigid-body model, the paper's convention and printed G (its Model 2)         |
| `dm_physical` | datasheet rigid-body model read physically (joint-2 armature, reflected friction)      |
| `pbr`         | OLS-identified rigid-body model (the paper's Model 3, gray box)                        |
| `cpbr`        | physically consistent constrained fit (M(q) ≻ 0 for all q, friction ≥ 0)               |
| `<key>+gmr`   | the same plus a GMR on x = [q, dq, ddq] → r = τ − τ̂ (both joints in one mixture)       |
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from sklearn.linear_model import RidgeCV

from ident_opt.arm.datasheet import PlanarRobot, datasheet_pi
from ident_opt.arm.planar import PAPER, PHYSICAL, RIGID, PlanarArm
from ident_opt.data import Dataset
from ident_opt.gmr import GMR
from ident_opt.identify import estimators
from ident_opt.identify.stats import Stats
from ident_opt.problem.spec import ResidualSpec

#: Ridge penalties searched by (efficient leave-one-out) cross-validation.
RIDGE_ALPHAS = tuple(np.logspace(-4, 4, 17))
#: The identified rigid-body models: key -> estimator (`ident_opt.identify.estimators`).
FITTED = {"pbr": "ols", "cpbr": "constrained"}
#: The datasheet models: convention -> (key, the arm it is evaluated with). The paper's is evaluated with
#: its printed gravity vector, as its Model 2 was (that is what reproduces its DM row); the physical
#: reading carries the joint-2 armature.
DATASHEETS = {"paper": ("dm", PAPER), "physical": ("dm_physical", PHYSICAL)}


class TorqueModel(Protocol):
    """What every model offers."""

    key: str

    def fit(self, train: Dataset) -> TorqueModel: ...

    def predict(self, data: Dataset) -> np.ndarray: ...


def features(data: Dataset) -> np.ndarray:
    """The kinematic input x = [q1 q2 dq1 dq2 ddq1 ddq2] (N, 6) [rad, rad/s, rad/s²] of a trial (anything
    with q, dq, ddq (N, 2)): the input of the ridge model and of every GMR residual."""
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
        """τ̂ (N, 2) [N m]."""
        return self._reg.predict(features(data))


@dataclass
class RigidModel:
    """A rigid-body model τ̂ = Y(q, dq, ddq) π with π fixed (datasheet) or identified (`estimator`).

    estimator: None (no fitting: `pi` is given) or a name of `ident_opt.identify.estimators` (``"ols"``:
    Model 3, ``"constrained"``: physically consistent). After fit: `pi` (vector in `arm.names` order) and
    `fit_` (the estimator's `LinearFit`, if any).
    """

    key: str
    arm: PlanarArm = RIGID
    pi: np.ndarray | None = None
    estimator: str | None = None
    fit_: object = field(init=False, default=None)

    def fit(self, train: Dataset) -> RigidModel:
        """Identify π on the training trial (a no-op for a datasheet model)."""
        if self.estimator is None:
            return self
        stats = Stats.from_data(self.arm, train.q, train.dq, train.ddq, train.tau)
        self.fit_ = estimators.fit(self.estimator, stats, self.arm)
        self.pi = np.asarray(self.fit_.pi, dtype=float)
        return self

    def predict(self, data: Dataset) -> np.ndarray:
        """τ̂ (N, 2) [N m]."""
        return self.arm.predict(self.pi, data.q, data.dq, data.ddq)

    def params(self) -> dict[str, float]:
        """π by name."""
        return self.arm.as_dict(self.pi)


def datasheet_model(robot: PlanarRobot, convention: str) -> RigidModel:
    """The datasheet model: the paper's (its printed G, key `dm`) or the physical reading (`dm_physical`)."""
    key, arm = DATASHEETS[convention]
    return RigidModel(key, arm, arm.vector(datasheet_pi(robot, convention)))


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
        """τ̂ (N, 2) [N m]."""
        return self.base.predict(data) + self.gmr.predict_mean(features(data))

    def predict_interval(self, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
        """τ̂ and the predictive standard deviation per joint, both (N, 2) [N m]."""
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


def parametric_models(robot: PlanarRobot, constrained: bool = True) -> list:
    """Fresh, unfitted parametric models in report order: rr, dm, dm_physical, pbr (, cpbr)."""
    fitted = {key: name for key, name in FITTED.items() if constrained or name != "constrained"}
    return [
        RidgeModel(),
        *(datasheet_model(robot, convention) for convention in DATASHEETS),
        *(RigidModel(key, RIGID, estimator=name) for key, name in fitted.items()),
    ]
