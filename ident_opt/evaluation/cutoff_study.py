"""Where the derivative cut-off rule and the recommended fit stand: a study in simulation, whose truth is known.

For each condition (kind of motion × sampling rate × noise factor, `evaluation.cutoff_plant`) and seed, one 20 s trial
of a two-link arm under gravity is simulated, written as a CSV of t, q, τ and read back by the loader like any
log. Then:

- **recommended**: the default pipeline — `derivative_cutoff_hz = "auto"` (`derivatives.cutoff_choice`) and the
  recommended fit (`fitting.recommend`);
- **auto**: the arm's consistent fit at the auto cut-off (what the recommendation starts from);
- **hindsight**: the consistent fit with the trial read at each cut-off of a grid (0.5 Hz to a quarter of the
  rate, `GRID` points), and the best of them knowing the truth: per trial (the luckiest cut-off for that noise
  draw) and per condition (the one cut-off best across the condition's seeds);
- **cross-validated hindsight**: what a rule that knew the condition, but not the trial, could reach: for each
  seed, the grid cut-off best over the condition's *other* seeds, scored on that seed (`cross_validated_best`).
  The per-condition best is the least of `GRID` noisy medians, chosen on the very trials it is scored on, so it is
  luckier than any rule; this one is not, and says how much of a ratio to it is that luck.

The error of a fit is the median over the inertial, coupling and gravity parameters of |π̂ − π|/|π|: friction
depends on how the plant's stiction is modelled near zero speed, which no cut-off decides (its error is reported
beside, over every parameter). Standard errors are judged too: the share of those parameters within 2 SE of the
truth (`covered`).
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ident_opt.data.loader import load_dataset
from ident_opt.evaluation.cutoff_plant import KINDS, Condition, simulate
from ident_opt.fitting import estimators
from ident_opt.fitting.recommend import choose
from ident_opt.fitting.trust import JUDGED_KINDS
from ident_opt.problem.spec import DataSpec

RATES = (100.0, 250.0, 500.0, 1000.0)
NOISES = (0.5, 1.0, 3.0)
#: Seeds used while developing the rule, seeds looked at only for a final table (since stop 33), and a larger set
#: run once, after the cross-validated yardstick was added and with the rule unchanged.
TUNING_SEEDS = (0, 1, 2)
UNSEEN_SEEDS = (1000, 1001, 1002)
FRESH_SEEDS = tuple(range(2000, 2010))
SEED_SETS = {"tuning": TUNING_SEEDS, "unseen": UNSEEN_SEEDS, "fresh": FRESH_SEEDS}
#: Cut-offs of the hindsight grid (log-spaced from 0.5 Hz to a quarter of the rate).
GRID = 12
#: The truth's friction [N m s/rad, N m]: the nominal arm's, made large enough to matter.
FRICTION = {"fv1": 0.02, "fv2": 0.015, "fc1": 0.09, "fc2": 0.08}


@dataclass
class Row:
    """One trial's outcome: the condition and seed, the auto cut-off [Hz], the recommended estimator, and the
    errors (median relative, judged parameters) of each way of fitting, with the per-trial best cut-off."""

    kind: str
    rate_hz: float
    noise: float
    seed: int
    cutoff_hz: float
    recommended: str
    error_recommended: float
    error_auto: float
    error_all_recommended: float  # over every parameter, friction included
    covered: float  # share of judged parameters within 2 SE of the truth (recommended fit)
    grid_hz: list[float]
    error_grid: list[float]

    @property
    def best_hz(self) -> float:
        """The per-trial best cut-off of the grid [Hz]."""
        return self.grid_hz[int(np.argmin(self.error_grid))]

    @property
    def error_best(self) -> float:
        """The per-trial best error on the grid."""
        return float(min(self.error_grid))


def truth(robot) -> tuple:
    """(arm, π): the robot's physical datasheet model with `FRICTION`."""
    arm, pi = robot.datasheets()["physical"]
    pi = np.array(pi, dtype=float)
    for name, value in FRICTION.items():
        pi[arm.names.index(name)] = value
    return arm, pi


def _error(arm, pi_hat: np.ndarray, pi: np.ndarray, judged: bool = True) -> float:
    index = [i for i, p in enumerate(arm.parameters) if p.kind in JUDGED_KINDS] if judged else range(len(pi))
    index = [i for i in index if pi[i] != 0]
    return float(np.median(np.abs(pi_hat[index] - pi[index]) / np.abs(pi[index])))


def _covered(arm, fit, pi: np.ndarray) -> float:
    index = [i for i, p in enumerate(arm.parameters) if p.kind in JUDGED_KINDS]
    se = np.asarray(fit.se)[index]
    ok = np.abs(fit.pi[index] - pi[index]) <= 2 * np.where(np.isfinite(se), se, 0.0)
    return float(np.mean(ok))


def run_trial(problem, condition: Condition, seed: int, folder: Path) -> Row:
    """One simulated trial through the loader, fitted every way of the module doc."""
    robot = problem.robot
    arm, pi = truth(robot)
    path = folder / f"{condition.kind}_{condition.rate_hz:g}_{condition.noise:g}_{seed}.csv"
    simulate(arm, pi, condition, seed).to_csv(path, index=False)
    spec = DataSpec(derivative_cutoff_hz="auto")
    # The plant writes SI units: a passive link that goes over the top and spins on (|q| past 100 rad on fresh seed
    # 2003) is motion, not the unit mistake the loader's plausibility check is there to catch.
    trial = load_dataset(path, spec, robot, allow_implausible=True)
    auto_problem = replace(problem, data=spec)
    found = choose(auto_problem, [trial], model=arm)
    fit = found.fit(robot, arm, [trial])
    consistent = robot.default_estimator
    auto = estimators.fit_for(robot, consistent, estimators.statistics(arm, [trial], consistent), arm)
    grid = np.geomspace(0.5, condition.rate_hz / 4, GRID)
    errors = []
    for cutoff in grid:
        at = load_dataset(path, DataSpec(derivative_cutoff_hz=float(cutoff)), robot, allow_implausible=True)
        fitted = estimators.fit_for(robot, consistent, estimators.statistics(arm, [at], consistent), arm)
        errors.append(_error(arm, fitted.pi, pi))
    return Row(
        condition.kind,
        condition.rate_hz,
        condition.noise,
        seed,
        float(trial.cutoff_hz),
        found.estimator,
        _error(arm, fit.pi, pi),
        _error(arm, auto.pi, pi),
        _error(arm, fit.pi, pi, judged=False),
        _covered(arm, fit, pi),
        [float(c) for c in grid],
        errors,
    )


def run(
    problem,
    seeds: tuple[int, ...] = TUNING_SEEDS,
    kinds: tuple[str, ...] = KINDS,
    rates: tuple[float, ...] = RATES,
    noises: tuple[float, ...] = NOISES,
    progress: bool = True,
) -> list[Row]:
    """Every condition × seed (module doc), in a temporary folder."""
    cells = [(Condition(k, r, n), s) for k in kinds for r in rates for n in noises for s in seeds]
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for condition, seed in tqdm(cells, desc="cut-off study", disable=not progress):
            rows.append(run_trial(problem, condition, seed, Path(folder)))
    return rows


def cross_validated_best(grid_errors: np.ndarray) -> float:
    """The hindsight best of a rule that knows the condition but not the trial (module doc): for each seed (a row of
    `grid_errors`, seeds × grid cut-offs), the error at the grid cut-off whose median error over the other seeds is
    least; the median of those over seeds. NaN with fewer than two seeds."""
    n = len(grid_errors)
    if n < 2:
        return float("nan")
    picked = [grid_errors[i, np.argmin(np.median(np.delete(grid_errors, i, axis=0), axis=0))] for i in range(n)]
    return float(np.median(picked))


def summary(rows: list[Row]) -> list[dict]:
    """Per condition: medians over seeds of each error, the ratio of the recommended fit's to the per-trial,
    per-condition and cross-validated hindsight best, the recommended estimators and the coverage."""
    out = []
    keys = sorted({(r.kind, r.rate_hz, r.noise) for r in rows}, key=lambda k: (KINDS.index(k[0]), k[1], k[2]))
    for kind, rate, noise in keys:
        cell = [r for r in rows if (r.kind, r.rate_hz, r.noise) == (kind, rate, noise)]
        grid = np.array([r.error_grid for r in cell])
        per_condition = float(np.min(np.median(grid, axis=0)))
        rec = float(np.median([r.error_recommended for r in cell]))
        best = float(np.median([r.error_best for r in cell]))
        cv = cross_validated_best(grid)
        out.append(
            {
                "kind": kind,
                "rate_hz": rate,
                "noise": noise,
                "cutoff_hz": float(np.median([r.cutoff_hz for r in cell])),
                "best_hz": float(np.median([r.best_hz for r in cell])),
                "recommended": "/".join(sorted({r.recommended for r in cell})),
                "error_recommended": rec,
                "error_auto": float(np.median([r.error_auto for r in cell])),
                "error_best_per_trial": best,
                "error_best_per_condition": per_condition,
                "ratio_per_trial": rec / best if best > 0 else float("inf"),
                "ratio_per_condition": rec / per_condition if per_condition > 0 else float("inf"),
                "error_cross_validated": cv,
                # the yardstick's own luck: how far a rule that knew the condition stays from the per-condition best
                "ratio_cross_validated_to_best": cv / per_condition if per_condition > 0 else float("inf"),
                "ratio_to_cross_validated": rec / cv if cv > 0 else float("nan"),
                "error_all_recommended": float(np.median([r.error_all_recommended for r in cell])),
                "covered": float(np.mean([r.covered for r in cell])),
            }
        )
    return out
