"""Where the physical-consistency constraints matter: OLS vs the constrained fit on many short, poorly
exciting trials with a known truth (how often OLS is inconsistent, whose parameters are closer to the truth),
and on trials that excite everything (the constraints should then cost nothing).

Both fits come from the sufficient statistics of each trial (`ident_opt.fitting.estimators`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from tqdm import tqdm

from ident_opt import simulator as simulate
from ident_opt.arm.datasheet import datasheet_pi
from ident_opt.arm.planar import PHYSICAL, PlanarArm
from ident_opt.data.dataset import Dataset
from ident_opt.fitting import estimators
from ident_opt.fitting.stats import Stats


def multisine_trial(
    model: PlanarArm,
    pi_true: np.ndarray,
    *,
    duration: float,
    rate_hz: float = 100.0,
    seed: int = 0,
    amplitude: tuple[float, float] = (0.6, 0.6),
    noise: tuple[float, float] = (0.5, 0.3),
    n_sines: int = 4,
    band_hz: tuple[float, float] = (0.1, 1.0),
) -> Dataset:
    """A rigid trial with known truth: q_j(t) = q0_j + Σ_k A_jk sin(2π f_k t + φ_jk) [rad], exact dq and ddq,
    τ = Y(q, dq, ddq) π_true + N(0, noise_j²) [N m]. Deterministic for a seed. A joint with amplitude 0
    stays still (its friction and inertia columns are then not excited)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 1.0 / rate_hz)
    q, dq, ddq = (np.zeros((len(t), 2)) for _ in range(3))
    for j in range(2):
        q[:, j] = rng.uniform(-np.pi / 2, np.pi / 2) if j == 0 else rng.uniform(-2.0, 2.0)
        if amplitude[j] == 0:
            continue
        f = rng.uniform(*band_hz, n_sines)
        a = amplitude[j] * rng.uniform(0.3, 1.0, n_sines) / n_sines
        phi = rng.uniform(0, 2 * np.pi, n_sines)
        arg = 2 * np.pi * f[None, :] * t[:, None] + phi[None, :]
        w = 2 * np.pi * f[None, :]
        q[:, j] += (a * np.sin(arg)).sum(1)
        dq[:, j] = (a * w * np.cos(arg)).sum(1)
        ddq[:, j] = -(a * w**2 * np.sin(arg)).sum(1)
    tau = model.predict(pi_true, q, dq, ddq) + rng.normal(size=(len(t), 2)) * np.asarray(noise)
    return Dataset(f"multisine(seed={seed}, {duration:.2f} s)", t, q, dq, ddq, tau, derivatives="exact")


def relative_error(pi_hat: np.ndarray, pi_true: np.ndarray) -> float:
    """RMS over parameters of (π̂_p − π_p)/|π_p|: a unit-free parameter error."""
    return float(np.sqrt(np.mean(((pi_hat - pi_true) / np.abs(pi_true)) ** 2)))


@dataclass
class StudyResult:
    """Per-trial results of `constraints_study` and its summary."""

    rows: pd.DataFrame
    settings: dict = field(default_factory=dict)

    @property
    def summary(self) -> dict:
        """Inconsistency rate of OLS, the constrained fit's, win rate and median error ratio."""
        r = self.rows
        differ = r["err_constrained"] != r["err_ols"]
        ratio = r["err_constrained"] / r["err_ols"]
        return {
            "trials": len(r),
            "ols_inconsistent": int((~r["ols_consistent"]).sum()),
            "constrained_inconsistent": int((~r["constrained_consistent"]).sum()),
            "fits_differ": int(differ.sum()),
            "constrained_wins": int((r["err_constrained"] < r["err_ols"]).sum()),
            "win_rate_where_differ": float((r["err_constrained"] < r["err_ols"])[differ].mean())
            if differ.any()
            else float("nan"),
            "median_error_ols": float(r["err_ols"].median()),
            "median_error_constrained": float(r["err_constrained"].median()),
            "median_error_ratio": float(ratio.median()),
            "median_error_ratio_where_differ": float(ratio[differ].median()) if differ.any() else float("nan"),
            "median_error_ols_excited": float(r["err_ols_excited"].median()),
            "median_error_constrained_excited": float(r["err_constrained_excited"].median()),
        }


STUDY_SOURCES = {
    "multisine": "a local rigid generator: one joint moves (multisine, alternating), the other is held still or "
    "moves ±0.05 rad; exact dq, ddq; Gaussian torque noise",
    "simulator": "the built-in simulator (`ident_opt.simulator`, no hidden effect): the first seconds of a "
    "tud01 point-to-point trial under closed-loop control, with its measurement noise, "
    "quantisation and estimated derivatives",
}


def _study_trial(
    source: str,
    robot,
    model: PlanarArm,
    pi_sheet: np.ndarray,
    i: int,
    duration: float,
    seed: int,
    noise: tuple[float, float],
    rate_hz: float,
) -> tuple[Dataset, np.ndarray, dict]:
    """Trial i of the constraints study: (data, true π, description columns)."""
    if source == "simulator":
        sim = simulate.simulate_trial(
            robot, trajectory="tud01", duration=duration, rate_hz=rate_hz, seed=seed * 100003 + i, progress=False
        )
        data = sim.dataset()
        moved = np.ptp(data.q, axis=0) > 0.05
        return (
            data,
            model.vector(sim.truth["pi"]),
            {"moving_joints": "".join(str(j + 1) for j in range(2) if moved[j]) or "none"},
        )
    moving = i % 2
    small = 0.0 if (i // 2) % 2 == 0 else 0.05
    amp = (0.8, small) if moving == 0 else (small, 0.8)
    data = multisine_trial(
        model, pi_sheet, duration=duration, rate_hz=rate_hz, seed=seed * 100003 + i, amplitude=amp, noise=noise
    )
    return data, pi_sheet, {"moving_joints": str(moving + 1), "other_amplitude": small}


def constraints_study(
    robot,
    n_trials: int = 50,
    *,
    source: str = "multisine",
    seed: int = 0,
    durations: tuple[float, float] = (2.0, 5.0),
    noise: tuple[float, float] = (0.5, 0.3),
    rate_hz: float = 100.0,
    margin: float = 1e-6,
    progress: bool = True,
) -> StudyResult:
    """OLS vs constrained on `n_trials` short, poorly exciting trials with known truth.

    `source`: "multisine" or "simulator" (see `STUDY_SOURCES`). Truth: the physical-convention datasheet
    π with joint-2 armature; the fitted model is `robot.PHYSICAL`, which contains the truth.
    Trial i lasts a duration uniform in `durations` [s]; `noise` [N m] is the multisine source's.
    """
    if source not in STUDY_SOURCES:
        raise ValueError(f"source must be one of {sorted(STUDY_SOURCES)}, not {source!r}")
    model = PHYSICAL
    pi_sheet = model.vector(datasheet_pi(robot, "physical"))
    rng = np.random.default_rng(seed)
    rows = []
    for i in tqdm(range(n_trials), desc=f"constraints study ({source})", disable=not progress):
        duration = float(rng.uniform(*durations))
        trial, pi_true, described = _study_trial(source, robot, model, pi_sheet, i, duration, seed, noise, rate_hz)
        rows.append({"trial": i, "duration_s": duration, **described, **_both_fits(trial, model, pi_true, margin)})
    settings = {
        "n_trials": n_trials,
        "source": source,
        "seed": seed,
        "durations_s": list(durations),
        "noise_nm": list(noise) if source == "multisine" else "the simulator's",
        "rate_hz": rate_hz,
        "margin": margin,
        "model": list(model.names),
        "truth": "physical-convention datasheet π with joint-2 armature",
    }
    return StudyResult(pd.DataFrame(rows), settings)


def _both_fits(trial: Dataset, model: PlanarArm, pi_true: np.ndarray, margin: float) -> dict:
    """OLS and the constrained fit on one trial: rank, consistency, active constraints, parameter errors."""
    st = Stats.from_data(model, trial.q, trial.dq, trial.ddq, trial.tau)
    ols = estimators.fit("ols", st, model)
    con = estimators.fit("constrained", st, model, margin=margin)
    excited = np.array([name not in ols.unexcited for name in model.names])
    return {
        "rank": ols.rank,
        "ols_consistent": ols.consistent,
        "ols_min_eig": ols.min_mass_eigenvalue,
        "constrained_consistent": bool(con.min_mass_eigenvalue >= margin * (1 - 1e-6) and con.consistent),
        "constrained_min_eig": con.min_mass_eigenvalue,
        "active": " ".join(con.active),
        "err_ols": relative_error(ols.pi, pi_true),
        "err_constrained": relative_error(con.pi, pi_true),
        # the same over the parameters whose columns the trial excites at all
        "err_ols_excited": relative_error(ols.pi[excited], pi_true[excited]),
        "err_constrained_excited": relative_error(con.pi[excited], pi_true[excited]),
    }


def rich_agreement(
    robot, n_trials: int = 10, *, duration: float = 30.0, seed: int = 0, margin: float = 1e-6, progress: bool = True
) -> dict:
    """On exciting simulated trials (the simulator's `fourier` reference, both joints, `duration` s): is
    OLS consistent, how far is the constrained fit from it in OLS standard errors, and how often is the
    truth within ±2 SE. Returns a summary dict."""
    model = PHYSICAL
    distance, inside, consistent = [], [], 0
    for i in tqdm(range(n_trials), desc="rich trials", disable=not progress):
        sim = simulate.simulate_trial(
            robot, trajectory="fourier", duration=duration, seed=seed * 100003 + i, progress=False
        )
        data = sim.dataset()
        st = Stats.from_data(model, data.q, data.dq, data.ddq, data.tau)
        ols, con = estimators.fit("ols", st, model), estimators.fit("constrained", st, model, margin=margin)
        consistent += ols.consistent
        distance.append(float(np.max(np.abs(con.pi - ols.pi) / ols.se)))
        inside.append(np.abs(ols.pi - model.vector(sim.truth["pi"])) <= 2 * ols.se)
    return {
        "trials": n_trials,
        "duration_s": duration,
        "ols_consistent": int(consistent),
        "max_constrained_minus_ols_in_se": float(max(distance)),
        "truth_within_2se": float(np.mean(inside)),
    }


def study(
    robot,
    n_trials: int,
    sources: tuple[str, ...] = tuple(STUDY_SOURCES),
    *,
    margin: float = 1e-6,
    progress: bool = True,
) -> tuple[list[StudyResult], dict | None]:
    """`constraints_study` for each trial source, plus `rich_agreement` when the simulator is among them."""
    results = [constraints_study(robot, n_trials, source=s, margin=margin, progress=progress) for s in sources]
    rich = rich_agreement(robot, margin=margin, progress=progress) if "simulator" in sources else None
    return results, rich
