"""Benchmark: time to simulate the 80 s default trial, as a ratio against real time (target ≥ 5×).

Run: .venv/bin/python benchmarks/bench_simulate.py [--repeat 3]
Times, side by side in one run: the clean rigid trial, the calibrated default of problems/tudor_sim.toml
(flexible link, asymmetric Coulomb, Stribeck, and the background terms stiction, drift, ripple), the background
terms alone, and every catalogue effect at its default magnitude; the
first call of each also pays for building the CasADi functions, so the best of `--repeat` runs is reported.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from timing import best_time

from ident_opt.effects import BACKGROUND
from ident_opt.problem import load_problem
from ident_opt.simulate import CATALOGUE, simulate_trial

ROOT = Path(__file__).resolve().parents[1]


def simulation_time(robot, effects, duration: float, repeat: int) -> float:
    """Best wall time [s] of `repeat` simulations of the default trial with `effects`."""
    return best_time(lambda: simulate_trial(robot, duration=duration, effects=effects, progress=False), repeat)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--duration", type=float, default=80.0)
    args = parser.parse_args()
    sim = load_problem(ROOT / "problems" / "tudor_sim.toml")
    cases = {
        "clean (rigid truth)": [],
        "tudor_sim default": list(sim.simulate.effects),
        "background terms only": list(BACKGROUND),
        "all catalogue effects": list(CATALOGUE),
    }
    print(f"simulating {args.duration:g} s at 1 kHz control, 100 Hz logging; cores available: {os.cpu_count()}")
    print(f"{'case':28s} {'seconds':>8s} {'x real time':>12s}")
    for name, effects in cases.items():
        t = simulation_time(sim.robot, effects, args.duration, args.repeat)
        print(f"{name:28s} {t:8.3f} {args.duration / t:12.1f}")
    print("target: >= 5x real time")


if __name__ == "__main__":
    main()
