"""The one registry of estimators: a name → a fit from sufficient statistics, for any arm.

| name           | fit from the statistics                                                            | online     |
|----------------|------------------------------------------------------------------------------------|------------|
| `ols`          | `fitting.base.fit_least_squares`: (weighted) least squares with SEs, on the base   | bounded    |
|                | parameters when the regressor does not determine every parameter                   |            |
| `constrained`  | `fitting.constrained.fit_constrained`: the arm's mass LMIs ⪰ margin·I, friction    | consistent |
|                | and armature ≥ 0                                                                    |            |
| `nlp_physical` | `fitting.nlp.fit_physical`: physical parameters of the planar arm by IPOPT, a weak | —          |
|                | pull toward its datasheet                                                          |            |
| `consistent`   | `fitting.physical.fit_physical`: consistent and plausible, a log-det prior toward  | —          |
|                | the URDF's inertials, masses and centres of mass bounded around them                |            |
| `robust`       | the arm's consistent fit (`Robot.default_estimator`) on the instruments' two-stage  | —          |
|                | statistics (`fitting.iv`): consistent, and without the errors-in-variables bias;   |            |
|                | with probes in its statistics, standard errors that cover the bias it keeps         |            |

Which of them an arm offers, and the options each takes from its description (a datasheet, a prior), the arm says
(`Robot.estimators`, `Robot.fit_options`). Estimators in `INSTRUMENTED` take `fitting.iv.InstrumentStats`
(`statistics` builds the right kind from trials); every other takes `Stats`, or the `stats` inside instrument
statistics. Every place that lets a user or a model choose between them
(`models.RigidModel`, `ident-opt codegen --estimator`, the online models' offline start, `ident-opt compare`) goes
through `fit`, so a new estimator is one entry here.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from ident_opt.arm.base import Arm, Robot
from ident_opt.data.dataset import Dataset
from ident_opt.fitting import nlp, physical
from ident_opt.fitting.base import base_parameters, fit_least_squares, lifted_fit
from ident_opt.fitting.constrained import fit_constrained
from ident_opt.fitting.fit import LinearFit
from ident_opt.fitting.iv import InstrumentStats, fit_iv, probe_trials
from ident_opt.fitting.stats import Stats

#: (statistics, arm, **options) -> LinearFit. Options: `weights` for all, `margin`, `bounds`… for `constrained`,
#: the robot's `fit_options` for the others.
FitFn = Callable[..., LinearFit]


def _nlp_physical(stats: Stats, arm: Arm, *, robot, **options) -> LinearFit:
    """`fitting.nlp.fit_physical` in the registry's signature."""
    return nlp.fit_physical(stats, robot, arm, **options)


def _robust(stats: InstrumentStats, arm: Arm, *, consistent: str, **options) -> LinearFit:
    """The consistent estimator `consistent` on the two-stage statistics of the instruments (`fitting.iv`).

    With the statistics' bias probes (`iv.probe_trials`: the instruments, and the whole derivative cut-off, at half
    theirs), its standard errors cover its bias: se = √(se_IV² + Σ_k b_k²), b_k per parameter how far the estimate
    moves from the trials as read to probe k. An unbiased fit would move by noise alone; the two sources of bias an
    IV fit keeps move it more, each under its own probe: what is left of the noise's correlation between
    instruments and regressor (the instruments' cut-off), and the filter's distortion of the dynamics (the
    derivatives' cut-off); taken as independent, they add in quadrature. `details` keeps `se_noise` (the 2SLS
    errors alone) and `bias_bound` (√Σ b_k²)."""
    result = replace(fit(consistent, stats.two_stage(), arm, **options), method="robust")
    if not stats.probes:
        return result
    moved = [np.abs(fit(consistent, p.two_stage(), arm, **options).pi - result.pi) for p in stats.probes.values()]
    bias = np.sqrt(np.sum(np.square(moved), axis=0))
    details = {**result.details, "se_noise": result.se, "bias_bound": bias}
    return replace(result, se=np.sqrt(result.se**2 + bias**2), details=details)


ESTIMATORS: dict[str, FitFn] = {
    "ols": fit_least_squares,
    "constrained": fit_constrained,
    "nlp_physical": _nlp_physical,
    "consistent": physical.fit_physical,
    "robust": _robust,
}
#: The estimators that take instrument statistics (`fitting.iv.InstrumentStats`).
INSTRUMENTED = frozenset({"robust"})

#: What each estimator is, in a line (reports).
MEANING = {
    "ols": "least squares (on the base parameters where the data cannot tell the parameters apart)",
    "constrained": "physically consistent least squares: the mass LMIs ⪰ margin·I, friction and armature ≥ 0",
    "nlp_physical": "physical parameters (masses, lengths, inertias) by IPOPT, a weak pull toward the datasheet",
    "consistent": "consistent and plausible: a log-det prior toward the URDF's inertials, masses within a range",
    "robust": "the consistent fit on instrumental variables: no errors-in-variables bias from noisy accelerations",
}

#: The `ident_opt.adaptation.identifier.Estimator` kind that follows each estimator sample by sample.
ONLINE = {"ols": "bounded", "constrained": "consistent"}


def fit(name: str, stats: Stats | InstrumentStats, arm: Arm, **options) -> LinearFit:
    """π̂ of estimator `name` from the statistics of `arm`'s regressor; `options` go to the estimator. An estimator
    in `INSTRUMENTED` needs `InstrumentStats`; the others take `Stats` (or use those inside `InstrumentStats`)."""
    fn = estimator(name)
    if name in INSTRUMENTED:
        if not isinstance(stats, InstrumentStats):
            raise ValueError(f"estimator {name!r} needs instrument statistics (estimators.statistics)")
        return fn(stats, arm, **options)
    return fn(stats.stats if isinstance(stats, InstrumentStats) else stats, arm, **options)


def estimator(name: str) -> FitFn:
    """The fit function of `name`; a ValueError naming the known estimators otherwise."""
    try:
        return ESTIMATORS[name]
    except KeyError:
        raise ValueError(f"unknown estimator {name!r}; known: {', '.join(ESTIMATORS)}") from None


def options_for(robot: Robot, name: str) -> dict:
    """The options estimator `name` takes from the robot's description (`Robot.fit_options`); the robust fit is the
    arm's consistent fit (`Robot.default_estimator`) with its options."""
    if name == "robust":
        return {"consistent": robot.default_estimator, **robot.fit_options(robot.default_estimator)}
    return robot.fit_options(name)


def fit_for(robot: Robot, name: str, stats: Stats | InstrumentStats, arm: Arm, **options) -> LinearFit:
    """Estimator `name` with the options the robot's description gives it (`options_for`) and `options`."""
    return fit(name, stats, arm, **options_for(robot, name), **options)


def statistics(
    arm: Arm, trials: Sequence[Dataset], name: str | None = None, probes: bool = False
) -> Stats | InstrumentStats:
    """The statistics of `arm` over `trials` (they add up; each trial's derivatives its own; τ as fits use it,
    `Dataset.tau_fit`): `InstrumentStats` when estimator `name` takes them (or when `name` is None), else `Stats`.
    `probes`: with the instrument statistics, those of each trial read the ways of `iv.probe_trials`, which the
    robust fit's standard errors use to cover its bias (whole trials only: a shuffled subset has no derivatives to
    estimate again)."""
    if name is not None and name not in INSTRUMENTED:
        total = Stats.zeros(arm.n_params, arm.n_joints)
        for d in trials:
            total += _independent(Stats.from_data(arm, d.q, d.dq, d.ddq, d.tau_fit), d)
        return total
    total = InstrumentStats.zeros(arm.n_params, arm.n_joints)
    for d in trials:
        one = InstrumentStats.from_data(arm, d)
        read = {k: InstrumentStats.from_data(arm, p) for k, p in probe_trials(d).items()} if probes else {}
        total = total + replace(one, stats=_independent(one.stats, d), probes=read)
    return total


def _independent(stats: Stats, d: Dataset) -> Stats:
    """`stats` of trial `d` with how many of its residuals are independent (`Stats.effective`): n · 2 f_c / f_s
    when its torque was low-passed at f_c with the derivatives."""
    if d.tau_filtered is None or d.cutoff_hz is None or d.n < 2:
        return stats
    return replace(stats, effective=d.n * min(1.0, 2 * d.cutoff_hz / d.rate_hz))


def iv(stats: InstrumentStats, arm: Arm) -> LinearFit:
    """IDIM-IV (`fitting.iv.fit_iv`), on the base parameters when the regressor does not determine every
    parameter (`fitting.base.lifted_fit`)."""
    base = base_parameters(arm)
    if base.rank == arm.n_params:
        return fit_iv(stats, arm)
    return lifted_fit(arm, lambda view: fit_iv(base.instruments(stats), view))
