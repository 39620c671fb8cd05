"""Benchmark: sufficient statistics vs the full regressor + lstsq, and constrained vs OLS solve time.

    .venv/bin/python benchmarks/bench_identify.py [--sizes 1e4 1e5 1e6] [--repeats 30]

1. For N samples: one chunked pass accumulating (G, b, s, n) then OLS from them, against building the
   full 2N×P regressor and calling numpy.linalg.lstsq. Time (samples/s) and tracemalloc peak memory
   (inputs are allocated before tracing starts, so the peak is what the method itself needs).
2. From the same statistics: the OLS solve, the constrained conic solve (cvxpy + Clarabel, compiled once,
   a constraint active), and Clarabel's own time, each the median over repeats. Ratios printed side by side.
Targets (issue 4): statistics at least as fast as full-matrix OLS with O(1) memory in N; constrained
under 10x the OLS solve and under 50 ms, independent of N.
"""

from __future__ import annotations

import argparse
import statistics
import time
import tracemalloc

import numpy as np

from ident_opt.identify.constrained import fit_constrained
from ident_opt.identify.fit import fit_ols
from ident_opt.identify.ols import solve_ols
from ident_opt.identify.stats import Stats
from ident_opt.robot import ArmModel


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
    tau = ArmModel().predict(pi, q, dq, ddq) + 0.3 * rng.normal(size=(n, 2))
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


def median_time(fn, repeats: int) -> float:
    """Median wall time of `repeats` calls [s]."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    """Run both parts and print the tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=[1e4, 1e5, 1e6])
    parser.add_argument("--repeats", type=int, default=30)
    args = parser.parse_args()
    model = ArmModel()
    P = model.n_params

    print("1) statistics pass + OLS vs full regressor + numpy.linalg.lstsq")
    print(f"{'N':>9} | {'stats s':>8} {'Msamp/s':>8} {'peak MB':>8} | {'lstsq s':>8} {'Msamp/s':>8} {'peak MB':>8} | "
          f"{'speed ratio':>11} {'mem ratio':>9} | max |Δπ|")
    stats_for_solve = None
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
        print(f"{n:>9} | {ts:8.3f} {n / ts / 1e6:8.2f} {ms:8.1f} | {tl:8.3f} {n / tl / 1e6:8.2f} {ml:8.1f} | "
              f"{tl / ts:10.2f}x {ml / ms:8.1f}x | {np.max(np.abs(pi_s - pi_l)):.1e}")
        stats_for_solve = st

    print(f"\n2) solve time from the same statistics (median over repeats, N = {stats_for_solve.n})")
    st = stats_for_solve
    fit_constrained(st, model, backend="cvxpy")  # compile the cvxpy program once (cached per structure)
    t_ols_solve = median_time(lambda: solve_ols(st), args.repeats)
    t_ols_fit = median_time(lambda: fit_ols(st, model), args.repeats)
    t_con_fit = median_time(lambda: fit_constrained(st, model), args.repeats)
    con = fit_constrained(st, model)
    runs = [fit_constrained(st, model) for _ in range(args.repeats)]
    t_con_solve = statistics.median(r.solve_seconds for r in runs)
    t_clarabel = statistics.median(r.details["clarabel_seconds"] for r in runs)
    t_cvxpy = statistics.median(fit_constrained(st, model, backend="cvxpy").solve_seconds
                                for _ in range(args.repeats))
    print(f"   active constraints: {con.active}")
    rows = [
        ("OLS solve (P×P normal equations)", t_ols_solve, t_ols_solve),
        ("constrained solve, direct Clarabel (named blocks)", t_con_solve, t_ols_solve),
        ("  of which Clarabel's own solve time", t_clarabel, t_ols_solve),
        ("constrained solve, cvxpy backend (compiled once)", t_cvxpy, t_ols_solve),
        ("fit_ols incl. SEs and diagnostics", t_ols_fit, t_ols_fit),
        ("fit_constrained incl. SEs and diagnostics", t_con_fit, t_ols_fit),
    ]
    for label, t, ref in rows:
        print(f"   {label:<52} {1e3 * t:8.3f} ms   {t / ref:7.1f}x its OLS counterpart")

if __name__ == "__main__":
    main()
