"""Side by side, for any arm: the nominal model (datasheet or URDF), OLS, the consistent fits the arm offers, IV.

`compare` fits every estimator of the arm (`Robot.estimators`: OLS, the constrained fit, and the planar
arm's NLP on physical parameters or an n-joint arm's plausible consistent fit) on all training trials from their
sufficient statistics, and scores each, the nominal models and a published `[reference]` on the same held-out
samples: the paper's shuffled protocol (the planar arm only, `Robot.paper_views`), the chronological split of the
pooled training samples and, when held-out trials are given, each of them and their pool. Beside the fits: the
trust checks (`fitting.trust`), each LMI's smallest eigenvalue, the links' masses against the nominal ones, and
the OLS base parameters no consistent arm can have negative. `ident_opt.report.compare` writes it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from ident_opt.arm.base import Arm
from ident_opt.consistency import lmi_eigenvalues, necessarily_nonnegative, sign_violations
from ident_opt.data.dataset import Dataset, chronological_split, concat, shuffled_split
from ident_opt.data.loader import held_out_overlap
from ident_opt.data.validate import checked_problem, checked_trials
from ident_opt.errors import InputError, excerpt
from ident_opt.fitting import drive_gains, estimators
from ident_opt.fitting.base import base_parameters
from ident_opt.fitting.drive_gains import DriveGains
from ident_opt.fitting.fit import LinearFit
from ident_opt.fitting.recommend import Choice, choose, option
from ident_opt.fitting.trust import Trust, check_masses, check_slow_samples
from ident_opt.metrics import METRICS, all_metrics
from ident_opt.outputs import shown
from ident_opt.paper.seeds import FitFn, SplitResults, deviation_from_mean, seed_study, split_fits
from ident_opt.problem.spec import Problem

PROTOCOLS = {
    "paper": "shuffled 70/30, mean over the paper's seeds (flattering: test samples have near-copies in training)",
    "chronological": "first 70 % of the (pooled) training samples in time trains, the rest tests",
    "cross_trial": "identify on all training trials, test on the held-out trial(s), pooled",
}
#: A fit within this factor of OLS's held-out RMSE on a joint (where OLS beats the nominal model) costs nothing.
WITHIN_OLS = 1.1


def fitted_estimators(robot, margin: float = 1e-6, weights: str | None = None) -> dict[str, FitFn]:
    """The arm's estimators by key (`Robot.estimators`): statistics + model → LinearFit (`weights`: None or
    "wls"); `margin` [kg m²] of the constrained fit's LMIs."""
    out = {}
    for name in robot.estimators:
        options = {"margin": margin} if name == "constrained" else {}
        out[name] = partial(estimators.fit_for, robot, name, weights=weights, **options)
    return out


def nominal_models(robot, reference=None) -> dict[str, tuple[Arm, np.ndarray]]:
    """The nominal models scored beside the fits, each with the arm it is evaluated with: "datasheet_<name>" for
    each of the robot's (`Robot.datasheets`), and "reference" for a problem's `[reference]`."""
    out = {f"datasheet_{name}": model for name, model in robot.datasheets().items()}
    if reference is not None:
        out["reference"] = robot.reference(reference.parameters)
    return out


@dataclass
class Comparison:
    """Everything `ident-opt compare` reports. `fits` are on all training trials; `metrics` is
    {protocol: {metric: {estimator: [one value per joint]}}}; `seeds` is the paper's seed study (None for an arm
    the paper's views do not apply to)."""

    model: Arm
    fits: dict[str, LinearFit]
    datasheets: dict[str, tuple[Arm, np.ndarray]]
    metrics: dict[str, dict[str, dict[str, list[float]]]]
    seeds: SplitResults | None
    datasheet: str  # the key of `datasheets` that is the problem's own nominal model
    joints: tuple[str, ...] = ()  # the joints' names, base to tip
    sources: dict[str, str] = field(default_factory=dict)  # "train", "unseen" -> the trial's file
    trust: Trust = field(default_factory=Trust)  # the checks behind the warnings (`fitting.trust`)
    #: per held-out trial: {file: {metric: {estimator: [one value per joint]}}} (when there are several)
    by_test_trial: dict[str, dict[str, dict[str, list[float]]]] = field(default_factory=dict)
    trials: dict[str, list[str]] = field(default_factory=dict)  # "train", "test" -> files
    reference_label: str | None = None  # the `[reference]`'s label, keyed "reference"
    #: what the tool applied to read the robot (`Robot.statement`)
    robot_statement: tuple[str, ...] = ()
    default: str = "constrained"  # the fit the tool uses downstream: the recommended one
    #: the recommended fit and why (`fitting.recommend`)
    choice: Choice | None = None
    #: each drive's gain, when a training trial carries a known load (`fitting.drive_gains`); None: none does
    drive_gains: DriveGains | None = None

    def as_json(self) -> dict:
        """The `compare --json` payload (`docs/cli.md`): parameters, standard errors, consistency, metrics, warnings,
        the same keys for every arm (the seed study where the paper's protocol ran, masses where π holds them)."""
        ols = self.fits["ols"]
        out = {
            "parameters": self.parameters(),
            "standard_errors": {key: fit.se_dict() for key, fit in self.fits.items()},
            "consistency": self.consistency(),
            "metrics": self.metrics,
            "protocols": {p: PROTOCOLS[p] for p in self.metrics},
            "fits": {key: fit.summary() for key, fit in self.fits.items()},
            "physical_parameters": (
                self.fits["nlp_physical"].details.get("physical", {}) if "nlp_physical" in self.fits else {}
            ),
            "model": list(self.model.names),
            "joints": list(self.joints),
            "recommended": self.choice.estimator,
            "recommended_why": self.choice.why,
            "sources": {key: shown(path) for key, path in self.sources.items()},
            "trials": {key: [shown(p) for p in paths] for key, paths in self.trials.items()},
            "metrics_by_test_trial": {shown(k): v for k, v in self.by_test_trial.items()},
            "warnings": [w.as_dict() for w in self.trust.warnings],
            "cutoff_hz": self.trust.cutoffs,
            "cutoff_factor": self.choice.factor,
            "sensitivity": {f"ols_{f:g}x_cutoff": fit.as_dict() for f, fit in self.trust.sensitivity.items()},
            "gravity_direction": self.trust.gravity_direction,
            "reference": self.reference_label,
            "within_10_percent_of_ols": self.within_ols(),
            "masses": self.masses(),
            "base_parameters": {"ols": ols.details["base_parameters"]} if "base_parameters" in ols.details else {},
            "not_determined": {"ols": ols.details.get("not_determined", [])},
            "ols_impossible_base_values": self.impossible_base_values(),
            "standard_error_parts": {
                key: {
                    part: {n: float(v) if np.isfinite(v) else None for n, v in zip(fit.names, fit.details[part])}
                    for part in ("se_noise", "bias_bound")
                }
                for key, fit in self.fits.items()
                if "bias_bound" in fit.details
            },
        }
        if self.drive_gains is not None:
            out["drive_gains"] = self.drive_gains.as_json()
        if self.seeds is not None:
            out["seed_study"] = {
                "seeds": self.seeds.labels,
                "parameters": {key: v.tolist() for key, v in self.seeds.pi.items()},
                "deviation_from_mean_percent": {
                    key: deviation_from_mean(self.seeds, key).to_numpy().tolist() for key in self.seeds.pi
                },
                "rmse_mean": self.seeds.mean("rmse"),
                "rmse_std": self.seeds.std("rmse"),
            }
        if self.robot_statement:  # what the tool applied to read the robot (a URDF's angle offsets, notes)
            out["robot"] = list(self.robot_statement)
        return out

    def parameters(self) -> dict[str, dict[str, float]]:
        """π by estimator: "datasheet" (the problem's own), each nominal model, and every fit."""
        out = {key: arm.as_dict(pi) for key, (arm, pi) in self.datasheets.items()}
        out = {"datasheet": out[f"datasheet_{self.datasheet}"], **out}
        out.update({key: fit.as_dict() for key, fit in self.fits.items()})
        return out

    def consistency(self) -> dict[str, dict]:
        """Physical consistency of each parameter set: the smallest eigenvalue of the mass LMIs [kg m²] (overall
        and per LMI), friction signs, the verdict (which also requires armature ≥ 0), the active constraints."""
        out = {}
        for key, (arm, pi) in self.datasheets.items():
            wrong_sign = sign_violations(arm.parameters, pi)
            eig = arm.min_mass_eigenvalue(pi)
            out[key] = {
                "min_mass_eigenvalue": eig,
                "friction_nonnegative": "friction" not in wrong_sign,
                "consistent": bool(eig > 0 and not wrong_sign),
                "active_constraints": [],
                "lmi_min_eigenvalue": lmi_eigenvalues(arm, pi),
            }
        for key, fit in self.fits.items():
            out[key] = {
                "min_mass_eigenvalue": fit.min_mass_eigenvalue,
                "friction_nonnegative": fit.friction_ok,
                "consistent": fit.consistent,
                "active_constraints": fit.active,
                "lmi_min_eigenvalue": lmi_eigenvalues(self.model, fit.pi),
            }
        return out

    def masses(self) -> dict[str, dict]:
        """Each link's mass [kg] and their total per parameter set, for an arm whose parameters hold its links'
        masses (`Arm.link_masses`); {} for the planar arm's grouped π, which do not."""
        out = {}
        for key, (arm, pi) in {**self.datasheets, **{k: (self.model, f.pi) for k, f in self.fits.items()}}.items():
            links = arm.link_masses(pi)
            if links:
                out[key] = {"total": float(sum(links.values())), "links": links}
        return out

    def impossible_base_values(self) -> dict[str, dict]:
        """The OLS base parameters that no consistent arm can have negative, yet are negative: name → value, SE,
        and how many SE below 0 (what a consistent fit cannot follow); {} when the arm's consistency does not
        separate per link (`consistency.necessarily_nonnegative`) or OLS fitted every parameter itself."""
        ols = self.fits.get("ols")
        summary = ols.details.get("base_parameters") if ols is not None else None
        if not summary:
            return {}
        definite = necessarily_nonnegative(self.model, base_parameters(self.model).K)
        if definite is None:
            return {}
        out = {}
        for (name, b), sure in zip(summary.items(), definite):
            if sure and b["value"] < 0:
                out[name] = {"value": b["value"], "se": b["se"], "se_below_zero": -b["value"] / max(b["se"], 1e-300)}
        return out

    def within_ols(self) -> dict[str, dict]:
        """Per joint, on the last protocol: does OLS beat the nominal model, and is the default fit's held-out RMSE
        within `WITHIN_OLS` × OLS's (consistency then costs nothing there)?"""
        protocol = list(self.metrics)[-1]
        rmse = self.metrics[protocol]["rmse"]
        nominal, default = rmse[f"datasheet_{self.datasheet}"], rmse[self.default]
        out = {}
        for j, name in enumerate(self.joints):
            ols = rmse["ols"][j]
            out[name] = {
                "ols_better_than_datasheet": ols < nominal[j],
                "ratio_to_ols": default[j] / ols if ols > 0 else float("inf"),
                "within": default[j] <= WITHIN_OLS * ols,
            }
        return out


def _scores(datasets: list[tuple[Dataset, np.ndarray]], model: Arm, pi: np.ndarray) -> dict[str, list]:
    """Metrics of a fixed π on (dataset, test index) pairs, averaged over the pairs."""
    per = [all_metrics(d.tau[idx], model.predict(pi, d.q[idx], d.dq[idx], d.ddq[idx])) for d, idx in datasets]
    return {m: [float(np.mean([p[m][j] for p in per])) for j in range(model.n_joints)] for m in METRICS}


def _held_out(d: Dataset, scored: dict[str, tuple[Arm, np.ndarray]]) -> dict[str, dict[str, list[float]]]:
    """{metric: {key: [one value per joint]}} of each fixed (arm, π) on every sample of `d` (measured τ)."""
    out: dict[str, dict[str, list[float]]] = {m: {} for m in METRICS}
    for key, (arm, pi) in scored.items():
        for m, v in all_metrics(d.tau, arm.predict(pi, d.q, d.dq, d.ddq)).items():
            out[m][key] = v
    return out


def _within_trial(pool: Dataset, model: Arm, split, fitters: dict[str, FitFn], paper: bool, progress: bool):
    """(seed study or None, metrics and the test sets of the protocols within the training pool): the paper's
    shuffled protocol when `paper`, and the chronological split."""
    metrics: dict[str, dict[str, dict[str, list[float]]]] = {}
    test_sets: dict[str, list] = {}
    seeds = None
    if paper:
        seeds = seed_study(pool, model, split, fitters, progress=progress)
        metrics["paper"] = {m: seeds.mean(m) for m in METRICS}
        test_sets["paper"] = [(pool, shuffled_split(pool.n, split.train_fraction, s)[1]) for s in split.seeds]
    chrono = chronological_split(pool.n, split.train_fraction)
    chrono_res = split_fits(pool, model, [chrono], fitters)
    metrics["chronological"] = {m: chrono_res.mean(m) for m in METRICS}
    test_sets["chronological"] = [(pool, chrono[1])]
    return seeds, metrics, test_sets


def _extended_model(robot, extensions: Sequence[str] | None) -> Arm:
    """The model every estimator fits: the robot's own, or with `extensions`; an unknown one is an InputError."""
    try:
        return robot.model(tuple(extensions) if extensions else None)
    except ValueError as exc:
        raise InputError(f"extension: {exc}") from None


def _fit_all(
    robot, model: Arm, trains: list[Dataset], margin: float, weights: str | None
) -> tuple[dict[str, FitFn], dict[str, LinearFit]]:
    """(the estimators, their fits and IV's on all training trials): one set of statistics for every fit (they add
    up over trials); the estimators are reused by the within-trial protocols."""
    fitters = fitted_estimators(robot, margin, weights)
    whole = estimators.statistics(model, trains, probes=True)  # the robust fit's errors cover its bias
    fits = {key: fn(whole, model) for key, fn in fitters.items()}
    fits["iv"] = estimators.iv(whole, model)
    return fitters, fits


def _cross_trial(
    test_pool: Dataset,
    tests: list[Dataset],
    model: Arm,
    fits: dict[str, LinearFit],
    sheets: dict[str, tuple[Arm, np.ndarray]],
) -> tuple[dict[str, dict[str, list[float]]], dict[str, dict[str, dict[str, list[float]]]]]:
    """(metrics on the pooled held-out trials, metrics per held-out trial when there are several) of every fit and
    nominal model: the cross-trial protocol, each fit scored on data it never saw."""
    scored = {**{k: (model, f.pi) for k, f in fits.items()}, **sheets}
    pooled = _held_out(test_pool, scored)
    return pooled, ({d.source: _held_out(d, scored) for d in tests} if len(tests) > 1 else {})


def _score_nominal(
    metrics: dict[str, dict[str, dict[str, list[float]]]],
    test_sets: dict[str, list],
    sheets: dict[str, tuple[Arm, np.ndarray]],
) -> None:
    """Add the nominal models' scores to `metrics` on each within-trial protocol's own test samples, so that they
    stand beside the fits' on the same data."""
    for protocol, pairs in test_sets.items():
        for key, (sheet_model, pi) in sheets.items():
            for m, v in _scores(pairs, sheet_model, pi).items():
                metrics[protocol][m][key] = v


def _trust(
    choice: Choice,
    overlap: list,
    model: Arm,
    fits: dict[str, LinearFit],
    nominal: tuple[Arm, np.ndarray],
    joints: tuple[str, ...],
) -> Trust:
    """The recommendation's trust checks with the trials' own warnings first, the fits' link masses checked
    against the `nominal` (arm, π) and the training samples too slow to read friction from (the arm's `joints`):
    everything that qualifies the comparison, in one list."""
    trust = choice.evidence.trust
    trust.warnings[:0] = overlap  # the trials' own (a held-out trial that trains) come first
    nominal_arm, nominal_pi = nominal
    estimates = {k: f.pi for k, f in fits.items() if "base_parameters" not in f.details}  # not a lifted base fit
    trust.warnings += check_masses(model, estimates, nominal_arm.link_masses(nominal_pi))
    trust.warnings += check_slow_samples(model, choice.evidence.trials, joints)
    return trust


def _drive_gains(problem: Problem, model: Arm, trains: Sequence[Dataset], trust: Trust) -> DriveGains | None:
    """Each drive's gain when a training trial carries a known load (`[data.payloads]`), its warnings added to the
    trust checks'; None when none does."""
    loads = [problem.data.load_of(d.source) for d in trains]
    if not any(loads):
        return None
    drives = drive_gains.identify(problem.robot, model, trains, loads)
    trust.warnings += drives.warnings
    return drives


def compare(
    problem: Problem,
    training: Dataset | Sequence[Dataset],
    testing: Dataset | Sequence[Dataset] | None = None,
    *,
    extensions: Sequence[str] | None = None,
    margin: float = 1e-6,
    weights: str | None = None,
    progress: bool = False,
) -> Comparison:
    """`ident-opt compare`: fit every estimator of the problem's arm on all `training` trials (statistics add up; IV
    beside them), score it on the protocols of the module doc, score the nominal models (and the problem's
    `[reference]`) on the same test samples, run the trust checks (`fitting.trust`) and choose the fit to stand behind
    (`fitting.recommend`). `extensions`: the model's (`ident_opt.effects`; default the robot's own, `Robot.model`);
    `margin` [kg m²]: of M(q) ⪰ margin·I in the constrained fit; `weights`: None (plain least squares) or "wls" (joints
    weighted by 1/σ_j², estimated per fit). Fits use the torque filtered like the regressor's inputs
    (`Dataset.tau_fit`); every score is against the measured torque. A held-out trial that is a training trial is a
    warning."""
    checked_problem(problem, "compare").require("compare")
    robot, split, reference = problem.robot, problem.split, problem.reference
    if isinstance(extensions, str):  # one name, not its letters
        raise InputError(f"compare: extensions must be a list of extension names, got {extensions!r}")
    model = _extended_model(robot, extensions)
    margin = option("margin", margin, model, "compare")  # a number in --margin's range: never NaN, never < 0
    if weights is not None and not (isinstance(weights, str) and weights == "wls"):
        raise InputError(f'compare: weights must be None (plain least squares) or "wls", got {excerpt(weights)}')
    trains = checked_trials(problem, training, "compare", "training", fit=True)
    tests = checked_trials(problem, testing, "compare", "testing", required=False)
    overlap = held_out_overlap(trains, tests)
    choice = choose(problem, trains, model=model, command="compare")
    trains = choice.at_cutoff(trains)  # every fit is compared on the same derivatives
    pool, test_pool = concat(trains), (concat(tests) if tests else None)
    fitters, fits = _fit_all(robot, model, trains, margin, weights)
    seeds, metrics, test_sets = _within_trial(pool, model, split, fitters, robot.paper_views, progress)
    sheets = nominal_models(robot, reference)
    by_trial: dict[str, dict[str, dict[str, list[float]]]] = {}
    if test_pool is not None:
        metrics["cross_trial"], by_trial = _cross_trial(test_pool, tests, model, fits, sheets)
    _score_nominal(metrics, test_sets, sheets)
    sources = {"train": pool.source, **({"unseen": test_pool.source} if test_pool is not None else {})}
    trust = _trust(choice, overlap, model, fits, sheets[f"datasheet_{robot.datasheet}"], robot.joint_names)
    drives = _drive_gains(problem, model, trains, trust)
    return Comparison(
        model,
        fits,
        sheets,
        metrics,
        seeds,
        robot.datasheet,
        robot.joint_names,
        sources,
        trust,
        by_trial,
        {"train": [d.source for d in trains], "test": [d.source for d in tests]},
        reference.label if reference is not None else None,
        tuple(robot.statement),
        choice.estimator,
        choice,
        drives,
    )
