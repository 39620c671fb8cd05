"""Benchmark: sufficient statistics vs the full regressor + lstsq, and constrained vs OLS solve time.

    .venv/bin/python benchmarks/bench_identify.py [--sizes 1e4 1e5 1e6] [--repeats 300]

1. For N samples: one chunked pass accumulating (G, b, s, n) then OLS from them, against building the
   full 2N×P regressor and calling numpy.linalg.lstsq. Time (samples/s) and tracemalloc peak memory
   (inputs are allocated before tracing starts, so the peak is what the method itself needs).
2. From the same statistics, at every N (the solves must not depend on N), plus the real trial exp1 when
   data/merit/exp1.csv is there: the bare OLS solve (`solve_ols`, one lstsq on the P×P normal equations)
   against the lean constrained solve (`solve_constrained`, π only), Clarabel's own solve time inside it,
   and the full fits with standard errors and diagnostics (`fit_ols` vs `fit_constrained`). The synthetic
   arm has α3 < 0, like exp1, so OLS is infeasible and constraints are active: the constrained solve is
   measured on its slow path (one conic solve), not on the shortcut that returns a feasible OLS. Each time
   is a median over repeats, measured twice: back to back (each function's calls in a row: warm caches,
   which favours the tiny OLS solve) and interleaved (one call of each per round, as between other work).
Targets (issue 4): statistics at least as fast as full-matrix OLS with O(1) memory in N; constrained
under 10x the OLS solve and under 50 ms, independent of N.
"""

from __future__ import annotations

import argparse
import statistics
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ident_opt.arm.base import Arm
from ident_opt.arm.planar import PlanarArm
from ident_opt.data.loader import load_dataset
from ident_opt.fitting.constrained import fit_constrained, solve_constrained
from ident_opt.fitting.fit import fit_ols
from ident_opt.fitting.ols import solve_ols
from ident_opt.fitting.stats import Stats
from ident_opt.problem import load_problem


def trial(n: int, seed: int = 0) -> tuple[np.ndarray, ...]:
    """Random-phase multisine joint motion and noisy torques of an arm whose OLS fit is inconsistent."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 1000.0
    f = rng.uniform(0.1, 2.0, (2, 3))
    ph = rng.uniform(0, 2 * np.pi, (2, 3))
    arg = 2 * np.pi * f[None] * t[:, None, None] + ph[None]
    w = 2 * np.pi * f[None]
    q = 0.5 * np.sin(arg).sum(-1)
    dq = 0.5 * (w * np.cos(arg)).sum(-1)
    ddq = -0.5 * (w**2 * np.sin(arg)).sum(-1)
    # a3 < 0 in the generating parameters: the unconstrained fit is inconsistent, the constraints bind.
    pi = np.array([0.3, 0.05, -0.02, 3.7, 0.4, 1.0, 0.15, 0.5, 0.45])
    tau = PlanarArm().predict(pi, q, dq, ddq) + 0.3 * rng.normal(size=(n, 2))
    return q, dq, ddq, tau


def measure(fn) -> tuple[float, float, object]:
    """(seconds, tracemalloc peak in MB, result) of one call."""
    tracemalloc.start()
    t0 = time.perf_counter()
    out = fn()
    seconds = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1] / 1e6
    tracemalloc.stop()
    return seconds, peak, out


def medians(fns: dict[str, Callable[[], object]], repeats: int, interleaved: bool) -> dict[str, float]:
    """Median wall time [s] of each function over `repeats` calls.

    interleaved: one call of each function per round, so each call finds the caches as the others left
    them (as in a program that does other work between solves). Otherwise back to back: all calls of one
    function in a row, so a tiny working set such as the OLS solve's stays hot in cache.
    """
    times: dict[str, list[float]] = {name: [] for name in fns}
    rounds = [list(fns.items())] * repeats if interleaved else [[item] * repeats for item in fns.items()]
    for calls in rounds:
        for name, fn in calls:
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    return {name: statistics.median(t) for name, t in times.items()}


def exp1_stats(model: Arm) -> Stats | None:
    """Statistics of the real trial exp1, or None when its data file is not in the checkout."""
    problem = load_problem(Path(__file__).resolve().parents[1] / "problems" / "tudor_2dof.toml")
    if not problem.data.trials or not Path(problem.data.trials[0]).exists():
        return None
    trial_ = load_dataset(problem.data.trials[0], problem.data, problem.robot)
    return Stats.from_data(model, trial_.q, trial_.dq, trial_.ddq, trial_.tau)


def solve_table(cases: dict[str, Stats], model: Arm, repeats: int, interleaved: bool) -> None:
    """Part 2: per statistics, constrained vs OLS (lean solves and full fits) and Clarabel's own time."""
    print(f"   {'interleaved' if interleaved else 'back to back'}, median of {repeats} calls each")
    print(
        f"{'statistics':>12} {'active constraints':>30} | {'solve_ols':>9} {'solve_con':>9} {'ratio':>6} | "
        f"{'Clarabel':>8} {'ratio':>6} | {'fit_ols':>8} {'fit_con':>8} {'ratio':>6} | max rel Δπ"
    )
    worst = 0.0
    for label, st in cases.items():
        fits: list = []
        fns = {
            "ols": lambda st=st: solve_ols(st),
            "con": lambda st=st: solve_constrained(st, model),
            "fit_ols": lambda st=st: fit_ols(st, model),
            "fit_con": lambda st=st, fits=fits: fits.append(fit_constrained(st, model)),
        }
        for fn in fns.values():
            fn()  # warm-up: imports, the cached constraint structure
        t = medians(fns, repeats, interleaved)
        clarabel_s = statistics.median(f.details["clarabel_seconds"] for f in fits)
        fit = fits[-1]
        assert not fit_ols(st, model).consistent and fit.active, "the benchmark must exercise the conic solve"
        rel = np.max(np.abs(solve_constrained(st, model) - fit.pi) / np.abs(fit.pi))  # one implementation
        worst = max(worst, t["con"] / t["ols"])
        print(
            f"{label:>12} {','.join(a.replace('mass_pd_', '') for a in fit.active):>30} | "
            f"{1e3 * t['ols']:6.3f} ms {1e3 * t['con']:6.3f} ms {t['con'] / t['ols']:5.1f}x | "
            f"{1e3 * clarabel_s:5.3f} ms {clarabel_s / t['ols']:5.1f}x | {1e3 * t['fit_ols']:5.3f} ms "
            f"{1e3 * t['fit_con']:5.3f} ms {t['fit_con'] / t['fit_ols']:5.1f}x | {rel:.1e}"
        )
    print(
        f"   target (issue 4) solve_constrained < 10x solve_ols and < 50 ms: worst ratio {worst:.1f}x -> "
        + ("met" if worst < 10 else "NOT met")
        + ("" if interleaved else " (back to back)")
    )


def main() -> None:
    """Run both parts and print the tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=[1e4, 1e5, 1e6])
    parser.add_argument("--repeats", type=int, default=300, help="calls per solve timing")
    args = parser.parse_args()
    model = PlanarArm()
    P = model.n_params

    print("1) statistics pass + OLS vs full regressor + numpy.linalg.lstsq")
    print(
        f"{'N':>9} | {'stats s':>8} {'Msamp/s':>8} {'peak MB':>8} | {'lstsq s':>8} {'Msamp/s':>8} {'peak MB':>8} | "
        f"{'speed ratio':>11} {'mem ratio':>9} | max |Δπ|"
    )
    solve_cases: dict[str, Stats] = {}
    for n in (int(s) for s in args.sizes):
        q, dq, ddq, tau = trial(n)

        def by_stats(q=q, dq=dq, ddq=ddq, tau=tau):
            """One chunked pass into (G, b, s, n), then OLS from them."""
            st = Stats.from_data(model, q, dq, ddq, tau)
            return st, solve_ols(st)

        def by_lstsq(q=q, dq=dq, ddq=ddq, tau=tau):
            """The full 2N×P regressor and numpy.linalg.lstsq."""
            Y = model.regressor(q, dq, ddq).reshape(-1, P)
            return np.linalg.lstsq(Y, tau.reshape(-1), rcond=None)[0]

        by_stats()  # warm-up (imports, CasADi-free NumPy paths)
        ts, ms, (st, pi_s) = measure(by_stats)
        tl, ml, pi_l = measure(by_lstsq)
        print(
            f"{n:>9} | {ts:8.3f} {n / ts / 1e6:8.2f} {ms:8.1f} | {tl:8.3f} {n / tl / 1e6:8.2f} {ml:8.1f} | "
            f"{tl / ts:10.2f}x {ml / ms:8.1f}x | {np.max(np.abs(pi_s - pi_l)):.1e}"
        )
        solve_cases[f"N={n:.0e}"] = st

    print("\n2) solve from the same statistics, constrained (active constraints: OLS infeasible) vs OLS")
    cases = dict(solve_cases)
    real = exp1_stats(model)
    if real is not None:
        cases[f"exp1 {real.n}"] = real
    for interleaved in (False, True):
        solve_table(cases, model, args.repeats, interleaved)
    # For reference: the cvxpy statement of the same program (compiled once per structure).
    st = solve_cases[max(solve_cases)]
    fit_constrained(st, model, backend="cvxpy")
    t_cvxpy = statistics.median(fit_constrained(st, model, backend="cvxpy").solve_seconds for _ in range(20))
    print(f"   cvxpy backend, solve only: {1e3 * t_cvxpy:.3f} ms")


if __name__ == "__main__":
    main()
