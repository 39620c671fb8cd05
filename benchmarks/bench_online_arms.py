"""Benchmark (not a test): the generated `pi_update` of a 7-joint arm (the KUKA LWR4+, 69 base parameters) against a
from-scratch re-solve, with N = 10³, 10⁴, 10⁵ samples already seen, side by side in one run.

    .venv/bin/python benchmarks/bench_online_arms.py [--out results] [--steps K] [--repeats R] [--quick]

For each N: the offline state of N samples (the square-root factor of their base-regressor rows, folded in chunks)
is baked into a freshly generated and compiled `pi_update`; its example program then folds K more samples from a
CSV in a C loop (best of R runs): the time per update with the regressor, the regressor alone, and the update
alone (their difference). Beside it, after the same N + k samples: the from-scratch re-solves a batch method would
run per sample — the square-root factor of all N + k rows by QR plus the bounded solve (`FactorBoundedLS`), and the
normal equations summed from all rows plus `solve_bounded` — best of a few. Agreement: the C parameters after the K
updates against the from-scratch QR solve on the same N + K rows, per parameter against its size or, nearer 0, its
standard error. Data: random states within the KUKA's limits, torques of the arm at its OLS base parameters from the
real recording 1 (8 of its sign bounds active, as on the real data) plus 0.3 N·m noise.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one BLAS thread: on a shared machine threads mostly wait for cores

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ident_opt.adaptation import c_update  # noqa: E402
from ident_opt.adaptation.estimator import base_bounds  # noqa: E402
from ident_opt.adaptation.replay import _standard_errors  # noqa: E402
from ident_opt.adaptation.start import offline_start  # noqa: E402
from ident_opt.data.loader import load_dataset  # noqa: E402
from ident_opt.excitation.setup import random_states  # noqa: E402
from ident_opt.fitting.bounded import KKT_TOL, FactorBoundedLS, solve_bounded  # noqa: E402
from ident_opt.fitting.stats import Stats  # noqa: E402
from ident_opt.problem import load_problem  # noqa: E402
from ident_opt.report import record  # noqa: E402
from ident_opt.shipping.pi_update import _run_example  # noqa: E402

PROBLEM = ROOT / "problems" / "kuka_lwr4.toml"
SIZES = (1_000, 10_000, 100_000)
CHUNK = 5_000
FILES = ("online_arms_benchmark.md", "online_arms_benchmark.json")


class Data:
    """The KUKA's base design and bounds, and a generator of random samples (q, dq, ddq, τ) within its limits."""

    def __init__(self, seed: int = 0):
        problem = load_problem(PROBLEM)
        self.arm = problem.robot.arm
        real = load_dataset(problem.data.training[0], problem.data, problem.robot)
        start = offline_start("pbr", problem, real)
        self.design, self.bounds, self.names = start.design, start.estimator.bounds, start.names
        free = FactorBoundedLS(base_bounds(self.arm, start.base), *self._rows(real))
        free.bounds = type(self.bounds)(np.full(len(self.names), -np.inf), np.full(len(self.names), np.inf))
        self.theta = free.solve().pi  # OLS on the base parameters: some sign-bounded ones negative
        self.limits = problem.limits
        self.rng = np.random.default_rng(seed)

    def _rows(self, data):
        return self.design(data.q, data.dq, data.ddq), data.tau

    def samples(self, n: int):
        """n random samples: q, dq, ddq, τ (n, 7) each, and the design rows D (n, 7, P)."""
        q, dq, ddq = random_states(self.limits, n, self.rng)
        D = self.design(q, dq, ddq)
        tau = D @ self.theta + 0.3 * self.rng.standard_normal(q.shape)
        return q, dq, ddq, tau, D


def factor_of(data: Data, rows: list) -> FactorBoundedLS:
    """The square-root factor of every (D, τ) chunk of `rows`, solved."""
    f = FactorBoundedLS(data.bounds, *rows[0])
    for D, tau in rows[1:]:
        f.fold(D, tau)
    f.last = f.solve()
    return f


def from_scratch(data: Data, rows: list, repeats: int) -> dict:
    """Seconds of the two from-scratch re-solves on every row (best of `repeats`), and the QR solve's θ."""
    qr, normal, theta = np.inf, np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        f = factor_of(data, rows)
        qr = min(qr, time.perf_counter() - t0)
        theta = f.last.pi
        t0 = time.perf_counter()
        stats = Stats.from_regressor(*rows[0])
        for D, tau in rows[1:]:
            stats = stats + Stats.from_regressor(D, tau)
        H, h, _ = stats.combined()
        solve_bounded(H, h, data.bounds)
        normal = min(normal, time.perf_counter() - t0)
    return {"qr_s": qr, "normal_s": normal, "theta": theta}


def run_c(data: Data, rows: list, new: tuple, folder: Path, repeats: int) -> dict:
    """Generate pi_update with the state of `rows`, fold the samples `new` in its example's C loop."""
    f = factor_of(data, rows)
    n = sum(len(tau) for _, tau in rows)
    state = c_update.UpdateState(
        None, f.h, f.last.pi, f.last.state, n, data.bounds.lower, data.bounds.upper, f.R, f.z, f.hdiag
    )
    c_update.generate_pi_update(data.arm, state, folder, KKT_TOL, data.design.columns)
    _, example = c_update.compile_pi_update(folder)
    q, dq, ddq, tau, _ = new
    J = q.shape[1]
    header = ",".join(f"{k}{j + 1}" for k in ("q", "dq", "ddq", "tau") for j in range(J))
    csv = folder / "samples.csv"
    np.savetxt(csv, np.hstack([q, dq, ddq, tau]), delimiter=",", header=header, comments="", fmt="%.17g")
    runs = [_run_example(example, csv) for _ in range(repeats)]
    best = min(runs, key=lambda r: r["ns_per_update"])
    return {
        "ns_per_update": best["ns_per_update"],
        "cpu_ns_per_update": min(r["cpu_ns_per_update"] for r in runs),
        "ns_regressor": min(r["ns_regressor"] for r in runs),
        "theta": np.array([best["parameters"][name] for name in data.names]),
        "failed": best["failed"],
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "results"))
    ap.add_argument("--steps", type=int, default=2000, help="updates timed per N")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="N = 10³ and 10⁴ only, fewer steps")
    args = ap.parse_args(argv)
    sizes = SIZES[:2] if args.quick else SIZES
    steps = 300 if args.quick else args.steps
    data = Data()
    rows: list = []
    seen, out_rows = 0, []
    load = os.getloadavg()[0]
    for N in sizes:
        while seen < N:
            m = min(CHUNK, N - seen)
            _, _, _, tau, D = data.samples(m)
            rows.append((D, tau))
            seen += m
        new = data.samples(steps)
        with tempfile.TemporaryDirectory(prefix="ident_opt_bench_") as tmp:
            c = run_c(data, rows, new, Path(tmp), args.repeats)
        scratch = from_scratch(data, [*rows, (new[4], new[3])], max(1, args.repeats // 2))
        A = np.concatenate([D for D, _ in rows] + [new[4]])
        T = np.concatenate([t for _, t in rows] + [new[3]])
        se = _standard_errors(A, T, scratch["theta"])
        agree = float(np.max(np.abs(c["theta"] - scratch["theta"]) / np.maximum(np.abs(scratch["theta"]), se)))
        update_us = (c["ns_per_update"] - c["ns_regressor"]) / 1e3
        row = {
            "N": N,
            "c_us_per_update": c["ns_per_update"] / 1e3,
            "c_cpu_us_per_update": c["cpu_ns_per_update"] / 1e3,
            "c_us_regressor": c["ns_regressor"] / 1e3,
            "c_us_update_alone": update_us,
            "scratch_qr_us": scratch["qr_s"] * 1e6,
            "scratch_normal_us": scratch["normal_s"] * 1e6,
            "ratio_qr": scratch["qr_s"] * 1e6 / (c["ns_per_update"] / 1e3),
            "ratio_normal": scratch["normal_s"] * 1e6 / (c["ns_per_update"] / 1e3),
            "agreement_size_or_se": agree,
            "failed": c["failed"],
            "active_bounds": int(np.sum(np.abs(c["theta"]) == 0.0)),
        }
        out_rows.append(row)
        print(json.dumps({k: (float(f"{v:.4g}") if isinstance(v, float) else v) for k, v in row.items()}), flush=True)
    summary = {
        "max_c_us_per_update": max(r["c_us_per_update"] for r in out_rows),
        "max_c_cpu_us_per_update": max(r["c_cpu_us_per_update"] for r in out_rows),
        "max_c_us_update_alone": max(r["c_us_update_alone"] for r in out_rows),
        "flatness_last_over_first": out_rows[-1]["c_us_per_update"] / out_rows[0]["c_us_per_update"],
        "max_agreement": max(r["agreement_size_or_se"] for r in out_rows),
        "parameters": len(data.names),
        "steps": steps,
        "repeats": args.repeats,
        "load_average_at_start": load,
        "cflags": list(c_update.UPDATE_CFLAGS),
    }
    print(json.dumps(summary, indent=1))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / FILES[1]).write_text(json.dumps({"rows": out_rows, "summary": summary}, indent=1) + "\n")
    lines = [
        "# The generated update of a 7-joint arm vs a from-scratch re-solve (`benchmarks/bench_online_arms.py`)",
        "",
        f"KUKA LWR4+, {summary['parameters']} base parameters; {steps} updates timed per N from the example's C loop "
        f"(best of {args.repeats}; built with {' '.join(c_update.UPDATE_CFLAGS)}); load average "
        f"{load:.1f} on this 2-core machine at the start.",
        "",
        "| N seen | C per update [µs] | its CPU time [µs] | regressor [µs] | update alone [µs] | from scratch, QR "
        "[µs] | from scratch, normal equations [µs] | × QR | × normal | C vs from scratch (size or SE) | "
        "bounds active |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in out_rows:
        lines.append(
            f"| {r['N']:,} | {r['c_us_per_update']:.2f} | {r['c_cpu_us_per_update']:.2f} | {r['c_us_regressor']:.2f} | "
            f"{r['c_us_update_alone']:.2f} | "
            f"{r['scratch_qr_us']:.0f} | {r['scratch_normal_us']:.0f} | {r['ratio_qr']:.0f} | {r['ratio_normal']:.0f} "
            f"| {r['agreement_size_or_se']:.1e} | {r['active_bounds']} |"
        )
    lines += [
        "",
        f"Largest C time per update {summary['max_c_us_per_update']:.2f} µs with the regressor (target ≤ 10; its CPU "
        f"time {summary['max_c_cpu_us_per_update']:.2f} µs), "
        f"{summary['max_c_us_update_alone']:.2f} µs without; flatness (last N ÷ first) "
        f"{summary['flatness_last_over_first']:.2f}.",
        "",
    ]
    (out / FILES[0]).write_text("\n".join(lines), encoding="utf-8")
    record(out, "online_arms_benchmark", "the 7-joint generated update against a from-scratch re-solve", FILES)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
