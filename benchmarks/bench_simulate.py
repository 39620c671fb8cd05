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
import time
from pathlib import Path

from timing import best_time

from ident_opt.effects import BACKGROUND
from ident_opt.problem import load_problem
from ident_opt.simulator import CATALOGUE, simulate_trial

ROOT = Path(__file__).resolve().parents[1]


def simulation_time(robot, effects, duration: float, repeat: int) -> float:
    """Best wall time [s] of `repeat` simulations of the default trial with `effects`."""
    return best_time(lambda: simulate_trial(robot, duration=duration, effects=effects, progress=False), repeat)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--duration", type=float, default=80.0)
    parser.add_argument("--arm-only", action="store_true", help="only the 7-joint arm")
    args = parser.parse_args()
    if args.arm_only:
        return arm(args.repeat)
    sim = load_problem(ROOT / "problems" / "tudor_sim.toml")
    cases = {
        "clean (rigid truth)": [],
        "tudor_sim default": list(sim.simulate.effects),
        "background terms only": [name for name, term in BACKGROUND.items() if not term.any_arm],
        "all catalogue effects": list(CATALOGUE),
    }
    print(f"simulating {args.duration:g} s at 1 kHz control, 100 Hz logging; cores available: {os.cpu_count()}")
    print(f"{'case':28s} {'seconds':>8s} {'x real time':>12s}")
    for name, effects in cases.items():
        t = simulation_time(sim.robot, effects, args.duration, args.repeat)
        print(f"{name:28s} {t:8.3f} {args.duration / t:12.1f}")
    print("target: >= 5x real time")
    arm(args.repeat)


#: Every catalogue effect at once on the 7-joint arm (an elastic joint, friction of every kind, ...).
EVERY_EFFECT = [
    "armature:joint=3",
    "asymmetric_coulomb:joint=2",
    "stribeck:joint=5",
    "elasticity:joint=4,frequency_hz=5",
    "payload",
    "delay",
    "joint_offset:joint=6",
    "torque_scale:joint=1",
    "load_friction:joint=2",
]


def arm(repeat: int, duration: float = 60.0) -> None:
    """A 7-joint arm (the KUKA LWR4+): 60 s at 1 kHz, clean and with every catalogue effect, on the point-to-point
    `tud01` (moves and rests) and the `fourier` reference (always moving). The first run of each also compiles the
    loop to C (once per machine and arm structure); the best of `repeat` is the simulator's own speed. The share of
    ticks that took the fine RK4 steps (a joint near a reversal or at rest with an effect's friction) explains
    the difference between the two references."""
    problem = load_problem(ROOT / "problems" / "kuka_lwr4.toml")
    cases = {
        "7-joint clean, tud01": ([], "tud01"),
        "7-joint every effect, tud01": (EVERY_EFFECT, "tud01"),
        "7-joint clean, fourier": ([], "fourier"),
        "7-joint every effect, fourier": (EVERY_EFFECT, "fourier"),
    }
    print(
        f"\n7-joint arm (KUKA LWR4+), {duration:g} s at 1 kHz control, logged at 1 kHz; "
        f"5x real time = {duration / 5:g} s"
    )
    head = f"{'case':32s} {'first s':>8s} {'best s':>8s} {'x real time':>12s} {'cpu s':>6s} {'x real (cpu)':>12s}"
    print(f"{head} {'steps':>6s} {'fine ticks':>10s}")
    for name, (effects, trajectory) in cases.items():
        found = {}

        def simulate(effects=effects, trajectory=trajectory, found=found):
            found["trial"] = simulate_trial(
                problem.robot,
                trajectory=trajectory,
                duration=duration,
                rate_hz=1000.0,
                effects=effects,
                limits=problem.limits,
                progress=False,
            )

        first = best_time(simulate, 1)
        c0 = time.process_time()
        t = best_time(simulate, repeat)
        cpu = (time.process_time() - c0) / repeat  # one core's work per trial, whatever else the machine runs
        loop = found["trial"].truth["controller"]
        steps = f"{loop['rk4_substeps_away_from_reversals']}/{loop['rk4_substeps']}"
        print(
            f"{name:32s} {first:8.2f} {t:8.2f} {duration / t:12.1f} {cpu:6.2f} {duration / cpu:12.1f} "
            f"{steps:>6s} {loop['fine_tick_share']:10.1%}"
        )
    print("target: >= 5x real time on one core")


if __name__ == "__main__":
    main()
