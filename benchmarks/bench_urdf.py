"""Benchmark: an arm from a URDF (the KUKA LWR4+, 7 joints) — regressor rows, fits from statistics, generated C.

Targets (issue 16): regressor ≥ 10⁵ samples/s for 7 joints; the consistent fit from statistics ≤ 1 s;
generated C tau_hat for 7 joints ≤ 2 µs per call. The regressor (the CasADi model compiled to C, called on
chunks) is timed side by side with Pinocchio's per-sample path (`IDENT_OPT_REGRESSOR=pinocchio`), alternating
repetitions, so their ratio holds on a loaded machine; its setup (loading the cached library) is timed too.
The fits are timed on the statistics of the problem's training trials, after a first call (the plausible
fit caches its constraint rows per arm).
BLAS threads are set to 1 before NumPy loads (the fits' matrices are 100 × 100: threads only contend).

    .venv/bin/python benchmarks/bench_urdf.py [--problem P] [--samples N] [--calls N] [--json F]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from timing import best_time  # noqa: E402

from ident_opt.commands.common import write_json  # noqa: E402
from ident_opt.data.loader import load_dataset  # noqa: E402
from ident_opt.fitting.base import fit_base_ols  # noqa: E402
from ident_opt.fitting.constrained import fit_constrained  # noqa: E402
from ident_opt.fitting.physical import fit_physical  # noqa: E402
from ident_opt.fitting.trust import stats_of  # noqa: E402
from ident_opt.problem import load_problem  # noqa: E402
from ident_opt.shipping import codegen  # noqa: E402

TIMING_LOOP = ROOT / "benchmarks" / "c" / "bench_urdf.c"
TARGETS = {"regressor_samples_per_s": 1e5, "consistent_fit_s": 1.0, "tau_hat_ns": 2000.0}


def c_tau_hat_ns(arm, pi: np.ndarray, calls: int) -> float:
    """Generate tau_hat for π, compile it with the timing loop (-O2), run it: ns per call."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        source, _ = codegen.generate_sources(codegen.build_functions(arm, pi, forward=False), out)
        exe = out / "bench"
        cmd = [*codegen.find_compiler(), "-O2", "-std=c99", f"-DN_JOINTS={arm.n_joints}", f"-I{out}"]
        cmd += [str(TIMING_LOOP), str(source), "-o", str(exe), "-lm"]
        subprocess.run(cmd, check=True)
        done = subprocess.run([str(exe), str(calls)], check=True, capture_output=True, text=True)
    return float(done.stdout.split()[1])


def pinocchio_twin(arm):
    """The same arm whose regressor is Pinocchio's per sample (the documented switch, set while it is built)."""
    os.environ["IDENT_OPT_REGRESSOR"] = "pinocchio"
    try:
        twin = dataclasses.replace(arm)
        assert twin._compiled_regressor is None  # decided now, cached on the twin
    finally:
        del os.environ["IDENT_OPT_REGRESSOR"]
    return twin


def regressor_rates(arm, q, dq, ddq, repeats: int = 5) -> tuple[float, float, float]:
    """(compiled, Pinocchio) samples/s, best of `repeats` alternating runs, and the compiled path's setup [s]
    on a fresh arm (the library is cached by then: this is loading it)."""
    fresh = dataclasses.replace(arm)
    start = time.perf_counter()
    fresh._compiled_regressor  # noqa: B018  (what the first regressor call of a process pays)
    setup = time.perf_counter() - start
    twin = pinocchio_twin(arm)
    chunk = 4096  # samples per regressor call (Stats.from_data passes larger chunks; this one is cache-sized)
    starts = range(0, len(q), chunk)
    best = {id(arm): float("inf"), id(twin): float("inf")}
    for _ in range(repeats):
        for which in (arm, twin):
            seconds = best_time(
                lambda w=which: [w.regressor(q[s : s + chunk], dq[s : s + chunk], ddq[s : s + chunk]) for s in starts],
                repeats=1,
            )
            best[id(which)] = min(best[id(which)], seconds)
    return len(q) / best[id(arm)], len(q) / best[id(twin)], setup


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problem", default=str(ROOT / "problems" / "kuka_lwr4.toml"))
    parser.add_argument("--samples", type=int, default=20000, help="random states for the regressor timing")
    parser.add_argument("--calls", type=int, default=100000, help="C calls per timed repetition")
    parser.add_argument("--json", metavar="F", help="also write the figures as JSON")
    args = parser.parse_args(argv)

    problem = load_problem(args.problem)
    arm = problem.robot.arm
    rng = np.random.default_rng(0)
    size = (args.samples, arm.n_joints)
    q, dq, ddq = rng.uniform(-3, 3, size), rng.uniform(-2, 2, size), rng.uniform(-5, 5, size)
    arm.regressor(q[:1], dq[:1], ddq[:1])  # compiles the regressor if this machine has not yet
    compiled_rate, pinocchio_rate, setup_s = regressor_rates(arm, q, dq, ddq)
    stats = stats_of(arm, [load_dataset(p, problem.data, problem.robot) for p in problem.data.training])
    robot = problem.robot
    options = {"prior_weight": robot.prior_weight, "mass_range": robot.mass_range, "com_box": robot.com_box}
    consistent = fit_physical(stats, arm, **options)  # first call: cvxpy compiles the program
    fits = {
        "ols (base parameters)": best_time(lambda: fit_base_ols(stats, arm)),
        "constrained (pseudo-inertias, Clarabel)": best_time(lambda: fit_constrained(stats, arm)),
        "consistent (plausible, Clarabel)": best_time(lambda: fit_physical(stats, arm, **options)),
    }
    tau_ns = c_tau_hat_ns(arm, consistent.pi, args.calls)
    figures = {
        "regressor_samples_per_s": compiled_rate,
        "regressor_pinocchio_samples_per_s": pinocchio_rate,
        "regressor_speedup": compiled_rate / pinocchio_rate,
        "regressor_setup_s": setup_s,
        "consistent_fit_s": fits["consistent (plausible, Clarabel)"],
        "tau_hat_ns": tau_ns,
    }
    print(f"{problem.name}: {arm.n_joints} joints, {arm.n_params} parameters, {stats.n} training samples")
    print(f"  regressor       {figures['regressor_samples_per_s']:12.0f} samples/s   (target >= 1e5)")
    print(
        f"  (Pinocchio per sample {pinocchio_rate:.0f} samples/s in the same run: "
        f"{compiled_rate / pinocchio_rate:.1f}x; loading the compiled regressor {setup_s * 1e3:.0f} ms)"
    )
    for name, s in fits.items():
        print(f"  fit {name:40s} {s * 1e3:9.1f} ms")
    print(f"  generated C tau_hat {tau_ns:8.1f} ns/call     (target <= 2000)")
    met = {
        "regressor_samples_per_s": figures["regressor_samples_per_s"] >= TARGETS["regressor_samples_per_s"],
        "consistent_fit_s": figures["consistent_fit_s"] <= TARGETS["consistent_fit_s"],
        "tau_hat_ns": figures["tau_hat_ns"] <= TARGETS["tau_hat_ns"],
    }
    load = os.getloadavg()[0]
    print("targets: " + ", ".join(f"{k} {'met' if v else 'NOT met'}" for k, v in met.items()))
    print(f"load average while running: {load:.2f} on {os.cpu_count()} CPUs (timings scale with it)")
    payload = {"figures": figures, "fits_s": fits, "targets": TARGETS, "met": met, "load_average": load}
    write_json(args.json, payload)
    return 0


if __name__ == "__main__":
    sys.exit(main())
