"""Timing shared by the benchmarks (scripts run as `python benchmarks/bench_*.py`, so this imports as `timing`)."""

from __future__ import annotations

import time
from collections.abc import Callable


def best_time(fn: Callable[[], object], repeats: int = 5) -> float:
    """Fastest wall time [s] of `repeats` calls of fn(): the run least disturbed by other processes."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best
