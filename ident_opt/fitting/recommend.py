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

from dataclasses import dataclass

import numpy as np

from ident_opt.arm.base import Arm, Robot
from ident_opt.data.dataset import Dataset, refiltered
from ident_opt.data.derivatives import CUTOFF_MAX_FRACTION
from ident_opt.errors import InputError
from ident_opt.fitting import estimators
from ident_opt.fitting.fit import LinearFit
from ident_opt.fitting.trust import JUDGED_KINDS, SENSITIVITY_TOLERANCE, Trust, checks
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


@dataclass(frozen=True)
class Recommendation:
    """The estimator the tool stands behind (a name of `ident_opt.fitting.estimators`), why, in a sentence, and
    the factor applied to each training trial's derivative cut-off (1: the spectra's)."""

    estimator: str
    why: str
    factor: float = 1.0


def agree(model: Arm, ols: LinearFit, iv: LinearFit) -> bool:
    """Whether OLS and IV agree on every judged parameter the data determine (`AGREE_TOLERANCE`)."""
    for i, p in enumerate(model.parameters):
        if p.kind not in JUDGED_KINDS or not (np.isfinite(ols.se[i]) and np.isfinite(iv.se[i])):
            continue
        if abs(ols.pi[i] - iv.pi[i]) > AGREE_TOLERANCE * abs(iv.pi[i]):
            return False
    return True


def recommend(robot: Robot, trust: Trust, agreed: bool = True, factor: float = 1.0) -> Recommendation:
    """The recommended estimator from the trust checks' warnings and whether OLS and IV agree at the spectra's
    cut-offs (`agreed`); `factor`: the highest cut-off factor where they still agreed (module doc)."""
    consistent = robot.default_estimator
    if not trust.cutoffs:
        return Recommendation(
            consistent,
            "the derivatives were logged, not estimated here: no cut-off to judge, so the physically consistent fit "
            f"({consistent})",
        )
    evidence = [w.code for w in trust.warnings if w.code in BIASED]
    if (evidence or not agreed) and "robust" in robot.estimators:
        shown = {"ols_iv_disagree": "OLS and IV disagree", "cutoff_sensitivity": "the parameters move with the cut-off"}
        said = " and ".join(shown[c] for c in evidence) or "OLS and IV differ beyond their standard errors"
        return Recommendation(
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
    return Recommendation(consistent, f"OLS and IV agree: the physically consistent fit ({consistent}) {where}", factor)


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


@dataclass
class Evidence:
    """What the recommendation rests on: OLS and IV on the training trials at the spectra's cut-offs, the trust
    checks (with `undecided`), the recommendation, and the training trials at its cut-off (`trials`)."""

    ols: LinearFit
    iv: LinearFit
    trust: Trust
    recommendation: Recommendation
    trials: list[Dataset]


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


def evidence(
    robot: Robot,
    model: Arm,
    trials: list[Dataset],
    conversions: dict[str, tuple[float, float]] | None = None,
    setting: float | str | None = None,
    ols: LinearFit | None = None,
    iv: LinearFit | None = None,
) -> Evidence:
    """OLS and IV on the training `trials` (given, or fitted here), the trust checks (`fitting.trust.checks`;
    `setting`: the problem's `derivative_cutoff_hz`), and the recommendation they lead to with the trials at its
    cut-off (module doc)."""
    stats = estimators.statistics(model, trials) if ols is None or iv is None else None
    ols = ols or estimators.fit_for(robot, "ols", stats, model)
    iv = iv or estimators.iv(stats, model)
    trust = checks(model, trials, ols, iv, conversions, robot, setting)
    agreed = agree(model, ols, iv)
    factor, at = 1.0, trials
    if trust.cutoffs and agreed and not any(w.code in BIASED for w in trust.warnings):
        factor, at = _highest_agreeing(model, trials)
    choice = recommend(robot, trust, agreed, factor)
    if choice.estimator == "robust":
        trust.warnings += undecided(model, trust, ols, iv)
    return Evidence(ols, iv, trust, choice, at)


def recommended_fit(robot: Robot, model: Arm, trials: list[Dataset], problem=None) -> tuple[LinearFit, Evidence]:
    """The recommended fit of `model` on `trials` (at the recommendation's cut-off), with the evidence behind it;
    `problem` gives the conversions and the cut-off setting the advice takes into account."""
    data = problem.data if problem is not None else None
    found = evidence(
        robot,
        model,
        trials,
        data.conversions if data is not None else None,
        data.derivative_cutoff_hz if data is not None else None,
    )
    name = found.recommendation.estimator
    fit = estimators.fit_for(robot, name, estimators.statistics(model, found.trials, name, probes=True), model)
    return fit, found


def chosen(command: str, robot: Robot, model: Arm, trials: list[Dataset], problem, asked: str | None) -> Recommendation:
    """The estimator `command` uses: `asked` (`--estimator`, checked against the arm's fits: an InputError naming
    them otherwise), else the recommended one from the training `trials`' evidence."""
    if asked is not None:
        if asked not in robot.estimators:
            raise InputError(
                f"{command}: --estimator {asked} is not a fit of this arm ({robot.described_as}); its fits: "
                f"{', '.join(robot.estimators)}"
            )
        return Recommendation(asked, "chosen with --estimator")
    data = problem.data
    return evidence(robot, model, trials, data.conversions, data.derivative_cutoff_hz).recommendation


def for_diagnosis(
    robot: Robot,
    trial: Dataset,
    unseen: Dataset | None = None,
    train_fraction: float = 0.7,
    conversions: dict[str, tuple[float, float]] | None = None,
    setting: float | str | None = None,
) -> Evidence:
    """The evidence (and the recommendation) on the part of the data `diagnose` trains on: all of `trial` when a
    held-out `unseen` trial is given, else its first `train_fraction` in time (`diagnosis.loop.split`, the
    diagnosis's own split). The command and the benchmarks that stand for it both ask here."""
    from ident_opt.diagnosis.loop import split  # the diagnosis sits on the estimators, not on the studies

    train = split(trial, unseen, train_fraction)[0]
    return evidence(robot, robot.model(), [train], conversions, setting)
