"""What `ident-opt export` writes, computed: the arm identified on the problem's training trials by the fit the
tool stands behind (its consistent fit, or `--estimator`), realised exactly as rigid bodies
(`ident_opt.arm.realise`), with what the data did not determine named. `ident_opt.shipping` writes it."""

from __future__ import annotations

from dataclasses import dataclass

from ident_opt.arm.base import Arm
from ident_opt.arm.bodies import RobotDescription
from ident_opt.data.dataset import Dataset
from ident_opt.errors import InputError
from ident_opt.fitting import estimators
from ident_opt.fitting.fit import LinearFit


@dataclass
class Exported:
    """The identified arm: its model, the fit (π with standard errors), the estimator's name, the rigid bodies
    that realise π, and the training trials' files."""

    model: Arm
    fit: LinearFit
    estimator: str
    description: RobotDescription
    trials: list[str]


def identified_arm(robot, trials: list[Dataset], estimator: str) -> Exported:
    """The robot's model fitted by `estimator` on all `trials` (statistics add up; the torque filtered like the
    regressor's inputs), realised as rigid bodies; an InputError when the fit fails or no physical robot has its
    parameters (an OLS fit can have a negative mass: the message names the link)."""
    model = robot.model()
    try:
        stats = estimators.statistics(model, trials, estimator, probes=True)
        fit = estimators.fit_for(robot, estimator, stats, model)
    except RuntimeError as exc:  # the solver failed: nothing to export
        raise InputError(f"export: the {estimator} fit failed ({exc}); try another --estimator") from None
    undetermined = fit.details.get("not_determined", [])
    description = robot.bodies(model, fit.pi, undetermined=undetermined)
    return Exported(model, fit, estimator, description, [t.source for t in trials])
