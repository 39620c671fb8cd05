"""Benchmark: time to design an excitation (`ident-opt excite`), D-optimal and cond-optimal, side by side, on the
planar two-link arm and on the 7-joint KUKA LWR4+.

Run: .venv/bin/python benchmarks/bench_excitation.py [--duration 20] [--harmonics 5] [--starts 6] [--workers K]
         [--arm planar|kuka|both]
Each design is timed whole (the NLP built once, `--starts` IPOPT runs on `--workers` processes, the 1 kHz limit
check), with the criteria it reached next to those of its best random start, and the CPU seconds of the whole design
(this process's and its workers', summed: on a shared machine the wall clock also counts other people's work; on an
idle machine with K cores the design's wall clock is about that sum ÷ K when the starts dominate). Targets: the
planar arm's D-optimal design (2 joints × 5 harmonics × 20 s) in ≤ 30 s on 2 cores (issue 15); the 7-joint one
(7 joints × 5 harmonics × 20 s) in ≤ 120 s on 2 cores (issue 28). The planar arm's noise σ: the datasheet
residual on exp1; the KUKA's: 1 N m.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from ident_opt.data.loader import load_dataset
from ident_opt.excitation import design as excitation
from ident_opt.excitation.setup import make_setup
from ident_opt.problem import load_problem

ROOT = Path(__file__).resolve().parents[1]
#: (problem, base frequency [Hz] (None: excite's default), criteria timed, target [s]).
ARMS = {
    "planar": ("tudor_2dof", None, ("d", "cond"), 30.0),
    "kuka": ("kuka_lwr4", 0.2, ("d",), 120.0),
}


def bench(arm: str, args: argparse.Namespace) -> None:
    """Time the designs of one arm and print a line per criterion."""
    name, base_hz, criteria, target = ARMS[arm]
    problem = load_problem(ROOT / "problems" / f"{name}.toml")
    trial = load_dataset(problem.data.trials[0], problem.data, problem.robot) if arm == "planar" else None
    t0 = time.perf_counter()
    setup = make_setup(
        problem.robot, problem.limits, args.duration, harmonics=args.harmonics, base_hz=base_hz, trial=trial
    )
    setup_s = time.perf_counter() - t0
    print(
        f"\n{name}: {problem.robot.n_joints} joints x {args.harmonics} harmonics x {args.duration:g} s, {args.starts} "
        f"starts on {args.workers} processes; cores available: {excitation.cores()}; load average "
        f"{os.getloadavg()[0]:.1f}; setup {setup_s:.1f} s"
    )
    print(
        f"{'criterion':10s} {'seconds':>8s} {'vs target':>10s} {'CPU s':>12s} {'÷ workers':>10s} "
        f"{'log det':>8s} {'start':>8s} {'cond':>7s} {'start':>7s}"
    )
    for criterion in criteria:
        t0, c0 = time.perf_counter(), time.process_time()
        d = excitation.design(setup, criterion, starts=args.starts, progress=False, workers=args.workers)
        seconds = time.perf_counter() - t0 + setup_s
        # the whole design's CPU: this process's, plus the workers' (their starts) when they were forked
        cpu = time.process_time() - c0 + (sum(r["cpu_seconds"] for r in d.starts) if args.workers > 1 else 0.0)
        c, s = d.criteria, d.start_criteria
        print(
            f"{criterion:10s} {seconds:8.1f} {seconds / target:10.2f} {cpu:12.1f} {cpu / args.workers:10.1f} "
            f"{c['log_det']:8.3f} {s['log_det']:8.3f} {c['cond']:7.3f} {s['cond']:7.3f}"
        )
    print(f"target: the d design in <= {target:g} s on 2 cores (vs target <= 1); seconds include the setup")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=20.0)
    parser.add_argument("--harmonics", type=int, default=5)
    parser.add_argument("--starts", type=int, default=6)
    parser.add_argument("--workers", type=int, default=excitation.cores())
    parser.add_argument("--arm", choices=(*ARMS, "both"), default="both")
    args = parser.parse_args()
    for arm in ARMS if args.arm == "both" else (args.arm,):
        bench(arm, args)


if __name__ == "__main__":
    main()
