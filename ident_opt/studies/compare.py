"""Side by side: the datasheet (both conventions), OLS, the constrained fit and the NLP on physical parameters.

`compare_estimators` returns the parameters (values ± SE, physical consistency) and the held-out errors per
joint on the paper's shuffled protocol, the chronological split and the unseen trial. Every estimator is
fitted from sufficient statistics of the training samples only; the datasheets are scored on the same test
samples. `ident_opt.report.compare` writes it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial

import numpy as np

from ident_opt.arm.planar import RIGID, PlanarArm
from ident_opt.consistency import sign_violations
from ident_opt.data import Dataset, chronological_split, concat, shuffled_split
from ident_opt.errors import InputError
from ident_opt.identify import estimators
from ident_opt.identify.fit import LinearFit
from ident_opt.identify.nlp import fit_physical
from ident_opt.metrics import all_metrics
from ident_opt.models import DATASHEETS, datasheet_model
from ident_opt.studies import METRICS
from ident_opt.studies.seeds import FitFn, SplitResults, seed_study, split_fits
from ident_opt.studies.trust import Trust, checks, iv_fit, stats_of


def fitted_estimators(robot, margin: float = 1e-6, weights: str | None = None) -> dict[str, FitFn]:
    """The fitted estimators by key: statistics + model → LinearFit (`weights`: None or "wls")."""
    return {
        "ols": partial(estimators.fit, "ols", weights=weights),
        "constrained": partial(estimators.fit, "constrained", margin=margin, weights=weights),
        "nlp_physical": lambda st, m: fit_physical(st, robot, m, weights=weights),
    }


def datasheet_models(robot) -> dict[str, tuple[PlanarArm, np.ndarray]]:
    """The datasheet under both conventions (`models.DATASHEETS`), each with the arm it is evaluated with:
    "datasheet_<convention>" -> (arm, π)."""
    out = {}
    for convention in DATASHEETS:
        model = datasheet_model(robot, convention)
        out[f"datasheet_{convention}"] = (model.arm, model.pi)
    return out


def default_model(robot) -> tuple[PlanarArm, str | None]:
    """(The model `compare` fits when no --extension is given, why, or None for the plain rigid model).

    A robot described by its inertials with a reflected rotor inertia on a joint (a geared drive) carries
    that inertia on the diagonal of M: the model then frees it (`armature`, ia2 apart from α1) instead of
    folding a wrong fixed value into the other parameters. Bars-and-cylinder datasheets (the paper's form)
    keep the paper's rigid model."""
    if robot.description == "inertials" and any(j.rotor_inertia > 0 for j in robot.joints):
        return PlanarArm(("armature",)), "armature, as the robot states a rotor inertia behind a gear"
    return RIGID, None


def reference_model(reference) -> tuple[PlanarArm, np.ndarray]:
    """A problem's `[reference]` (a published identification) as (arm, π): the armature extension when it
    names ia2; an unknown parameter name is an InputError naming it."""
    model = PlanarArm(("armature",)) if "ia2" in reference.parameters else RIGID
    unknown = [k for k in reference.parameters if k not in model.names]
    if unknown:
        raise InputError(f"[reference.parameters]: unknown parameter '{unknown[0]}'; known: {', '.join(model.names)}")
    return model, model.vector(reference.parameters)


PROTOCOLS = {
    "paper": "shuffled 70/30, mean over the paper's seeds (flattering: test samples have near-copies in training)",
    "chronological": "first 70 % of the (pooled) training samples in time trains, the rest tests",
    "cross_trial": "identify on all training trials, test on the held-out trial(s), pooled",
}


@dataclass
class Comparison:
    """Everything `ident-opt compare` reports. `fits` are on the whole identification trial; `metrics` is
    {protocol: {metric: {estimator: [joint 1, joint 2]}}}; `seeds` is the paper's seed study."""

    model: PlanarArm
    fits: dict[str, LinearFit]
    datasheets: dict[str, tuple[PlanarArm, np.ndarray]]
    metrics: dict[str, dict[str, dict[str, list[float]]]]
    seeds: SplitResults
    convention: str
    sources: dict[str, str] = field(default_factory=dict)  # "train", "unseen" -> the trial's file
    trust: Trust = field(default_factory=Trust)  # the checks behind the warnings (`studies.trust`)
    #: per held-out trial: {file: {metric: {estimator: [joint 1, joint 2]}}} (when there are several)
    by_test_trial: dict[str, dict[str, dict[str, list[float]]]] = field(default_factory=dict)
    trials: dict[str, list[str]] = field(default_factory=dict)  # "train", "test" -> files
    reference_label: str | None = None  # the `[reference]`'s label, keyed "reference"
    #: what the tool applied to read the robot (a URDF arm's angle offsets and signs, `UrdfPlanarRobot.statement`)
    robot_statement: tuple[str, ...] = ()

    def parameters(self) -> dict[str, dict[str, float]]:
        """π by estimator: "datasheet" (the problem's convention), both datasheets, and every fit."""
        out = {key: model.as_dict(pi) for key, (model, pi) in self.datasheets.items()}
        out = {"datasheet": out[f"datasheet_{self.convention}"], **out}
        out.update({key: fit.as_dict() for key, fit in self.fits.items()})
        return out

    def consistency(self) -> dict[str, dict]:
        """Physical consistency of each parameter set: M(q) margin [kg m²], friction signs, verdict (which
        also requires armature ≥ 0)."""
        out = {}
        for key, (model, pi) in self.datasheets.items():
            wrong_sign = sign_violations(model.parameters, pi)
            eig = model.min_mass_eigenvalue(pi)
            out[key] = {
                "min_mass_eigenvalue": eig,
                "friction_nonnegative": "friction" not in wrong_sign,
                "consistent": bool(eig > 0 and not wrong_sign),
                "active_constraints": [],
            }
        for key, fit in self.fits.items():
            out[key] = {
                "min_mass_eigenvalue": fit.min_mass_eigenvalue,
                "friction_nonnegative": fit.friction_ok,
                "consistent": fit.consistent,
                "active_constraints": fit.active,
            }
        return out


def _scores(datasets: list[tuple[Dataset, np.ndarray]], model: PlanarArm, pi: np.ndarray) -> dict[str, list]:
    """Metrics of a fixed π on (dataset, test index) pairs, averaged over the pairs."""
    per = [all_metrics(d.tau[idx], model.predict(pi, d.q[idx], d.dq[idx], d.ddq[idx])) for d, idx in datasets]
    return {m: [float(np.mean([p[m][j] for p in per])) for j in range(2)] for m in METRICS}


def _held_out(d: Dataset, scored: dict[str, tuple[PlanarArm, np.ndarray]]) -> dict[str, dict[str, list[float]]]:
    """{metric: {key: [joint 1, joint 2]}} of each fixed (arm, π) on every sample of `d` (measured τ)."""
    out: dict[str, dict[str, list[float]]] = {m: {} for m in METRICS}
    for key, (arm, pi) in scored.items():
        for m, v in all_metrics(d.tau, arm.predict(pi, d.q, d.dq, d.ddq)).items():
            out[m][key] = v
    return out


def _as_list(trials: Dataset | list[Dataset] | None) -> list[Dataset]:
    if trials is None:
        return []
    return [trials] if isinstance(trials, Dataset) else list(trials)


def compare_estimators(
    train: Dataset | list[Dataset],
    robot,
    split,
    unseen: Dataset | list[Dataset] | None = None,
    *,
    model: PlanarArm | None = None,
    margin: float = 1e-6,
    weights: str | None = None,
    progress: bool = True,
    reference=None,
    conversions: dict[str, tuple[float, float]] | None = None,
) -> Comparison:
    """Fit every estimator on all training trials (statistics add up; IV beside them), score it on the paper's
    shuffled protocol and the chronological split of the pooled training samples and (when held-out trials are
    given) on each held-out trial and their pool; score both datasheets (and the problem's `[reference]`) on
    the same test samples; run the trust checks (`studies.trust`). `weights`: None (plain least squares) or
    "wls" (joints weighted by 1/σ_j², estimated per fit). Fits use the torque filtered like the regressor's
    inputs (`Dataset.tau_fit`); every score is against the measured torque."""
    model = model or RIGID
    trains, tests = _as_list(train), _as_list(unseen)
    pool, test_pool = concat(trains), (concat(tests) if tests else None)
    fitters = fitted_estimators(robot, margin, weights)
    whole = stats_of(model, trains)
    fits = {key: fn(whole, model) for key, fn in fitters.items()}
    fits["iv"] = iv_fit(model, trains)
    seeds = seed_study(pool, model, split, fitters, progress=progress)
    metrics: dict[str, dict[str, dict[str, list[float]]]] = {p: {m: {} for m in METRICS} for p in PROTOCOLS}
    for m in METRICS:
        metrics["paper"][m].update(seeds.mean(m))
    chrono = chronological_split(pool.n, split.train_fraction)
    chrono_res = split_fits(pool, model, [chrono], fitters)
    for m in METRICS:
        metrics["chronological"][m].update(chrono_res.mean(m))
    test_sets = {
        "paper": [(pool, shuffled_split(pool.n, split.train_fraction, s)[1]) for s in split.seeds],
        "chronological": [(pool, chrono[1])],
    }
    sheets = datasheet_models(robot)
    if reference is not None:
        sheets["reference"] = reference_model(reference)
    by_trial: dict[str, dict[str, dict[str, list[float]]]] = {}
    if test_pool is not None:
        scored = {**{k: (model, f.pi) for k, f in fits.items()}, **sheets}
        metrics["cross_trial"] = _held_out(test_pool, scored)
        by_trial = {d.source: _held_out(d, scored) for d in tests} if len(tests) > 1 else {}
    else:
        metrics.pop("cross_trial")
    for protocol, pairs in test_sets.items():
        for key, (sheet_model, pi) in sheets.items():
            for m, v in _scores(pairs, sheet_model, pi).items():
                metrics[protocol][m][key] = v
    sources = {"train": pool.source, **({"unseen": test_pool.source} if test_pool is not None else {})}
    trust = checks(model, trains, fits["ols"], fits["iv"], conversions)
    trials = {"train": [d.source for d in trains], "test": [d.source for d in tests]}
    label = reference.label if reference is not None else None
    statement = tuple(getattr(robot, "statement", ()))  # a URDF arm's: the angle offsets applied to its data
    return Comparison(
        model, fits, sheets, metrics, seeds, robot.convention, sources, trust, by_trial, trials, label, statement
    )
