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

from ident_opt.consistency import sign_violations
from ident_opt.data import Dataset, chronological_split, shuffled_split
from ident_opt.identify import estimators
from ident_opt.identify.fit import LinearFit
from ident_opt.identify.nlp import fit_physical
from ident_opt.identify.stats import Stats
from ident_opt.metrics import all_metrics
from ident_opt.models import DATASHEETS, datasheet_model
from ident_opt.robot import RIGID, ArmModel
from ident_opt.studies import METRICS
from ident_opt.studies.seeds import FitFn, SplitResults, seed_study, split_fits


def fitted_estimators(robot, margin: float = 1e-6, weights: str | None = None) -> dict[str, FitFn]:
    """The fitted estimators by key: statistics + model → LinearFit (`weights`: None or "wls")."""
    return {
        "ols": partial(estimators.fit, "ols", weights=weights),
        "constrained": partial(estimators.fit, "constrained", margin=margin, weights=weights),
        "nlp_physical": lambda st, m: fit_physical(st, robot, m, weights=weights),
    }


def datasheet_models(robot) -> dict[str, tuple[ArmModel, np.ndarray]]:
    """The datasheet under both conventions (`models.DATASHEETS`), each with the arm it is evaluated with:
    "datasheet_<convention>" -> (arm, π)."""
    out = {}
    for convention in DATASHEETS:
        model = datasheet_model(robot, convention)
        out[f"datasheet_{convention}"] = (model.arm, model.pi)
    return out


PROTOCOLS = {
    "paper": "shuffled 70/30, mean over the paper's seeds (flattering: test samples have near-copies in training)",
    "chronological": "first 70 % of the trial in time trains, the rest tests (honest within one trial)",
    "cross_trial": "identify on the whole first trial, test on the second, unseen trial",
}


@dataclass
class Comparison:
    """Everything `ident-opt compare` reports. `fits` are on the whole identification trial; `metrics` is
    {protocol: {metric: {estimator: [joint 1, joint 2]}}}; `seeds` is the paper's seed study."""

    model: ArmModel
    fits: dict[str, LinearFit]
    datasheets: dict[str, tuple[ArmModel, np.ndarray]]
    metrics: dict[str, dict[str, dict[str, list[float]]]]
    seeds: SplitResults
    convention: str
    sources: dict[str, str] = field(default_factory=dict)  # "train", "unseen" -> the trial's file

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


def _scores(datasets: list[tuple[Dataset, np.ndarray]], model: ArmModel, pi: np.ndarray) -> dict[str, list]:
    """Metrics of a fixed π on (dataset, test index) pairs, averaged over the pairs."""
    per = [all_metrics(d.tau[idx], model.predict(pi, d.q[idx], d.dq[idx], d.ddq[idx])) for d, idx in datasets]
    return {m: [float(np.mean([p[m][j] for p in per])) for j in range(2)] for m in METRICS}


def compare_estimators(
    train: Dataset,
    robot,
    split,
    unseen: Dataset | None = None,
    *,
    model: ArmModel | None = None,
    margin: float = 1e-6,
    weights: str | None = None,
    progress: bool = True,
) -> Comparison:
    """Fit every estimator, score it on the paper's shuffled protocol, the chronological split and (when
    `unseen` is given) the unseen trial; score both datasheets on the same test samples. `weights`:
    None (plain least squares) or "wls" (joints weighted by 1/σ_j², estimated per fit)."""
    model = model or RIGID
    fitters = fitted_estimators(robot, margin, weights)
    whole = Stats.from_data(model, train.q, train.dq, train.ddq, train.tau)
    fits = {key: fn(whole, model) for key, fn in fitters.items()}
    seeds = seed_study(train, model, split, fitters, progress=progress)
    metrics: dict[str, dict[str, dict[str, list[float]]]] = {p: {m: {} for m in METRICS} for p in PROTOCOLS}
    for m in METRICS:
        metrics["paper"][m].update(seeds.mean(m))
    chrono = chronological_split(train.n, split.train_fraction)
    chrono_res = split_fits(train, model, [chrono], fitters)
    for m in METRICS:
        metrics["chronological"][m].update(chrono_res.mean(m))
    test_sets = {
        "paper": [(train, shuffled_split(train.n, split.train_fraction, s)[1]) for s in split.seeds],
        "chronological": [(train, chrono[1])],
    }
    if unseen is not None:
        Y = model.regressor(unseen.q, unseen.dq, unseen.ddq)
        for key, fit in fits.items():
            for m, v in all_metrics(unseen.tau, Y @ fit.pi).items():
                metrics["cross_trial"][m][key] = v
        test_sets["cross_trial"] = [(unseen, np.arange(unseen.n))]
    else:
        metrics.pop("cross_trial")
    sheets = datasheet_models(robot)
    for protocol, pairs in test_sets.items():
        for key, (sheet_model, pi) in sheets.items():
            for m, v in _scores(pairs, sheet_model, pi).items():
                metrics[protocol][m][key] = v
    sources = {"train": train.source, **({"unseen": unseen.source} if unseen is not None else {})}
    return Comparison(model, fits, sheets, metrics, seeds, robot.convention, sources)
