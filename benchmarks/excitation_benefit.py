"""Is the designed excitation worth running on this arm? The D-optimal design (`excitation.design`) against random
Fourier motions within the same limits and duration, each run with measurement noise and identified through the
standard derivative pipeline (the loader's zero-phase estimate from the logged angles, never exact derivatives).

    python benchmarks/excitation_benefit.py --problem P [--seeds N] [--out DIR]   (`make excitation-arms`)

Per noise seed s: the design (one, from the design's own seeded starts) and a new random Fourier motion (the
design's start recipe: random decaying harmonics around the rest pose, scaled into the limits, then checked and
repaired on the 1 kHz grid, `excitation.into_limits`, `excitation.repaired`) are each logged with noise seed s:

- an arm the closed-loop simulator serves (`Robot.serves` "simulate": the planar two-link arm) follows the motion
  in the simulator (`simulate --trajectory-file`), with its measured sensor noise, logged at 100 Hz;
- any other arm: rigid inverse dynamics of its model at the nominal parameters (`Robot.datasheets`, the truth),
  sampled at `RATE_HZ`, with Gaussian noise of σ_q `NOISE_Q` rad on every angle and σ_τ `NOISE_TAU` N m on every
  torque, written as t, q, τ and read back by the loader (derivatives estimated).

The error of a trial: the median over the base parameters (`fitting.base`; every parameter on the planar arm)
of |π̂_b − π_b| / |π_b| for OLS (parameters whose truth is 0 left out). The seeds used while developing (`DEV_SEEDS`)
are reported apart from the unseen ones (`UNSEEN_FROM` on), which decide: the ratio of the random motions' median
error to the design's.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from ident_opt.columns import channel_names
from ident_opt.data.dataset import Dataset
from ident_opt.data.loader import load_dataset
from ident_opt.diagnosis.split import at_rest
from ident_opt.errors import InputError
from ident_opt.excitation import design as excitation
from ident_opt.excitation.setup import Setup, make_setup
from ident_opt.fitting import estimators
from ident_opt.fitting.base import base_parameters
from ident_opt.fitting.stats import Stats
from ident_opt.problem import load_problem
from ident_opt.problem.spec import Problem
from ident_opt.report import record
from ident_opt.simulator import simulate_trial

ROOT = Path(__file__).resolve().parents[1]
#: Seeds looked at while developing; the unseen ones start at `UNSEEN_FROM`.
DEV_SEEDS = (0, 1, 2, 3, 4)
UNSEEN_FROM = 1000
#: Rigid inverse dynamics: log rate [Hz], angle noise [rad] and torque noise [N m] (σ, Gaussian, every joint).
RATE_HZ = 200.0
NOISE_Q = 2e-5
NOISE_TAU = 0.5
#: Seed stream of the random motions (apart from the noise's).
MOTION_STREAM = 7


@dataclasses.dataclass
class Benefit:
    """The design, its setup, one row per trial, how the trials were made, timings."""

    problem: str
    setup: Setup
    design: excitation.Design
    trials: pd.DataFrame
    how: str
    seconds: dict
    workers: int = 1
    load: float = 0.0  # the 1-minute load average before the design (the machine is shared)

    def summary(self, unseen: bool = True) -> dict:
        """Over the unseen (or the development) seeds: the median error of the design and of the random motions
        and their ratio (random ÷ design: > 1 means the design identifies better)."""
        rows = self.trials[self.trials["unseen"] == unseen]
        design = float(rows["error_design"].median())
        random = float(rows["error_random"].median())
        rests = float(rows["error_random_rests0"].median()) / float(rows["error_design_rests0"].median())
        return {
            "seeds": [int(s) for s in rows["seed"]],
            "median_error_design": design,
            "median_error_random": random,
            "ratio": random / design if design > 0 else None,
            "design_better_on": int((rows["error_design"] < rows["error_random"]).sum()),
            "ratio_rests0": rests if np.isfinite(rests) else None,
        }


def random_motion(setup: Setup, seed: int) -> np.ndarray:
    """x of a random Fourier motion as large as the limits allow (the design's start recipe, then its harmonics scaled
    up together to the largest factor that keeps every limit on the 1 kHz grid: as much excitation as the limits
    give a motion of that shape)."""
    rng = np.random.default_rng([seed, MOTION_STREAM])
    centre = 0.5 * (np.array(setup.limits.position_min) + np.array(setup.limits.position_max))
    centre = excitation.rest_pose(setup, centre)
    x = excitation.repaired(setup, excitation.into_limits(setup, setup.fourier.random(rng, centre)))
    if x is None:
        raise InputError("no random Fourier motion fits the limits even at rest; widen [limits]")
    return largest_within(setup, x)


def largest_within(setup: Setup, x: np.ndarray) -> np.ndarray:
    """x (within the limits at 1 kHz) with its harmonics scaled by the largest factor ≥ 1 that stays within them."""
    f = setup.fourier
    lo, hi = 1.0, 2.0
    while hi < 1e3 and excitation.feasible(setup, f.scaled(x, hi)):
        lo, hi = hi, 2 * hi
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if excitation.feasible(setup, f.scaled(x, mid)) else (lo, mid)
    return f.scaled(x, lo)


def rigid_trial(problem: Problem, setup: Setup, x: np.ndarray, seed: int, folder: Path) -> tuple[Dataset, np.ndarray]:
    """(the trial as the loader reads it, the true π): the motion of x logged at `RATE_HZ` with noise `NOISE_Q`,
    `NOISE_TAU`, its torques by rigid inverse dynamics of the setup's model at the nominal parameters."""
    robot = problem.robot
    nominal, pi = robot.datasheets()[robot.datasheet]
    arm = setup.arm
    pi_true = arm.vector(nominal.as_dict(pi))
    t = np.arange(round(setup.duration * RATE_HZ)) / RATE_HZ
    q, dq, ddq = setup.fourier.evaluate(x, t)
    tau = arm.predict(pi_true, q, dq, ddq)
    rng = np.random.default_rng([seed, 28])
    names = channel_names(arm.n_joints)
    frame = pd.DataFrame({"t": t})
    for kind, values, sigma in (("q", q, NOISE_Q), ("tau", tau, NOISE_TAU)):
        noisy = values + sigma * rng.standard_normal(values.shape)
        for j, name in enumerate(names[kind]):
            frame[name] = noisy[:, j]
    path = folder / f"trial_{seed}_{_key(x)}.csv"
    frame.to_csv(path, index=False, float_format="%.12g")
    spec = dataclasses.replace(problem.data, columns={}, conversions={}, header=True)
    return load_dataset(path, spec, robot), pi_true


def simulated_trial(
    problem: Problem, setup: Setup, x: np.ndarray, seed: int, folder: Path
) -> tuple[Dataset, np.ndarray]:
    """(the trial, the true π) from the closed-loop simulator following the motion of x (the planar arm)."""
    t = np.arange(round(setup.duration * 1000.0)) / 1000.0
    q, dq, ddq = setup.fourier.evaluate(x, t)
    names = channel_names(setup.arm.n_joints)
    frame = pd.DataFrame({"t": t})
    for kind, values in (("q", q), ("dq", dq), ("ddq", ddq)):
        for j, name in enumerate(names[kind]):
            frame[name] = values[:, j]
    path = folder / f"motion_{_key(x)}.csv"
    if not path.exists():
        frame.to_csv(path, index=False, float_format="%.12g")
    sim = simulate_trial(problem.robot, trajectory=str(path), duration=setup.duration, seed=seed, progress=False)
    return sim.dataset(), setup.arm.vector(sim.truth["pi"])


def _key(x: np.ndarray) -> str:
    """A short name for a motion's coefficients (its files)."""
    return hashlib.sha256(np.ascontiguousarray(x).tobytes()).hexdigest()[:12]


def trial_error(setup: Setup, data: Dataset, pi_true: np.ndarray) -> float:
    """Median over the base parameters of |π̂_b − π_b| / |π_b| (truth 0 left out) for OLS on `data`."""
    arm = setup.arm
    fit = estimators.fit("ols", Stats.from_data(arm, data.q, data.dq, data.ddq, data.tau), arm)
    base = base_parameters(arm)
    estimate, truth = base.project(fit.pi), base.project(pi_true)
    keep = np.abs(truth) > 1e-9 * np.abs(truth).max()
    return float(np.median(np.abs(estimate[keep] - truth[keep]) / np.abs(truth[keep])))


def run(
    problem: Problem,
    *,
    seeds: int = 20,
    duration: float = 20.0,
    harmonics: int = 5,
    base_hz: float | None = None,
    starts: int = 6,
    design: excitation.Design | None = None,
    progress: bool = True,
    unseen_from: int = UNSEEN_FROM,
    workers: int = 1,
) -> Benefit:
    """The design (unless given) and the trials of `DEV_SEEDS` and of `seeds` unseen seeds from `unseen_from` on
    (module doc); `base_hz`: the series' base frequency (`excite --base-hz`; default excite's), the random motions'
    too; `workers`: processes running the design's starts."""
    if unseen_from <= max(DEV_SEEDS):
        raise InputError(f"unseen seeds start above the development seeds {DEV_SEEDS}, got {unseen_from}")
    if problem.limits is None:
        raise InputError(f"{problem.path}: section [limits] is required to design an excitation")
    t0, load = time.perf_counter(), os.getloadavg()[0]
    setup = make_setup(problem.robot, problem.limits, duration, harmonics=harmonics, base_hz=base_hz)
    design = design or excitation.design(setup, "d", starts=starts, progress=progress, workers=workers)
    t_design = time.perf_counter()
    closed_loop = "simulate" in problem.robot.serves and problem.robot.paper_views
    make = simulated_trial if closed_loop else rigid_trial
    how = (
        "closed-loop simulator (its sensor noise), logged at 100 Hz, derivatives estimated"
        if closed_loop
        else f"rigid inverse dynamics at the nominal parameters, {RATE_HZ:g} Hz, noise σ_q = {NOISE_Q:g} rad, "
        f"σ_τ = {NOISE_TAU:g} N m, derivatives estimated by the loader"
    )
    rows = []
    all_seeds = [*DEV_SEEDS, *range(unseen_from, unseen_from + seeds)]
    with tempfile.TemporaryDirectory(prefix="ident_opt_benefit_") as tmp:
        for seed in tqdm(all_seeds, desc="excitation benefit", disable=not progress):
            x_random = random_motion(setup, seed)
            row = {"seed": seed, "unseen": seed >= unseen_from}
            for label, x in (("design", design.x), ("random", x_random)):
                data, pi_true = make(problem, setup, x, seed, Path(tmp))
                row[f"error_{label}"] = trial_error(setup, data, pi_true)
                # The reading of the last proof's "rests 0" columns: slow speeds as rest (`diagnosis.split.at_rest`).
                row[f"error_{label}_rests0"] = trial_error(setup, at_rest(data), pi_true)
                crit = excitation.criteria(setup, data.q, data.dq, data.ddq)
                row[f"log_det_{label}"], row[f"cond_{label}"] = crit["log_det"], crit["cond"]
            row["ratio"] = row["error_random"] / row["error_design"]
            rows.append(row)
    seconds = {"design": t_design - t0, "trials": time.perf_counter() - t_design}
    return Benefit(problem.name, setup, design, pd.DataFrame(rows), how, seconds, workers, load)


def payload(b: Benefit) -> dict:
    """The JSON of a run: the design's criteria, margins and time, every seed's row, the summaries."""
    d = b.design
    return {
        "problem": b.problem,
        "joints": int(b.setup.arm.n_joints),
        "duration_s": b.setup.duration,
        "harmonics": b.setup.fourier.harmonics,
        "base_hz": b.setup.fourier.base_hz,
        "base_parameters": len(b.setup.base),
        "trials": b.how,
        "design": {
            "criteria": d.criteria,
            "seconds": d.seconds,
            "starts": len(d.starts),
            "start_cpu_seconds": [r.get("cpu_seconds") for r in d.starts],
            "start_iterations": [r["iterations"] for r in d.starts],
            "workers": b.workers,
            "load_average_before": b.load,
            "converged": d.converged,
            "margins": d.margins,
            "tightest_margin": min(min(m["fraction"]) for m in d.margins.values()),
        },
        "unseen": b.summary(True),
        "development": b.summary(False),
        "design_coefficients": [float(v) for v in d.x],
        "rows": b.trials.to_dict(orient="records"),
        "seconds": b.seconds,
    }


def markdown(data: dict) -> str:
    """The report of one arm."""
    u, d, des = data["unseen"], data["development"], data["design"]
    lines = [
        f"## {data['problem']}: {data['joints']} joints, {data['harmonics']} harmonics of {data['base_hz']:g} Hz, "
        f"{data['duration_s']:g} s",
        "",
        f"D-optimal design in {des['seconds']:.1f} s ({des['starts']} starts on {des['workers']} processes, "
        f"{sum(des['start_cpu_seconds']):.0f} s of CPU in IPOPT, load average {des['load_average_before']:.1f} "
        f"before; converged: {des['converged']}); "
        f"tightest limit margin {des['tightest_margin']:.1%} of its limit (1 kHz grid); {data['base_parameters']} "
        f"base parameters. Trials: {data['trials']}.",
        "",
        "| seed | unseen | error design | error random | random ÷ design | log det design | log det random | "
        "÷ with slow speeds read as rest |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in data["rows"]:
        lines.append(
            f"| {r['seed']} | {'yes' if r['unseen'] else 'no'} | {r['error_design']:.4g} | {r['error_random']:.4g} | "
            f"{r['ratio']:.2f} | {r['log_det_design']:.4g} | {r['log_det_random']:.4g} | "
            f"{r['error_random_rests0'] / r['error_design_rests0']:.2f} |"
        )
    lines += [
        "",
        *(
            f"{label} seeds ({len(v['seeds'])}): median error {v['median_error_design']:.4g} (design) vs "
            f"{v['median_error_random']:.4g} (random): **{v['ratio']:.2f}×** lower with the design; the design is "
            f"better on {v['design_better_on']} of {len(v['seeds'])} seeds (with slow speeds read as rest, "
            f'`diagnosis.split.at_rest`, as the last proof\'s "rests 0" columns: {v["ratio_rests0"]:.2f}×).'
            for label, v in (("Unseen", u), ("Development", d))
            if v["seeds"]
        ),
        "",
        "Margins per limit (least fraction of the limit left, per joint): "
        + "; ".join(f"{k} {', '.join(f'{v:.1%}' for v in m['fraction'])}" for k, m in des["margins"].items())
        + ".",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problem", action="append", required=True, help="a problem with [limits]; repeatable")
    ap.add_argument(
        "--base-hz", action="append", type=float, help="the series' base frequency per --problem, in their order"
    )
    ap.add_argument("--seeds", type=int, default=20, help="unseen noise seeds (default 20)")
    ap.add_argument("--starts", type=int, default=6)
    ap.add_argument("--unseen-from", type=int, default=UNSEEN_FROM, help=f"first unseen seed (default {UNSEEN_FROM})")
    ap.add_argument("--workers", type=int, default=excitation.cores(), help="processes running the design's starts")
    ap.add_argument("--out", default=str(ROOT / "results"))
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    hz = args.base_hz or [None] * len(args.problem)
    if len(hz) != len(args.problem):
        raise SystemExit("give --base-hz once per --problem, or not at all")
    runs = [
        payload(
            run(
                load_problem(p),
                seeds=args.seeds,
                starts=args.starts,
                base_hz=f,
                progress=not args.no_progress,
                unseen_from=args.unseen_from,
                workers=args.workers,
            )
        )
        for p, f in zip(args.problem, hz)
    ]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "excitation_arms.json").write_text(json.dumps(runs, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    text = "\n".join(
        [
            "# Designed excitation against random Fourier motions (`make excitation-arms`)",
            "",
            (__doc__ or "").split("\n\n", 1)[1].split("\n\n")[0].replace("\n", " "),
            "",
            *(markdown(r) for r in runs),
        ]
    )
    (out / "excitation_arms.md").write_text(text, encoding="utf-8")
    record(
        out,
        "excitation_arms",
        "the designed excitation against random Fourier motions, 7 joints and 2, on unseen noise seeds",
        ("excitation_arms.md", "excitation_arms.json"),
    )
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
