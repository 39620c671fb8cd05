"""The paper's seed study, and held-out evaluation of fitted estimators on any list of splits.

The paper shuffles the samples of one trial, trains on 70 % and tests on 30 %, for 10 seeds, and shows
the grouped parameters across seeds as a heatmap of their deviation from the mean, with the test RMSE's
mean and standard deviation. Shuffled splits of a densely sampled trial flatter every model (each test
sample has near-copies in training); the chronological split is the honest counterpart.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial

import numpy as np
import pandas as pd
from tqdm import tqdm

from ident_opt.arm.base import Arm
from ident_opt.data.dataset import Dataset, shuffled_split
from ident_opt.fitting import estimators
from ident_opt.fitting.fit import LinearFit
from ident_opt.fitting.iv import InstrumentStats
from ident_opt.fitting.stats import Stats
from ident_opt.metrics import METRICS, all_metrics

#: statistics (or instrument statistics, `fitting.estimators.fit`) + model -> fit.
FitFn = Callable[[Stats | InstrumentStats, Arm], LinearFit]


@dataclass
class SplitResults:
    """Per split s and estimator e: π (S, P) and held-out metrics {metric: (S, n)}, one column per joint."""

    names: tuple[str, ...]
    pi: dict[str, np.ndarray]
    metrics: dict[str, dict[str, np.ndarray]]
    consistent: dict[str, np.ndarray] = field(default_factory=dict)
    labels: list = field(default_factory=list)

    def mean(self, metric: str) -> dict[str, list[float]]:
        """Metric averaged over splits, per estimator and joint."""
        return {e: [float(v) for v in m[metric].mean(0)] for e, m in self.metrics.items()}

    def std(self, metric: str) -> dict[str, list[float]]:
        """Metric's standard deviation over splits (ddof = 1 when there are several)."""
        return {
            e: [float(v) for v in m[metric].std(0, ddof=1 if len(self.labels) > 1 else 0)]
            for e, m in self.metrics.items()
        }


def split_fits(
    dataset: Dataset,
    model: Arm,
    splits: Sequence[tuple[np.ndarray, np.ndarray]],
    fits: dict[str, FitFn],
    test: Dataset | None = None,
    labels: Sequence | None = None,
    progress: bool = False,
) -> SplitResults:
    """Fit each estimator on each split's training samples (from statistics) and score it on the test
    samples — or on `test` (another trial) when given. The regressor is built once for the whole trial; with the
    trial's instruments, each estimator gets `InstrumentStats` (`fitting.estimators.fit` takes what it needs)."""
    Y = model.regressor(dataset.q, dataset.dq, dataset.ddq)
    # The instruments' regressor too, so that estimators on instrumental variables fit the same splits.
    Z = None if dataset.instruments is None else model.regressor(dataset.q, *dataset.instruments)
    Y_other = model.regressor(test.q, test.dq, test.ddq) if test is not None else None
    S, P = len(splits), model.n_params
    pi = {e: np.zeros((S, P)) for e in fits}
    ok = {e: np.zeros(S, dtype=bool) for e in fits}
    metrics = {e: {m: np.zeros((S, model.n_joints)) for m in METRICS} for e in fits}
    for s, (train, held) in enumerate(tqdm(splits, desc="splits", disable=not progress)):
        if Z is None:
            stats = Stats.from_regressor(Y[train], dataset.tau[train])
        else:
            stats = InstrumentStats.from_regressors(Y[train], Z[train], dataset.tau[train])
        if test is None:
            Y_test, tau_test = Y[held], dataset.tau[held]
        else:
            Y_test, tau_test = Y_other, test.tau
        for e, fn in fits.items():
            fit = fn(stats, model)
            pi[e][s], ok[e][s] = fit.pi, fit.consistent
            for m, values in all_metrics(tau_test, Y_test @ fit.pi).items():
                metrics[e][m][s] = values
    return SplitResults(model.names, pi, metrics, ok, list(labels if labels is not None else range(S)))


def seed_study(
    dataset: Dataset, model: Arm, split, fits: dict[str, FitFn] | None = None, progress: bool = False
) -> SplitResults:
    """The paper's protocol: for each seed in `split.seeds`, a shuffled `split.train_fraction` split;
    `fits` default to OLS only. Returns parameters and held-out metrics per seed."""
    fits = fits or {"ols": partial(estimators.fit, "ols")}
    splits = [shuffled_split(dataset.n, split.train_fraction, seed) for seed in split.seeds]
    return split_fits(dataset, model, splits, fits, labels=list(split.seeds), progress=progress)


def rmse_table(study: SplitResults) -> pd.DataFrame:
    """Held-out RMSE [N m] mean and std over seeds, per estimator and joint (the paper's table form)."""
    rows = []
    for e in study.metrics:
        mean, std = study.mean("rmse")[e], study.std("rmse")[e]
        row = {"estimator": e}
        for j, (m, s) in enumerate(zip(mean, std), 1):
            row.update({f"rmse_j{j}_mean": m, f"rmse_j{j}_std": s})
        rows.append(row)
    return pd.DataFrame(rows).set_index("estimator")


def deviation_from_mean(study: SplitResults, estimator: str = "ols") -> pd.DataFrame:
    """(π_s − mean_s π) / |mean_s π| in %, seeds × parameters: how much a shuffle moves each parameter."""
    pi = study.pi[estimator]
    mean = pi.mean(0)
    dev = 100.0 * (pi - mean) / np.where(np.abs(mean) > 0, np.abs(mean), 1.0)
    return pd.DataFrame(dev, index=pd.Index(study.labels, name="seed"), columns=list(study.names))
