"""Which fit the tool stands behind: the recommended fit, chosen from the run's own evidence.

Every command that uses an identified model (`identify`'s models, `codegen`, the `online` start, `diagnose`'s
rigid fit, `export`) takes the recommended fit unless told otherwise, and `compare` and `identify` report it with
its reason (`recommended`, `recommended_why`). The evidence is the instrumental-variable fit (`fitting.iv`), which
noise in the estimated accelerations does not bias, beside least squares, which it does:

- **OLS and IV agree** (within `AGREE_TOLERANCE`) at the cut-offs the spectra gave (`derivatives.cutoff_choice`):
  the noise does not bias least squares there. The cut-off is then raised in steps (`FACTORS_UP` × each trial's)
  for as long as the two still agree: a low-pass filter distorts the dynamics it passes (τ = Y(q, q̇, q̈)·π is
  not linear in the signals), less the higher its cut-off, and the instruments say how high the noise allows. The
  recommendation is the arm's physically consistent fit (`Robot.default_estimator`) at the highest cut-off where
  they agreed.
- **They disagree** (or the trust checks of `fitting.trust` show the parameters moving with the cut-off): the
  robust fit (`estimators` "robust": the same consistent fit on instrumental variables) at the spectra's cut-offs.
  Its standard errors are the instrumental-variable ones, wider than least squares', and include what noise in the
  regressor does to the estimate.
- **Derivatives logged** (not estimated here): nothing to judge; the consistent fit.

When even the instruments cannot settle the parameters (their standard errors many times least squares', and the
parameters moving at half the cut-off too), a warning says so and what to record instead (`undecided`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from numbers import Real

import numpy as np

from ident_opt.arguments import range_of
from ident_opt.arm.base import Arm, Robot
from ident_opt.data.dataset import Dataset, refiltered
from ident_opt.data.validate import checked_array
from ident_opt.errors import InputError, excerpt
from ident_opt.fitting import estimators
from ident_opt.fitting.fit import LinearFit
from ident_opt.fitting.trust import JUDGED_KINDS, SENSITIVITY_TOLERANCE, Trust, checks
from ident_opt.numerics.derivatives import CUTOFF_MAX_FRACTION
from ident_opt.problem.spec import Problem
from ident_opt.warnings import ResultWarning

#: The trust checks whose warnings show the least-squares fits biased by noise in the regressor.
BIASED = ("ols_iv_disagree", "cutoff_sensitivity")
#: The instruments are weak when the judged parameters' IV standard errors are (median) this many times OLS's.
WEAK_INSTRUMENTS = 10.0
#: The cut-off factors tried above the spectra's choice, in order, while OLS and IV agree.
FACTORS_UP = (1.5, 2.0, 3.0, 4.0)
#: OLS and IV agree when no judged parameter the data determine differs by more than this fraction of its IV value.
#: Noise in the regressor shows as least squares drifting from IV as the cut-off rises; measured in the cut-off
#: study (`evaluation.cutoff_study`), the drift that matters starts at a few 0.1 %, below every standard error (which
#: count samples that a low-passed trial does not have independent of each other).
AGREE_TOLERANCE = 0.002


def agree(model: Arm, ols: LinearFit, iv: LinearFit) -> bool:
    """Whether OLS and IV agree on every judged parameter the data determine (`AGREE_TOLERANCE`)."""
    for i, p in enumerate(model.parameters):
        if p.kind not in JUDGED_KINDS or not (np.isfinite(ols.se[i]) and np.isfinite(iv.se[i])):
            continue
        if abs(ols.pi[i] - iv.pi[i]) > AGREE_TOLERANCE * abs(iv.pi[i]):
            return False
    return True


@dataclass
class Evidence:
    """What a choice rests on: OLS and IV on the training trials at the spectra's cut-offs, the trust checks (with
    `undecided`), and the training trials at the chosen cut-off (`trials`; `given`: the trials as they came)."""

    ols: LinearFit
    iv: LinearFit
    trust: Trust
    trials: list[Dataset]
    given: list[Dataset] = field(default_factory=list, repr=False)


@dataclass(frozen=True)
class Choice:
    """The fit a run stands behind, decided once (`choose`) and passed on whole: the estimator (a name of
    `ident_opt.fitting.estimators`), why (a sentence for the terminal, the reports and the JSON), the factor applied
    to each training trial's derivative cut-off (1: the trials' own), and the evidence behind it (None when the
    estimator was asked for). Every downstream use (models, `codegen`, `export`, the `online` start, `diagnose`'s
    rigid fit) takes this object: nothing re-reads the problem's setting or re-decides."""

    estimator: str
    why: str
    factor: float = 1.0
    evidence: Evidence | None = field(default=None, repr=False, compare=False)

    @property
    def warnings(self) -> list[ResultWarning]:
        """What is doubtful about the evidence (the trust checks' warnings; none when the estimator was asked)."""
        return list(self.evidence.trust.warnings) if self.evidence is not None else []

    def at_cutoff(self, trials: Sequence[Dataset]) -> list[Dataset]:
        """`trials` with their derivatives at the chosen cut-off (the evidence's own copies when it made them)."""
        trials = list(trials)
        ev = self.evidence
        if ev is not None and len(ev.given) == len(trials) and all(a is b for a, b in zip(ev.given, trials)):
            return list(ev.trials)
        return trials if self.factor == 1 else raised(trials, self.factor)

    def fit(self, robot: Robot, model: Arm, trials: Sequence[Dataset], **options) -> ArmFit:
        """The chosen fit of `model` on all `trials` (statistics add up) at the chosen cut-off: the one place every
        command's fit is made, so `compare`'s recommended π is the one `export` and `codegen` write. `options` go
        to the estimator (e.g. `weights="wls"`)."""
        stats = estimators.statistics(model, self.at_cutoff(trials), probes=True)
        fitted = estimators.fit_for(robot, self.estimator, stats, model, **options)
        linear = {f.name: getattr(fitted, f.name) for f in fields(LinearFit)}
        return ArmFit(**linear, model=model, choice=self, trials=tuple(d.source for d in trials))


@dataclass
class ArmFit(LinearFit):
    """A fit that knows its arm: the `LinearFit` (π, standard errors, active constraints, …), the model π belongs
    to, the choice it was made by and the trials it was made on (their files). `predict(trial)` is τ̂ [N m]."""

    model: Arm | None = None
    choice: Choice | None = None
    trials: tuple[str, ...] = ()

    def predict(self, trial: Dataset) -> np.ndarray:
        """τ̂ (N, n) [N m] of the fitted model along `trial`'s q, dq, ddq: each (N, n) with n the model's joints and
        every value finite, else an InputError naming it (never a prediction from some of q's columns)."""
        if self.model is None:
            raise InputError("predict: this fit knows no model (ident_opt.fit makes fits that do)")
        if not isinstance(trial, Dataset):
            raise InputError(
                f"predict: trial must be a trial (ident_opt.Dataset: ident_opt.trial or ident_opt.load_trials make "
                f"one), got {type(trial).__name__} {excerpt(trial)}"
            )
        n = self.model.n_joints
        why = f" (one row per sample, one column per joint of the fit's {n}-joint model)"
        q = checked_array("predict: trial.q", trial.q, (None, n), why)
        dq, ddq = (checked_array(f"predict: trial.{k}", getattr(trial, k), (len(q), n), why) for k in ("dq", "ddq"))
        return self.model.predict(self.pi, q, dq, ddq)

    def summary(self) -> dict:
        """`LinearFit.summary` (the model, the choice and the trials are not part of it)."""
        linear = LinearFit(**{f.name: getattr(self, f.name) for f in fields(LinearFit)})
        return linear.summary()


def _recommend(robot: Robot, trust: Trust, agreed: bool = True, factor: float = 1.0) -> Choice:
    """The recommended estimator from the trust checks' warnings and whether OLS and IV agree at the spectra's
    cut-offs (`agreed`); `factor`: the highest cut-off factor where they still agreed (module doc)."""
    consistent = robot.default_estimator
    if not trust.cutoffs:
        return Choice(
            consistent,
            "the derivatives were logged, not estimated here: no cut-off to judge, so the physically consistent fit "
            f"({consistent})",
        )
    evidence = [w.code for w in trust.warnings if w.code in BIASED]
    if (evidence or not agreed) and "robust" in robot.estimators:
        shown = {"ols_iv_disagree": "OLS and IV disagree", "cutoff_sensitivity": "the parameters move with the cut-off"}
        said = " and ".join(shown[c] for c in evidence) or "OLS and IV differ beyond their standard errors"
        return Choice(
            "robust",
            f"{said}: noise in the estimated accelerations biases least squares, so the consistent fit on "
            "instrumental variables (robust), which that noise does not bias",
        )
    where = (
        f"at {factor:g}× each trial's derivative cut-off, the highest where OLS and IV still agree (a higher cut-off "
        "distorts the dynamics less)"
        if factor > 1
        else "at the derivative cut-offs the spectra gave (OLS and IV part above them)"
    )
    return Choice(consistent, f"OLS and IV agree: the physically consistent fit ({consistent}) {where}", factor)


def undecided(model: Arm, trust: Trust, ols: LinearFit, iv: LinearFit) -> list[ResultWarning]:
    """A warning when neither the cut-off nor the instruments settle the judged parameters (module doc)."""
    judged = [i for i, p in enumerate(model.parameters) if p.kind in JUDGED_KINDS]
    ratio = np.asarray(iv.se)[judged] / np.maximum(np.asarray(ols.se)[judged], 1e-300)
    ratio = ratio[np.isfinite(ratio)]
    half = trust.sensitivity.get(0.5)
    moved_half = half is not None and any(
        abs(half.pi[i] - ols.pi[i]) > SENSITIVITY_TOLERANCE * abs(ols.pi[i]) for i in judged
    )
    if not (ratio.size and np.median(ratio) > WEAK_INSTRUMENTS and moved_half):
        return []
    return [
        ResultWarning(
            "undecided",
            f"the data cannot settle the inertial and gravity parameters: they move at half and at twice the "
            f"derivative cut-off, and the instruments' standard errors are {np.median(ratio):.0f}× least squares'. "
            "Record motion that excites the arm more (ident-opt excite), at a higher sampling rate, or log the joint "
            "velocities from the drives.",
        )
    ]


def raised(trials: list[Dataset], factor: float) -> list[Dataset]:
    """The trials with their derivatives at `factor` × their cut-off (at most a quarter of their rate)."""
    return [refiltered(d, min(factor * d.cutoff_hz, CUTOFF_MAX_FRACTION * d.rate_hz)) for d in trials]


def _highest_agreeing(model: Arm, trials: list[Dataset]) -> tuple[float, list[Dataset]]:
    """(factor, trials at it): the highest of `FACTORS_UP` up to which OLS and IV keep agreeing (1: none)."""
    factor, chosen_trials = 1.0, trials
    for f in FACTORS_UP:
        raised_trials = raised(trials, f)
        stats = estimators.statistics(model, raised_trials)
        if not agree(model, estimators.fit("ols", stats, model), estimators.iv(stats, model)):
            break
        factor, chosen_trials = f, raised_trials
    return factor, chosen_trials


def judge(
    robot: Robot,
    model: Arm,
    trials: list[Dataset],
    conversions: dict[str, tuple[float, float]] | None = None,
    setting: float | str | None = None,
) -> Choice:
    """The recommended fit from the training `trials`' own evidence (module doc): OLS and IV, the trust checks
    (`fitting.trust.checks`; `setting`: the problem's `derivative_cutoff_hz`, so that advice never asks for what the
    run already did) and the highest cut-off where OLS and IV agree."""
    stats = estimators.statistics(model, trials)
    ols = estimators.fit_for(robot, "ols", stats, model)
    iv = estimators.iv(stats, model)
    trust = checks(model, trials, ols, iv, conversions, robot, setting)
    agreed = agree(model, ols, iv)
    factor, at = 1.0, trials
    if trust.cutoffs and agreed and not any(w.code in BIASED for w in trust.warnings):
        factor, at = _highest_agreeing(model, trials)
    found = _recommend(robot, trust, agreed, factor)
    if found.estimator == "robust":
        trust.warnings += undecided(model, trust, ols, iv)
    return replace(found, evidence=Evidence(ols, iv, trust, at, list(trials)))


def choose(
    problem: Problem,
    trials: Sequence[Dataset],
    *,
    model: Arm | None = None,
    estimator: str | None = None,
    command: str = "ident-opt",
) -> Choice:
    """The fit `command` stands behind on the training `trials` of `problem` (its robot, conversions and derivative
    cut-off setting): `estimator` when one is asked for (checked against the arm's fits: an InputError naming them
    otherwise), else the recommended one from the trials' own evidence (`judge`). `model`: the arm's model the fit
    is for (default `problem.robot.model()`). The one entry point of the recommended fit."""
    robot = problem.robot
    if estimator is not None:
        if not isinstance(estimator, str):  # the API's `estimator=`: a name, never a fit or a choice
            raise InputError(
                f"{command}: estimator must be None (the recommended fit) or the name of one of the arm's fits "
                f"({', '.join(robot.estimators)}), got {type(estimator).__name__} {excerpt(estimator)}"
            )
        if estimator not in robot.estimators:
            raise InputError(
                f"{command}: --estimator {estimator} is not a fit of this arm ({robot.described_as}); its fits: "
                f"{', '.join(robot.estimators)}"
            )
        return Choice(estimator, "chosen with --estimator")
    model = model if model is not None else robot.model()
    data = problem.data
    return judge(robot, model, list(trials), data.conversions, data.derivative_cutoff_hz)


def checked_choice(value: object, robot: Robot, argument: str, command: str) -> Choice | None:
    """`value` when it is None or a `Choice` of one of `robot`'s fits (`choose` makes them; `ArmFit.choice` and
    `Comparison.choice` are ones); an InputError naming `argument` and what it must be otherwise (a fit's name goes
    to `estimator=`, which is chosen from)."""
    if value is None or (isinstance(value, Choice) and value.estimator in robot.estimators):
        return value
    if isinstance(value, Choice):
        raise InputError(
            f"{command}: {argument} is a choice of the {value.estimator} fit, which {robot.described_as} does not "
            f"have; its fits: {', '.join(robot.estimators)}"
        )
    hint = f"; to name a fit, pass estimator={value!r}" if isinstance(value, str) else ""
    raise InputError(
        f"{command}: {argument} must be None or a Choice of fit (ident_opt.fitting.recommend."
        f"choose makes one; fit.choice and comparison.choice are ones), got {type(value).__name__} "
        f"{excerpt(value)}{hint}"
    )


# ---------------------------------------------------------------------------------------------- fit options
#: The keyword options each estimator takes (`ident_opt.fit(problem, trials, estimator, **options)`; meaning and
#: defaults: the estimator's function, `fitting.estimators`). The robust fit takes those of the arm's consistent
#: fit (`Robot.default_estimator`); options the problem file sets for a fit (`Robot.fit_options`) are not the
#: caller's to give again.
FIT_OPTIONS = {
    "ols": ("weights",),
    "constrained": ("margin", "weights", "prior", "prior_weight", "bounds", "friction", "mass", "shortcut", "backend"),
    "nlp_physical": ("weights", "prior_weight", "options"),
    "consistent": ("margin", "weights", "prior", "prior_weight", "mass_range", "com_box", "backend"),
}
#: The solvers the conic fits can run on.
BACKENDS = ("clarabel", "cvxpy")


def fit_options(robot: Robot, estimator: str, model: Arm, options: Mapping[str, object], command: str) -> dict:
    """`options` for the `estimator` fit of `model` (the API's `**options`), each checked at the door like the
    command line's flags (`option`); an option the fit does not take is an InputError naming it and the ones it
    takes, never a solver's TypeError."""
    own = robot.default_estimator if estimator == "robust" else estimator
    fixed = set(estimators.options_for(robot, estimator))
    takes = [name for name in FIT_OPTIONS.get(own, ()) if name not in fixed]
    for name in options:
        if name not in takes:
            set_by = " (the problem file sets it)" if name in fixed else ""
            raise InputError(
                f"{command}: the {estimator} fit takes no option {name!r}{set_by}; its options: "
                f"{', '.join(takes) or 'none'}"
            )
    checked = {name: option(name, value, model, command, own) for name, value in options.items()}
    if own == "constrained" and (checked.get("prior_weight") or 0) > 0 and checked.get("prior") is None:
        if "prior" not in fixed:  # the solver's own ValueError otherwise
            raise InputError(
                f"{command}: prior_weight > 0 pulls π towards a prior: give it too (prior=, one value per "
                f"parameter of the {model.n_params}-parameter model), or leave prior_weight at 0"
            )
    return checked


def option(name: str, value: object, model: Arm, command: str, estimator: str = "constrained") -> object:
    """One fit option `name` of the `estimator` fit of `model`, checked (`_CHECKS`); an InputError naming it (as
    "`command`: `name`") otherwise."""
    check = _CHECKS.get(name)
    if check is None:
        raise InputError(f"{command}: {name}: not an option of any fit")
    return check(f"{command}: {name}", value, model, estimator)


def _is_number(value: object) -> bool:
    return isinstance(value, Real) and not isinstance(value, bool)


def _margin(label: str, value: object, model: Arm, estimator: str) -> float:
    """The LMIs' margin [kg m²]: a number in the command line's range for --margin."""
    low, high = range_of("compare", "margin")
    if not (_is_number(value) and low <= value <= high):
        raise InputError(
            f"{label} must be a number in [{low:g}, {high:g}] kg m² (M(q) ⪰ margin·I), got {excerpt(value)}"
        )
    return float(value)


def _nonnegative(label: str, value: object, model: Arm, estimator: str) -> float | None:
    """prior_weight ≥ 0 (> 0 for the consistent fit's log-det prior); mass_range, com_box [m]: None or ≥ 0."""
    strict = label.endswith("prior_weight") and estimator == "consistent"
    if value is None and not label.endswith("prior_weight"):
        return None
    if not (_is_number(value) and np.isfinite(value) and (value > 0 if strict else value >= 0)):
        raise InputError(f"{label} must be a finite number {'> 0' if strict else '≥ 0'}, got {excerpt(value)}")
    return float(value)


def _weights(label: str, value: object, model: Arm, estimator: str) -> str | np.ndarray | None:
    """None (plain least squares), "wls" (1/σ_j² per joint) or one positive weight per joint."""
    if value is None or (isinstance(value, str) and value == "wls"):
        return value
    if isinstance(value, str):
        raise InputError(f'{label} must be None, "wls" or one positive weight per joint, got {excerpt(value)}')
    w = checked_array(label, value, (model.n_joints,), f" (one weight per joint of the {model.n_joints}-joint model)")
    if (w <= 0).any():
        raise InputError(f"{label} must be positive (one weight per joint), got {excerpt(w)}")
    return w


def _prior(label: str, value: object, model: Arm, estimator: str) -> np.ndarray | None:
    """None or π0: one finite value per parameter."""
    return None if value is None else checked_array(label, value, (model.n_params,), " (one value per parameter)")


def _bounds(label: str, value: object, model: Arm, estimator: str) -> tuple[np.ndarray, np.ndarray] | None:
    """None or (lb, ub): one bound per parameter each, ±inf for none, lb ≤ ub."""
    if value is None:
        return None
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) != 2:
        raise InputError(
            f"{label} must be None or a pair (lb, ub) of {model.n_params} bounds each, got {excerpt(value)}"
        )
    why = " (one bound per parameter, ±inf for none)"
    lb, ub = (checked_array(f"{label}[{i}]", v, (model.n_params,), why, infinite=True) for i, v in enumerate(value))
    if (lb > ub).any():
        i = int(np.argmax(lb > ub))
        raise InputError(f"{label}: the lower bound of {model.names[i]} is above its upper one ({lb[i]:g} > {ub[i]:g})")
    return lb, ub


def _switch(label: str, value: object, model: Arm, estimator: str) -> bool:
    """friction, mass, shortcut: True or False."""
    if not isinstance(value, (bool, np.bool_)):
        raise InputError(f"{label} must be True or False, got {excerpt(value)}")
    return bool(value)


def _backend(label: str, value: object, model: Arm, estimator: str) -> str:
    """One of `BACKENDS`."""
    if not isinstance(value, str) or value not in BACKENDS:
        raise InputError(f"{label} must be one of {', '.join(BACKENDS)}, got {excerpt(value)}")
    return value


def _ipopt(label: str, value: object, model: Arm, estimator: str) -> Mapping | None:
    """None or a dict of IPOPT options (the NLP on physical parameters)."""
    if value is not None and not isinstance(value, Mapping):
        raise InputError(f"{label} must be None or a dict of IPOPT options, got {excerpt(value)}")
    return value


#: Each fit option's check: (label, value, model, estimator) → the value to pass on, or an InputError.
_CHECKS = {
    "margin": _margin,
    "prior_weight": _nonnegative,
    "mass_range": _nonnegative,
    "com_box": _nonnegative,
    "weights": _weights,
    "prior": _prior,
    "bounds": _bounds,
    "friction": _switch,
    "mass": _switch,
    "shortcut": _switch,
    "backend": _backend,
    "options": _ipopt,
}
