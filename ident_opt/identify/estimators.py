"""The one registry of estimators: a name → a fit from sufficient statistics, for any arm.

| name           | fit from the statistics                                                            | online     |
|----------------|------------------------------------------------------------------------------------|------------|
| `ols`          | `identify.base.fit_least_squares`: (weighted) least squares with SEs, on the base   | bounded    |
|                | parameters when the regressor does not determine every parameter                   |            |
| `constrained`  | `identify.constrained.fit_constrained`: the arm's mass LMIs ⪰ margin·I, friction    | consistent |
|                | and armature ≥ 0                                                                    |            |
| `nlp_physical` | `identify.nlp.fit_physical`: physical parameters of the planar arm by IPOPT, a weak | —          |
|                | pull toward its datasheet                                                          |            |
| `consistent`   | `identify.physical.fit_physical`: consistent and plausible, a log-det prior toward  | —          |
|                | the URDF's inertials, masses and centres of mass bounded around them                |            |

Which of them an arm offers, and the options each takes from its description (a datasheet, a prior), the arm says
(`Robot.estimators`, `Robot.fit_options`). Every place that lets a user or a model choose between them
(`models.RigidModel`, `ident-opt codegen --estimator`, the online models' offline start, `ident-opt compare`) goes
through `fit`, so a new estimator is one entry here.
"""

from __future__ import annotations

from collections.abc import Callable

from ident_opt.arm.base import Arm, Robot
from ident_opt.identify import nlp, physical
from ident_opt.identify.base import fit_least_squares
from ident_opt.identify.constrained import fit_constrained
from ident_opt.identify.fit import LinearFit
from ident_opt.identify.stats import Stats

#: (statistics, arm, **options) -> LinearFit. Options: `weights` for all, `margin`, `bounds`… for `constrained`,
#: the robot's `fit_options` for the others.
FitFn = Callable[..., LinearFit]


def _nlp_physical(stats: Stats, arm: Arm, *, robot, **options) -> LinearFit:
    """`identify.nlp.fit_physical` in the registry's signature."""
    return nlp.fit_physical(stats, robot, arm, **options)


ESTIMATORS: dict[str, FitFn] = {
    "ols": fit_least_squares,
    "constrained": fit_constrained,
    "nlp_physical": _nlp_physical,
    "consistent": physical.fit_physical,
}

#: What each estimator is, in a line (reports).
MEANING = {
    "ols": "least squares (on the base parameters where the data cannot tell the parameters apart)",
    "constrained": "physically consistent least squares: the mass LMIs ⪰ margin·I, friction and armature ≥ 0",
    "nlp_physical": "physical parameters (masses, lengths, inertias) by IPOPT, a weak pull toward the datasheet",
    "consistent": "consistent and plausible: a log-det prior toward the URDF's inertials, masses within a range",
}

#: The `ident_opt.online.Estimator` kind that follows each estimator sample by sample.
ONLINE = {"ols": "bounded", "constrained": "consistent"}


def fit(name: str, stats: Stats, arm: Arm, **options) -> LinearFit:
    """π̂ of estimator `name` from the statistics of `arm`'s regressor; `options` go to the estimator."""
    return estimator(name)(stats, arm, **options)


def estimator(name: str) -> FitFn:
    """The fit function of `name`; a ValueError naming the known estimators otherwise."""
    try:
        return ESTIMATORS[name]
    except KeyError:
        raise ValueError(f"unknown estimator {name!r}; known: {', '.join(ESTIMATORS)}") from None


def fit_for(robot: Robot, name: str, stats: Stats, arm: Arm, **options) -> LinearFit:
    """Estimator `name` with the options the robot's description gives it (`Robot.fit_options`) and `options`."""
    return fit(name, stats, arm, **robot.fit_options(name), **options)
