"""The one registry of linear estimators: a name → a fit from sufficient statistics.

| name          | fit from the statistics                                          | online, warm-started |
|---------------|------------------------------------------------------------------|----------------------|
| `ols`         | `identify.fit.fit_ols`: (weighted) least squares with SEs        | box-bounded LS       |
| `constrained` | `identify.constrained.fit_constrained`: M(q) ⪰ margin·I ∀q, friction and armature ≥ 0 | the same |

Every place that lets a user or a model choose between them (`models.RigidModel`, `ident-opt codegen
--estimator`, the online models' offline start, `ident-opt compare`) goes through `fit` and `ONLINE`, so a
new estimator is one entry here.
"""

from __future__ import annotations

from collections.abc import Callable

from ident_opt.arm.planar import PlanarArm
from ident_opt.identify.constrained import fit_constrained
from ident_opt.identify.fit import LinearFit, fit_ols
from ident_opt.identify.stats import Stats

#: (statistics, arm, **options) -> LinearFit. Options: `weights` for both, `margin`, `bounds`… for `constrained`.
FitFn = Callable[..., LinearFit]

ESTIMATORS: dict[str, FitFn] = {"ols": fit_ols, "constrained": fit_constrained}

#: The `ident_opt.online.Estimator` kind that follows each estimator sample by sample.
ONLINE = {"ols": "bounded", "constrained": "consistent"}


def fit(name: str, stats: Stats, arm: PlanarArm, **options) -> LinearFit:
    """π̂ of estimator `name` from the statistics of `arm`'s regressor; `options` go to the estimator."""
    return estimator(name)(stats, arm, **options)


def estimator(name: str) -> FitFn:
    """The fit function of `name`; a ValueError naming the known estimators otherwise."""
    try:
        return ESTIMATORS[name]
    except KeyError:
        raise ValueError(f"unknown estimator {name!r}; known: {', '.join(ESTIMATORS)}") from None
