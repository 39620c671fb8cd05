"""Benchmark: time to design an excitation (`ident-opt excite`), D-optimal and cond-optimal, side by side.

Run: .venv/bin/python benchmarks/bench_excitation.py [--duration 20] [--harmonics 5] [--starts 6]
The problem is problems/tudor_2dof.toml (its [limits]; noise σ from the datasheet residual on exp1). Each design
is timed whole (the NLP built once, `--starts` IPOPT runs, the 1 kHz limit check), with the criteria it
reached next to those of its best random start. Target (issue 15): the D-optimal design for 2 joints ×
5 harmonics × 20 s in ≤ 30 s on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from ident_opt.data import load_dataset
from ident_opt.problem import load_problem
from ident_opt.studies import excitation

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 30.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=20.0)
    parser.add_argument("--harmonics", type=int, default=5)
    parser.add_argument("--starts", type=int, default=6)
    args = parser.parse_args()
    problem = load_problem(ROOT / "problems" / "tudor_2dof.toml")
    trial = load_dataset(problem.data.trials[0], problem.data, problem.robot)
    setup = excitation.make_setup(problem.robot, problem.limits, args.duration, harmonics=args.harmonics, trial=trial)
    print(
        f"{len(problem.robot.joints)} joints x {args.harmonics} harmonics x {args.duration:g} s, "
        f"{args.starts} starts; cores available: {os.cpu_count()}"
    )
    print(
        f"{'criterion':10s} {'seconds':>8s} {'vs target':>10s} {'log det':>8s} {'start':>8s} {'cond':>7s} {'start':>7s}"
    )
    for criterion in ("d", "cond"):
        t0 = time.perf_counter()
        d = excitation.design(setup, criterion, starts=args.starts, progress=False)
        seconds = time.perf_counter() - t0
        c, s = d.criteria, d.start_criteria
        print(
            f"{criterion:10s} {seconds:8.1f} {seconds / TARGET_S:10.2f} {c['log_det']:8.3f} {s['log_det']:8.3f} "
            f"{c['cond']:7.3f} {s['cond']:7.3f}"
        )
    print(f"target: the d design in <= {TARGET_S:g} s (vs target <= 1)")


if __name__ == "__main__":
    main()
