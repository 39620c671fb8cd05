"""The identify study: every model (RR, DM in both conventions, PBR, CPBR, each ± GMR) under every protocol on
the problem's trials — the paper's shuffled 70/30 over its seeds (also with two GMR variants), a chronological
split and cross-trial — plus the parameters fitted on the whole first trial, Model 1's ridge weights and the
paper's seed study. `ident_opt.report.identify` writes it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ident_opt.columns import kinematic_columns
from ident_opt.data.dataset import Dataset, concat
from ident_opt.data.loader import held_out_overlap
from ident_opt.data.validate import checked_problem, checked_trials
from ident_opt.fitting import estimators
from ident_opt.fitting.recommend import Choice, choose
from ident_opt.fitting.trust import Trust, check_masses, check_slow_samples
from ident_opt.metrics import METRICS, all_metrics
from ident_opt.models.hybrid import RidgeModel, fitted
from ident_opt.paper.protocols import ProtocolResult, chronological_protocol, cross_trial_protocol, paper_protocol
from ident_opt.paper.published import PI_TRUE
from ident_opt.paper.seeds import SplitResults, seed_study
from ident_opt.problem.spec import Problem

#: The paper's protocol with other GMR settings: name -> label (`IdentifyResult.variants`).
VARIANTS = {"diagonal_covariance": "diag GMM", "one_component": "K = 1"}


@dataclass
class IdentifyResult:
    """Everything the report needs from one identify run."""

    problem_name: str
    trial: str  # the identification trial's file
    unseen: str | None  # the unseen trial's file
    protocols: dict[str, ProtocolResult]
    parameters: dict[str, dict[str, float]]  # datasheet, datasheet_<other convention>, ols, constrained
    standard_errors: dict[str, dict[str, float]]
    consistency: dict[str, float]  # estimator -> min over q of λ_min(M(q)) [kg m²]
    #: the paper's protocol with other GMR settings: name -> (label, result), e.g. diagonal covariances
    variants: dict[str, tuple[str, ProtocolResult]] = field(default_factory=dict)
    gmr_candidates: tuple[int, ...] = ()  # the problem's candidate numbers of components
    ridge: dict = field(default_factory=dict)  # Model 1 on the whole first trial: alpha, intercept, coef
    reg_covar: float = float("nan")  # the GMR's covariance regulariser (standardised units)
    seeds: SplitResults | None = None  # OLS over the paper's seeds (the seed figure)
    #: the problem describes the paper's robot: its reproduction table, π columns and sentences belong in the report
    paper_robot: bool = True
    #: what the tool applied to read the robot (`Robot.statement`: a URDF arm's angle offsets and signs, notes)
    robot_statement: tuple[str, ...] = ()
    joints: tuple[str, ...] = ("joint1", "joint2")  # the joints' names, base to tip
    paper_views: bool = True  # the paper's protocol, its seed study and tables apply (`Robot.paper_views`)
    #: what `consistency` measures, for the report (`Arm.consistency_measure` without its unit)
    consistency_note: str = "min eig M(q)"
    warnings: list = field(default_factory=list)  # `ident_opt.warnings.ResultWarning`s of the trust checks
    choice: Choice | None = None  # the fit cpbr is, and why (`fitting.recommend`)
    #: per held-out trial (when there are several): {file: {metric: {model: [one value per joint]}}}
    by_test_trial: dict = field(default_factory=dict)


#: A problem describes the paper's robot when its datasheet, read in the paper's convention, gives the paper's
#: π_True within this relative tolerance (inertial and gravity parameters).
PAPER_ROBOT_TOLERANCE = 0.02


def is_paper_robot(problem: Problem) -> bool:
    """Whether `problem` is the paper's arm (TUDOR): a planar arm of bars and motors whose paper-convention π is the
    paper's (`PAPER_ROBOT_TOLERANCE`)."""
    robot = problem.robot
    if not robot.paper_views or "paper" not in robot.datasheets():
        return False
    arm, pi = robot.datasheets()["paper"]
    values = arm.as_dict(pi)
    return all(abs(values[k] / PI_TRUE[k] - 1) <= PAPER_ROBOT_TOLERANCE for k in ("a1", "a2", "a3", "b1", "b2"))


def steps(problem: Problem, unseen: bool, variants: bool = True) -> int:
    """How many times `identify` ticks its progress bar (`unseen`: with held-out trials)."""
    paper = len(problem.split.seeds) * (3 if variants else 1) if problem.robot.paper_views else 0
    return paper + 2 + unseen


def identify(
    problem: Problem,
    training: list[Dataset],
    testing: list[Dataset] | None = None,
    *,
    variants: bool = True,
    progress=None,
) -> IdentifyResult:
    """The study on the `training` trials (pooled: derivatives were estimated per file, so nothing straddles two)
    and the held-out `testing` ones (pooled, and each scored on its own). `progress`: a tqdm-like bar (`update()`,
    `set_postfix_str(text)`) or None. The paper's protocol (and its GMR variants, its seed study) runs where the
    paper's views apply (`Robot.paper_views`). The trust checks of `fitting.trust` run on the training trials."""
    checked_problem(problem, "identify").require("identify")
    training = checked_trials(problem, training, "identify", "training", fit=True)
    testing = checked_trials(problem, testing, "identify", "testing", required=False)
    bar = progress or _Silent()
    robot = problem.robot
    overlap = held_out_overlap(training, testing or [])
    choice = choose(problem, training, model=robot.model(()), command="identify")
    training = choice.at_cutoff(training)
    trial = concat(training)
    unseen = concat(testing) if testing else None
    protocols, others, seeds = {}, {}, None
    if robot.paper_views:
        bar.set_postfix_str("paper's protocol")
        protocols["paper"] = paper_protocol(trial, problem, progress=bar.update, choice=choice)
        others = _variants(trial, problem, protocols["paper"], bar, choice) if variants else {}
        seeds = seed_study(trial, robot.model(()), problem.split)
    bar.set_postfix_str("chronological")
    protocols["chronological"] = chronological_protocol(trial, problem, progress=bar.update, choice=choice)
    if unseen is not None:
        bar.set_postfix_str("cross-trial")
        protocols["cross_trial"] = cross_trial_protocol(trial, unseen, problem, progress=bar.update, choice=choice)
    bar.set_postfix_str("parameters")
    params, ses, eig = whole_trial_parameters(problem, training, choice)
    trust = _trust(problem, choice, params)
    result = IdentifyResult(
        problem.name,
        trial.source,
        unseen.source if unseen is not None else None,
        protocols,
        params,
        ses,
        eig,
        others,
        gmr_candidates=tuple(problem.residual.candidates),
        ridge=ridge_weights(trial),
        reg_covar=problem.residual.reg_covar,
        seeds=seeds,
        paper_robot=is_paper_robot(problem),
        robot_statement=tuple(robot.statement),
        joints=tuple(robot.joint_names),
        paper_views=robot.paper_views,
        consistency_note=robot.model(()).consistency_measure.removesuffix(" [kg m²]"),
        warnings=[*overlap, *trust.warnings],  # the trials' own (a held-out trial that trains) first
        choice=choice,
        by_test_trial=_by_test_trial(protocols.get("cross_trial"), testing or []),
    )
    bar.update()
    return result


def _variants(
    trial: Dataset, problem: Problem, paper: ProtocolResult, bar, choice: Choice
) -> dict[str, tuple[str, ProtocolResult]]:
    """The paper's protocol with diagonal-covariance GMMs, and with one full-covariance component."""
    bar.set_postfix_str("paper's protocol, diagonal GMM")
    diag = paper_protocol(trial, problem, covariance="diag", progress=bar.update, choice=choice)
    diag.description += ", diagonal-covariance GMMs"
    bar.set_postfix_str("paper's protocol, one component")
    ones = dict.fromkeys(paper.components, 1)
    one = paper_protocol(trial, problem, components=ones, progress=bar.update, choice=choice)
    one.description += ", one full-covariance component"
    return {
        "diagonal_covariance": (VARIANTS["diagonal_covariance"], diag),
        "one_component": (VARIANTS["one_component"], one),
    }


def _trust(problem: Problem, choice: Choice, params: dict) -> Trust:
    """The trust checks (`fitting.trust`: the angle convention, the cut-off, OLS against IV) behind the
    recommendation, the fits' masses against the nominal ones and the training samples too slow to read friction
    from: what the JSON's `warnings` say."""
    robot, model = problem.robot, problem.robot.model(())
    trust = choice.evidence.trust
    nominal_arm, nominal_pi = robot.datasheets()[robot.datasheet]
    fits = fitted(robot, choice.estimator).values()
    estimates = {name: model.vector(params[name]) for name in fits if name != "ols"}
    trust.warnings += check_masses(model, estimates, nominal_arm.link_masses(nominal_pi))
    trust.warnings += check_slow_samples(model, choice.evidence.trials, robot.joint_names)
    return trust


def _by_test_trial(cross: ProtocolResult | None, testing: list[Dataset]) -> dict[str, dict]:
    """{file: {metric: {model: [one value per joint]}}} of the cross-trial protocol on each held-out trial, from its
    predictions on their pool (the trials follow one another in it); {} for fewer than two held-out trials."""
    if cross is None or len(testing) < 2:
        return {}
    out, start = {}, 0
    split = cross.example
    for d in testing:
        rows = slice(start, start + d.n)
        start += d.n
        per: dict[str, dict] = {m: {} for m in METRICS}
        for key, prediction in split.predictions.items():
            for m, v in all_metrics(d.tau, prediction[rows]).items():
                per[m][key] = v
        out[d.source] = per
    return out


def whole_trial_parameters(problem: Problem, training: list[Dataset], choice: Choice):
    """π on all the training trials: the robot's nominal models ("datasheet" its own, "datasheet_<name>" the
    others), every fitted estimator (`models.fitted`) with SEs; and each one's consistency margin
    (`Arm.min_mass_eigenvalue`, for the planar arm the smallest eigenvalue of M(q) over q) [kg m²] (rounded to
    1e-12). The statistics add up trial by trial (`estimators.statistics`), as `compare`'s do: each trial's
    residuals counted at its own cut-off, and the robust fit's errors covering its bias (`probes`); a pool of
    trials with different cut-offs would count every sample as independent."""
    robot = problem.robot
    sheets = robot.datasheets()
    own_arm, own_pi = sheets[robot.datasheet]
    params = {"datasheet": own_arm.as_dict(own_pi)}
    others = {name: model for name, model in sheets.items() if name != robot.datasheet}
    params.update({f"datasheet_{name}": arm.as_dict(pi) for name, (arm, pi) in others.items()})
    ses, eig = {}, {}
    arm = robot.model(())
    # OLS, the arm's consistent fit (the JSON contract's "constrained" for the planar arm) and the recommended one
    for name in dict.fromkeys([*fitted(robot).values(), *fitted(robot, choice.estimator).values()]):
        fit = estimators.fit_for(robot, name, estimators.statistics(arm, training, name, probes=True), arm)
        params[name] = fit.as_dict()
        ses[name] = fit.se_dict()
        eig[name] = arm.min_mass_eigenvalue(fit.pi)
    eig["datasheet"] = own_arm.min_mass_eigenvalue(own_pi)
    return params, ses, {k: float(np.round(v, 12)) for k, v in eig.items()}


def ridge_weights(trial: Dataset) -> dict:
    """Model 1 fitted on the whole first trial: penalty (chosen by leave-one-out CV), weights, intercept."""
    rr = RidgeModel().fit(trial)
    return {
        "alpha": rr.alpha_.tolist(),
        "intercept": rr.intercept_.tolist(),
        "coef": {f: rr.coef_[:, i].tolist() for i, f in enumerate(kinematic_columns(trial.q.shape[1])[1:])},
    }


class _Silent:
    """A progress bar that shows nothing."""

    def update(self) -> None:
        pass

    def set_postfix_str(self, text: str) -> None:
        pass
