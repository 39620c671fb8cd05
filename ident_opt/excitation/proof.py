"""Proof in the simulator that the designed excitations are worth running (`make excitation`,
results/excitation.md).

For one duration and the problem's [limits], the built-in simulator follows each trajectory (`simulate
--trajectory-file` for the designs) with the clean rigid truth (the datasheet read physically) and its
measurement noise, for `seeds` noise seeds each:

- identification: the D-optimal and cond-optimal designs against the MERIt-like trajectory (``tud01``: moves
  with rests, a new one per seed) and random Fourier trajectories (the simulator's ``fourier``, a new one per
  seed), all of the same duration. Per trial: cond and log det of the logged motion (`excitation.criteria`),
  and the median over parameters of |π̂ − π|/|π| for OLS and the constrained fit (`fitting.estimators`) of the
  nominal structure (`robot.PHYSICAL`, the simulator's `TRUTH_MODEL`).
- discrimination: the discriminating design against ``tud01``, with each of the two causes hidden in turn
  where the data put it (the candidates fitted on the problem's trial: e.g. asymmetric Coulomb at the fitted
  per-direction levels, elasticity at the fitted joint, mode and damping). Each seed simulates a training and a held-out
  trial (noise seeds s and s + 1000), `diagnose` scores every candidate, and the margin is the true cause's
  score minus the other's. At two noise levels: the simulator's own (the sensor noise measured
  on the real robot at rest), and the level the design was planned for — the real trial's residual as the
  diagnosis weighs it (the rigid refit's residual σ after the torque filter, `discrimination.fit_rivals`), the
  noise scaled per joint until a clean simulated trial shows that residual (`residual_noise_scale`). At the
  simulator's noise the scores are log-saturated (ln(1 + LOF/(nσ²)) with LOF ≫ nσ²); at the real residual
  level they grow with the lack of fit, as on the real robot. Beside each margin, the design's own criterion
  on the same logged motion (`discrimination.expected_gaps` at the real residual level: the score gap the design
  expects), so the criterion is checked against the diagnosis it stands for.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from ident_opt.arm.planar import PHYSICAL
from ident_opt.data.dataset import Dataset
from ident_opt.diagnosis.planar.engine import weights_of
from ident_opt.diagnosis.rounds import diagnose_trial
from ident_opt.diagnosis.split import at_rest, prepare
from ident_opt.effects import CATALOGUE
from ident_opt.excitation import design as excitation
from ident_opt.excitation import discrimination
from ident_opt.excitation.design import Design
from ident_opt.excitation.setup import Setup, make_setup
from ident_opt.fitting import estimators
from ident_opt.fitting.stats import Stats
from ident_opt.numerics.signals import REST_WINDOW_S, TORQUE_FILTER_HZ
from ident_opt.problem.spec import Problem
from ident_opt.simulator import simulate_trial
from ident_opt.simulator.fourier import default_base_hz
from ident_opt.simulator.trial import MAX_NOISE_SCALE

#: Trajectory kinds of the identification part, in table order: label -> a design name or a simulator reference.
IDENTIFICATION = {
    "D-optimal design": "d",
    "cond-optimal design": "cond",
    "MERIt-like (tud01)": "tud01",
    "random Fourier": "fourier",
}
#: The trajectory the optimal designs are measured against.
BASELINE = "MERIt-like (tud01)"
#: Offset of the held-out trial's noise seed.
HELD_OUT = 1000


@dataclass
class Proof:
    """Everything the report needs: the designs, one row per identification trial and per diagnosis."""

    duration: float
    seeds: int
    between: tuple[str, str]
    hidden: dict[str, str]
    designs: dict[str, Design]
    setup: Setup
    disc_setup: Setup
    identification: pd.DataFrame
    discrimination: pd.DataFrame
    seconds: dict[str, float] = field(default_factory=dict)
    #: The torque noise's σ per joint as a multiple of the simulator's, per noise level.
    noise_scales: dict[str, list[float]] = field(default_factory=dict)

    def identification_summary(self) -> pd.DataFrame:
        """Per trajectory kind: medians over the seeds (cond, log det, the two parameter errors)."""
        cols = [c for c in self.identification.columns if c not in ("trajectory", "seed")]
        return self.identification.groupby("trajectory", sort=False)[cols].median()

    def improvement(self) -> dict[str, dict[str, float]]:
        """Per design and error column: the MERIt-like trajectory's median error ÷ the design's."""
        s = self.identification_summary()
        errors = [c for c in s.columns if c.startswith("error_")]
        return {
            label: {c.removeprefix("error_"): float(s.loc[BASELINE, c] / s.loc[label, c]) for c in errors}
            for label in ("D-optimal design", "cond-optimal design")
        }

    def discrimination_summary(self) -> pd.DataFrame:
        """Per noise level, true cause and trajectory: median margin, its range, how often the true cause was
        named."""
        g = self.discrimination.groupby(["noise", "true cause", "trajectory"], sort=False)
        return pd.DataFrame(
            {
                "median margin": g["margin"].median(),
                "min margin": g["margin"].min(),
                "max margin": g["margin"].max(),
                "named right": g["named right"].mean(),
                "median criterion": g["criterion"].median(),
            }
        )

    def gap_ratio(self) -> dict[str, dict[str, float]]:
        """Per noise level and true cause: the discriminating design's median margin ÷ the MERIt-like one's."""
        s = self.discrimination_summary()["median margin"]
        levels = self.discrimination["noise"].unique()
        return {
            level: {
                cause: float(s.loc[(level, cause, "discriminating design")] / s.loc[(level, cause, BASELINE)])
                for cause in self.between
            }
            for level in levels
        }


def median_relative_error(pi_hat: np.ndarray, pi_true: np.ndarray) -> float:
    """Median over parameters of |π̂ − π| / |π| (parameters with π = 0 left out)."""
    keep = np.abs(pi_true) > 0
    return float(np.median(np.abs(pi_hat[keep] - pi_true[keep]) / np.abs(pi_true[keep])))


def identification_row(setup: Setup, ds: Dataset, pi_true: np.ndarray) -> dict:
    """cond, log det and both estimators' median relative error on one simulated trial, as logged and with the
    velocities of resting joints read as 0 (`data.dataset.at_rest`: at rest the sign of an estimated
    velocity is noise, and the Coulomb columns would carry it)."""
    row = {k: v for k, v in excitation.criteria(setup, ds.q, ds.dq, ds.ddq).items() if k != "rank"}
    for suffix, d in (("", ds), (" (rests 0)", at_rest(ds, REST_WINDOW_S))):
        stats = Stats.from_data(PHYSICAL, d.q, d.dq, d.ddq, d.tau)
        for name in ("ols", "constrained"):
            row[f"error_{name}{suffix}"] = median_relative_error(estimators.fit(name, stats, PHYSICAL).pi, pi_true)
    return row


def _write_design(d: Design, folder: Path, name: str) -> str:
    """The design as a trajectory file the simulator follows (t, q, dq, ddq); returns its path."""
    path = folder / f"{name}.csv"
    cols = {
        "t": d.t,
        **{f"{k}{j + 1}": v[:, j] for k, v in (("q", d.q), ("dq", d.dq), ("ddq", d.ddq)) for j in range(2)},
    }
    pd.DataFrame(cols).to_csv(path, index=False, float_format="%.12g")
    return str(path)


def run(
    problem: Problem,
    trial: Dataset,
    *,
    duration: float = 20.0,
    seeds: int = 10,
    between: str = "asymmetric_coulomb,elasticity",
    starts: int = 6,
    progress: bool = True,
    designs: dict[str, Design] | None = None,
    workers: int = 1,
) -> Proof:
    """Design (unless `designs` are given: "d", "cond", "discriminate"; `workers`: processes running each design's
    starts), then simulate and score (module doc)."""
    t0 = time.perf_counter()
    causes = discrimination.parse_between(between)
    setup = make_setup(problem.robot, problem.limits, duration, trial=trial)
    disc_setup = make_setup(
        problem.robot,
        problem.limits,
        duration,
        harmonics=discrimination.HARMONICS,
        base_hz=default_base_hz(duration, discrimination.BASE_HZ),
        trial=trial,
    )
    if designs is None:
        designs = {
            c: excitation.design(setup, c, starts=starts, progress=progress, workers=workers) for c in ("d", "cond")
        }
        designs["discriminate"] = discrimination.design(
            disc_setup, problem.robot, trial, between, starts=max(1, starts // 2), progress=progress, workers=workers
        )
    t_design = time.perf_counter()
    hidden = _hidden(designs["discriminate"], causes)
    rivals = discrimination.fit_rivals(problem.robot, trial, causes)
    sigma = np.sqrt(1.0 / rivals.ctx.weights)  # the design's noise model: the real trial's residual
    scales = {"simulator": [1.0, 1.0], "real residual": residual_noise_scale(problem, sigma, duration)}
    with tempfile.TemporaryDirectory() as tmp:
        files = {name: _write_design(d, Path(tmp), name) for name, d in designs.items()}
        ident = _identification(problem, setup, files, duration, seeds, progress)
        t_ident = time.perf_counter()
        disc = _discrimination(problem, files["discriminate"], hidden, duration, seeds, scales, rivals, progress)
    t_end = time.perf_counter()
    return Proof(
        duration,
        seeds,
        causes,
        hidden,
        designs,
        setup,
        disc_setup,
        ident,
        disc,
        {"designs": t_design - t0, "identification": t_ident - t_design, "discrimination": t_end - t_ident},
        scales,
    )


def residual_sigma(problem: Problem, duration: float, scale: float | np.ndarray) -> np.ndarray:
    """σ_j [N m] of the rigid refit's residual as the diagnosis weighs it (`weights_of` after `prepare`'s
    torque filter) on a clean simulated MERIt-like trial (seed 0) with the torque noise scaled by
    `scale` (0: no sensor noise, the loop's and the derivative filter's own mismatch)."""
    sim = simulate_trial(
        problem.robot, trajectory="tud01", duration=duration, seed=0, noise_scale=scale, progress=False
    )
    weights = weights_of(prepare(sim.dataset(), TORQUE_FILTER_HZ))
    return np.sqrt(1.0 / weights)


def residual_noise_scale(problem: Problem, sigma: np.ndarray, duration: float) -> list[float]:
    """The noise scale per joint at which the diagnosis sees a residual σ of `sigma` [N m] per joint: the
    residual's variance is the mismatch's (scale 0) plus the scale² times the noise's (scale 1 minus scale 0)."""
    base, unit = residual_sigma(problem, duration, 0.0), residual_sigma(problem, duration, 1.0)
    noise2 = np.maximum(unit**2 - base**2, 1e-12)
    scale = np.sqrt(np.maximum(sigma**2 - base**2, 0.0) / noise2)
    return np.clip(scale, 0.0, MAX_NOISE_SCALE).tolist()


def _hidden(design: Design, causes: tuple[str, str]) -> dict[str, str]:
    """The effect string the simulator hides for each cause: where the data put it (the candidate's estimate and
    searched parameters, in the effect's own keys), so the simulated trials hold the two causes the diagnosis of
    the real data could not separate well."""
    out = {}
    for cause in causes:
        fitted = design.discrimination["candidates"][cause] if design.discrimination else {}
        values = {**fitted.get("estimate", {}), **fitted.get("theta", {})}
        keys = [f"{k}={_text(v)}" for k, v in values.items() if k in CATALOGUE[cause].keys]
        out[cause] = cause + (":" + ",".join(keys) if keys else "")
    return out


def _text(value) -> str:
    """A value in the effect syntax: a number, or a bracketed pair."""
    if isinstance(value, list | tuple):
        return "[" + ",".join(f"{float(v):.6g}" for v in value) + "]"
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def _identification(
    problem: Problem, setup: Setup, files: dict[str, str], duration: float, seeds: int, progress: bool
) -> pd.DataFrame:
    rows = []
    jobs = [(label, kind, s) for label, kind in IDENTIFICATION.items() for s in range(seeds)]
    for label, kind, seed in tqdm(jobs, desc="excitation: identification trials", disable=not progress, leave=False):
        sim = simulate_trial(
            problem.robot, trajectory=files.get(kind, kind), duration=duration, seed=seed, progress=False
        )
        pi_true = PHYSICAL.vector(sim.truth["pi"])
        rows.append({"trajectory": label, "seed": seed, **identification_row(setup, sim.dataset(), pi_true)})
    return pd.DataFrame(rows)


def _discrimination(
    problem: Problem,
    design_file: str,
    hidden: dict[str, str],
    duration: float,
    seeds: int,
    scales: dict[str, list[float]],
    rivals: discrimination.Rivals,
    progress: bool,
) -> pd.DataFrame:
    rows, criterion = [], {}
    trajectories = {BASELINE: "tud01", "discriminating design": design_file}
    jobs = [(n, c, t, s) for n in scales for c in hidden for t in trajectories for s in range(seeds)]
    causes = list(hidden)
    for level, cause, label, seed in tqdm(jobs, desc="excitation: diagnoses", disable=not progress, leave=False):
        train, test = (
            simulate_trial(
                problem.robot,
                trajectory=trajectories[label],
                duration=duration,
                seed=s,
                effects=[hidden[cause]],
                progress=False,
                noise_scale=scales[level],
            ).dataset()
            for s in (seed, seed + HELD_OUT)
        )
        d = diagnose_trial(problem.robot, train, test, progress=False)
        scores = {c["cause"]: c["score"] for c in d.candidates}
        if (cause, label, seed) not in criterion:  # the same motion at every noise level
            motion = discrimination.trajectory_dataset(train.t, train.q, train.dq, train.ddq)
            gaps = discrimination.expected_gaps(rivals, motion)
            criterion[cause, label, seed] = gaps[f"gap_{cause}_true"]
        other = next(c for c in causes if c != cause)
        rows.append(
            {
                "noise": level,
                "true cause": cause,
                "trajectory": label,
                "seed": seed,
                "score true": scores.get(cause, float("nan")),
                "score other": scores.get(other, float("nan")),
                "margin": scores.get(cause, float("nan")) - scores.get(other, float("nan")),
                "named": d.cause,
                "named right": d.cause == cause,
                "criterion": criterion[cause, label, seed],
            }
        )
    return pd.DataFrame(rows)
