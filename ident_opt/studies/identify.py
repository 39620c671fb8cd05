"""The identify study: every model (RR, DM in both conventions, PBR, CPBR, each ± GMR) under every protocol on
the problem's trials — the paper's shuffled 70/30 over its seeds (also with two GMR variants), a chronological
split and cross-trial — plus the parameters fitted on the whole first trial, Model 1's ridge weights and the
paper's seed study. `ident_opt.report.identify` writes it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ident_opt.arm.datasheet import datasheet_pi
from ident_opt.arm.planar import RIGID
from ident_opt.data import Dataset
from ident_opt.models import DATASHEETS, FITTED, RidgeModel, RigidModel
from ident_opt.paper import PI_TRUE
from ident_opt.problem.spec import Problem
from ident_opt.studies.protocols import ProtocolResult, chronological_protocol, cross_trial_protocol, paper_protocol
from ident_opt.studies.seeds import SplitResults, seed_study

#: The paper's protocol with other GMR settings: name -> label (`IdentifyResult.variants`).
VARIANTS = {"diagonal_covariance": "diag GMM", "one_component": "K = 1"}
#: The names of Model 1's features, in its column order.
RIDGE_FEATURES = ("q1", "q2", "dq1", "dq2", "ddq1", "ddq2")


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
    #: what the tool applied to read the robot (a URDF arm's angle offsets and signs, `UrdfPlanarRobot.statement`)
    robot_statement: tuple[str, ...] = ()


#: A problem describes the paper's robot when its datasheet, read in the paper's convention, gives the paper's
#: π_True within this relative tolerance (inertial and gravity parameters).
PAPER_ROBOT_TOLERANCE = 0.02


def is_paper_robot(problem: Problem) -> bool:
    """Whether `problem` is the paper's arm (TUDOR): bars and motors whose paper-convention π is the paper's."""
    if getattr(problem.robot, "description", "bars") != "bars":
        return False
    pi = datasheet_pi(problem.robot, "paper")
    return all(abs(pi[k] / PI_TRUE[k] - 1) <= PAPER_ROBOT_TOLERANCE for k in ("a1", "a2", "a3", "b1", "b2"))


def steps(problem: Problem, unseen: Dataset | None, variants: bool = True) -> int:
    """How many times `identify` ticks its progress bar."""
    return len(problem.split.seeds) * (3 if variants else 1) + 2 + (unseen is not None)


def identify(
    problem: Problem, trial: Dataset, unseen: Dataset | None = None, *, variants: bool = True, progress=None
) -> IdentifyResult:
    """The study. `progress`: a tqdm-like bar (`update()`, `set_postfix_str(text)`) or None."""
    bar = progress or _Silent()
    bar.set_postfix_str("paper's protocol")
    protocols = {"paper": paper_protocol(trial, problem, progress=bar.update)}
    others = _variants(trial, problem, protocols["paper"], bar) if variants else {}
    bar.set_postfix_str("chronological")
    protocols["chronological"] = chronological_protocol(trial, problem, progress=bar.update)
    if unseen is not None:
        bar.set_postfix_str("cross-trial")
        protocols["cross_trial"] = cross_trial_protocol(trial, unseen, problem, progress=bar.update)
    bar.set_postfix_str("parameters")
    params, ses, eig = whole_trial_parameters(problem, trial)
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
        seeds=seed_study(trial, RIGID, problem.split),
        paper_robot=is_paper_robot(problem),
        robot_statement=tuple(getattr(problem.robot, "statement", ())),
    )
    bar.update()
    return result


def _variants(trial: Dataset, problem: Problem, paper: ProtocolResult, bar) -> dict[str, tuple[str, ProtocolResult]]:
    """The paper's protocol with diagonal-covariance GMMs, and with one full-covariance component."""
    bar.set_postfix_str("paper's protocol, diagonal GMM")
    diag = paper_protocol(trial, problem, covariance="diag", progress=bar.update)
    diag.description += ", diagonal-covariance GMMs"
    bar.set_postfix_str("paper's protocol, one component")
    ones = dict.fromkeys(paper.components, 1)
    one = paper_protocol(trial, problem, components=ones, progress=bar.update)
    one.description += ", one full-covariance component"
    return {
        "diagonal_covariance": (VARIANTS["diagonal_covariance"], diag),
        "one_component": (VARIANTS["one_component"], one),
    }


def whole_trial_parameters(problem: Problem, trial: Dataset):
    """π on the whole first trial: datasheet (both conventions), every fitted estimator (`models.FITTED`)
    with SEs; and each one's smallest eigenvalue of M(q) over q [kg m²] (rounded to 1e-12)."""
    conv = problem.robot.convention
    other = next(c for c in DATASHEETS if c != conv)
    params = {"datasheet": datasheet_pi(problem.robot, conv), f"datasheet_{other}": datasheet_pi(problem.robot, other)}
    ses, eig = {}, {}
    for name in FITTED.values():
        fitted = RigidModel(name, RIGID, estimator=name).fit(trial)
        params[name] = fitted.params()
        ses[name] = fitted.fit_.se_dict()
        eig[name] = RIGID.min_mass_eigenvalue(fitted.pi)
    arm = DATASHEETS[conv][1]  # M(q) does not depend on the gravity vector: RIGID's and PAPER's are the same
    eig["datasheet"] = arm.min_mass_eigenvalue(arm.vector(params["datasheet"]))
    return params, ses, {k: float(np.round(v, 12)) for k, v in eig.items()}


def ridge_weights(trial: Dataset) -> dict:
    """Model 1 fitted on the whole first trial: penalty (chosen by leave-one-out CV), weights, intercept."""
    rr = RidgeModel().fit(trial)
    return {
        "alpha": rr.alpha_.tolist(),
        "intercept": rr.intercept_.tolist(),
        "coef": {f: rr.coef_[:, i].tolist() for i, f in enumerate(RIDGE_FEATURES)},
    }


class _Silent:
    """A progress bar that shows nothing."""

    def update(self) -> None:
        pass

    def set_postfix_str(self, text: str) -> None:
        pass
