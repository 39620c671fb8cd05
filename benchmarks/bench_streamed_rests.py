"""Benchmark: what the loader's rest rule costs a fleet task on a long log read in pieces (`fleet.streamed`,
`fleet.rests`): one planar log of 3·10⁵ rows at 200 Hz, its statistics with `[data] rest_velocity = "auto"` (a
resting joint's velocity held at 0: two more passes over the velocities) against `"as_read"`, side by side in one
run, CPU seconds (best of 3) and the ratio, for least squares and the robust fit.

    .venv/bin/python benchmarks/bench_streamed_rests.py
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
from pathlib import Path

from ident_opt.fitting.recommend import Choice
from ident_opt.fleet import streamed, tasks
from ident_opt.fleet.simulated import long_trial

PLANAR = str(Path(__file__).resolve().parents[1] / "problems" / "tudor_2dof.toml")
ROWS, RATE_HZ, REPEATS = 300_000, 200.0, 3


def _cpu(path: Path, s, job, choice: Choice) -> float:
    best = float("inf")
    for _ in range(REPEATS):
        t0 = time.process_time()
        streamed.statistics(path, s, job, choice)
        best = min(best, time.process_time() - t0)
    return best


def main() -> None:
    job = tasks.Job(PLANAR)
    held = tasks.setup(PLANAR)
    read = dataclasses.replace(
        held,
        problem=dataclasses.replace(held.problem, data=dataclasses.replace(held.problem.data, rest_velocity="as_read")),
    )
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "long.csv"
        long_trial(PLANAR, ROWS, RATE_HZ, seed=5).to_csv(path, index=False)
        print(f"one planar log, {ROWS} rows at {RATE_HZ:g} Hz, read in pieces; CPU seconds, best of {REPEATS}")
        for estimator in ("ols", "robust"):
            choice = Choice(estimator, "", 1.0)
            a, b = _cpu(path, held, job, choice), _cpu(path, read, job, choice)
            print(f"  {estimator:7s} rests held {a:.2f} s, as read {b:.2f} s: ratio {a / b:.2f}")


if __name__ == "__main__":
    main()
