"""Evaluation protocols: fit every model on a training part, score it on a held-out part.

- ``paper``: shuffle the samples, train on 70 %, test on the other 30 %, for each of the paper's 10 seeds;
  metrics are the mean over seeds. At 100 Hz every test sample has near-copies in the training set, so
  this flatters local models (GMR most of all); it is here for comparability with the paper.
- ``chronological``: the first 70 % of the trial in time trains, the rest tests (the honest number within
  one trial).
- ``cross_trial``: identify on the whole first trial, evaluate on a second, unseen trial.

When the number of GMR components is "auto", the validation data that choose it mirror the protocol: a
random quarter of the training part under the paper's protocol, the latest quarter in time under the
honest ones (a random quarter there would have near-copies in the rest and always favour the most
components, which then do worse on later motions).

Metrics per joint (see `ident_opt.metrics`): ``rmse`` [N m], ``nmse`` (÷ variance), ``nmse_range``
(÷ range², the paper's), and for `+gmr` models ``coverage``: the fraction of test torques inside the 95 %
predictive interval.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from ident_opt.data.dataset import Dataset, chronological_split, shuffled_split
from ident_opt.fitting.recommend import Choice
from ident_opt.metrics import METRICS, all_metrics, coverage
from ident_opt.models.hybrid import HybridModel, make_gmr, parametric_models
from ident_opt.problem.spec import Problem


@dataclass
class SplitResult:
    """Every model fitted on one training part and scored on one test part."""

    test: Dataset
    models: dict[str, object]  # key -> fitted model (parametric and hybrid)
    predictions: dict[str, np.ndarray]  # key -> τ̂ on the test part (N, n) [N m]
    std: dict[str, np.ndarray]  # `+gmr` key -> predictive standard deviation (N, n) [N m]
    metrics: dict[str, dict[str, list[float]]]  # metric -> key -> [one value per joint]
    coverage: dict[str, list[float]]  # `+gmr` key -> [one value per joint]
    components: dict[str, int]  # `+gmr` key -> chosen number of mixture components
    train_fit: dict[str, list[float]]  # key -> training-data RMSE [N m] (hybrid never worse: checked in tests)


@dataclass
class ProtocolResult:
    """A protocol's outcome: metrics averaged over its splits, per-split RMSE, and one split kept whole."""

    name: str
    description: str
    metrics: dict[str, dict[str, list[float]]]
    coverage: dict[str, list[float]]
    components: dict[str, int]
    rmse_per_split: dict[str, list[list[float]]] = field(default_factory=dict)
    params_per_split: dict[str, list[dict[str, float]]] = field(default_factory=dict)
    example: SplitResult | None = None  # the first split, for figures

    def as_json(self) -> dict:
        """The spec's shape: metric -> key -> [one value per joint], plus coverage and the chosen components."""
        out: dict = {m: self.metrics[m] for m in METRICS}
        out["coverage"] = self.coverage
        out["gmr_components"] = self.components
        return out


def evaluate_split(
    train: Dataset,
    test: Dataset,
    problem: Problem,
    *,
    constrained: bool = True,
    components: dict[str, int] | None = None,
    covariance: str | None = None,
    random_state: int = 0,
    level: float = 0.95,
    validation: str = "random",
    choice: Choice | None = None,
) -> SplitResult:
    """Fit every parametric model and its `+gmr` hybrid on `train`; score all on `test`.

    components: `+gmr` key -> a fixed K (else the problem's `[residual]` setting, "auto" = chosen on
    validation data inside the training part: `validation` "random" or "blocked", the latest samples). `choice`: the
    fit cpbr is (`fitting.recommend.Choice`; None: the arm's physically consistent fit).
    """
    # The matrices here are small (N × 8, K ≤ 20): BLAS threads only add overhead, and on a busy machine
    # they oversubscribe the cores (measured: a 10-component fit 0.14 s single-threaded, 1–5 s threaded).
    with threadpool_limits(limits=1):
        return _evaluate_split(
            train, test, problem, constrained, components, covariance, random_state, level, validation, choice
        )


def _evaluate_split(train, test, problem, constrained, components, covariance, random_state, level, validation, choice):
    models: dict[str, object] = {}
    for base in parametric_models(problem.robot, constrained, choice.estimator if choice is not None else None):
        base.fit(train)
        models[base.key] = base
        k = (components or {}).get(base.key + "+gmr")
        hybrid = HybridModel(base, make_gmr(problem.residual, k, covariance, random_state, validation))
        models[hybrid.key] = hybrid.fit(train, fit_base=False)
    predictions, std, cover, chosen, train_fit = {}, {}, {}, {}, {}
    for key, model in models.items():
        train_fit[key] = [float(v) for v in np.sqrt(np.mean((train.tau - model.predict(train)) ** 2, axis=0))]
        if isinstance(model, HybridModel):
            predictions[key], std[key] = model.predict_interval(test)
            cover[key] = [float(v) for v in coverage(test.tau, predictions[key], std[key], level)]
            chosen[key] = int(model.gmr.n_components_)
        else:
            predictions[key] = model.predict(test)
    metrics: dict[str, dict[str, list[float]]] = {m: {} for m in METRICS}
    for key, pred in predictions.items():
        for m, values in all_metrics(test.tau, pred).items():
            metrics[m][key] = values
    return SplitResult(test, models, predictions, std, metrics, cover, chosen, train_fit)


def _mean_of(results: list[SplitResult]) -> tuple[dict, dict]:
    keys = results[0].metrics["rmse"].keys()
    metrics = {m: {k: np.mean([r.metrics[m][k] for r in results], axis=0).tolist() for k in keys} for m in METRICS}
    cover = {k: np.mean([r.coverage[k] for r in results], axis=0).tolist() for k in results[0].coverage}
    return metrics, cover


def _params(result: SplitResult) -> dict[str, dict[str, float]]:
    return {k: m.params() for k, m in result.models.items() if hasattr(m, "params") and m.estimator}


def paper_protocol(
    trial: Dataset,
    problem: Problem,
    *,
    constrained: bool = True,
    covariance: str | None = None,
    components: dict[str, int] | None = None,
    progress: Callable[[], None] | None = None,
    choice: Choice | None = None,
) -> ProtocolResult:
    """Shuffled 70/30 splits over the problem's seeds; the GMR components (`+gmr` key -> K, or chosen on the
    first seed when the problem says "auto") are kept for the other seeds, so every seed fits the same model."""
    results: list[SplitResult] = []
    for seed in problem.split.seeds:
        train, test = shuffled_split(trial.n, problem.split.train_fraction, seed)
        r = evaluate_split(
            trial.subset(train),
            trial.subset(test),
            problem,
            constrained=constrained,
            components=components,
            covariance=covariance,
            random_state=seed,
            choice=choice,
        )
        components = components or r.components
        results.append(r)
        if progress:
            progress()
    metrics, cover = _mean_of(results)
    per_seed = {k: [r.metrics["rmse"][k] for r in results] for k in results[0].metrics["rmse"]}
    params = {k: [_params(r)[k] for r in results] for k in _params(results[0])}
    desc = (
        f"shuffled {problem.split.train_fraction:.0%} / {1 - problem.split.train_fraction:.0%} split, "
        f"mean over {len(results)} seeds (the paper's protocol)"
    )
    return ProtocolResult("paper", desc, metrics, cover, components or {}, per_seed, params, results[0])


def chronological_protocol(
    trial: Dataset,
    problem: Problem,
    *,
    constrained: bool = True,
    progress: Callable[[], None] | None = None,
    choice: Choice | None = None,
) -> ProtocolResult:
    """The first `train_fraction` of the trial in time trains, the rest tests."""
    train, test = chronological_split(trial.n, problem.split.train_fraction)
    r = evaluate_split(
        trial.subset(train), trial.subset(test), problem, constrained=constrained, validation="blocked", choice=choice
    )
    if progress:
        progress()
    desc = (
        f"first {problem.split.train_fraction:.0%} of the trial in time trains, the last "
        f"{1 - problem.split.train_fraction:.0%} tests"
    )
    return ProtocolResult(
        "chronological",
        desc,
        r.metrics,
        r.coverage,
        r.components,
        {k: [v] for k, v in r.metrics["rmse"].items()},
        {},
        r,
    )


def cross_trial_protocol(
    trial: Dataset,
    unseen: Dataset,
    problem: Problem,
    *,
    constrained: bool = True,
    progress: Callable[[], None] | None = None,
    choice: Choice | None = None,
) -> ProtocolResult:
    """Identify on all of `trial`, evaluate on all of `unseen`."""
    r = evaluate_split(trial, unseen, problem, constrained=constrained, validation="blocked", choice=choice)
    if progress:
        progress()
    desc = f"identified on all of {_name(trial)}, evaluated on all of {_name(unseen)} (unseen trial)"
    return ProtocolResult(
        "cross_trial", desc, r.metrics, r.coverage, r.components, {k: [v] for k, v in r.metrics["rmse"].items()}, {}, r
    )


def _name(d: Dataset) -> str:
    return Path(d.source).name
