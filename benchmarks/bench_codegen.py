"""Benchmark: the generated C (ns per call) next to the Python/NumPy model (per sample), in one run.

For K = 5, 10, 20 GMR components: identify π (physically consistent fit) and fit the GMR residual on the
problem's first trial, generate and compile the C code with the timing loop `benchmarks/c/bench_codegen.c`,
and run it. The same run times the Python path on the same data: `PlanarArm.predict` and `GMR.predict_mean`,
both vectorised over the whole trial (cost per sample) and called on one sample at a time (cost per call,
what a Python control loop would pay). Targets (issue 8): tau_hat ≤ 100 ns, tau_hat_gmr at K = 10 ≤ 2 µs.

    .venv/bin/python benchmarks/bench_codegen.py [--problem P] [--components 5 10 20] [--calls N] [--json F]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from timing import best_time  # noqa: E402

from ident_opt.arm.planar import RIGID  # noqa: E402
from ident_opt.commands.common import write_json  # noqa: E402
from ident_opt.data.loader import load_dataset  # noqa: E402
from ident_opt.fitting.constrained import fit_constrained  # noqa: E402
from ident_opt.fitting.stats import Stats  # noqa: E402
from ident_opt.models.gmr import GMR  # noqa: E402
from ident_opt.problem import load_problem  # noqa: E402
from ident_opt.shipping import codegen  # noqa: E402

TIMING_LOOP = ROOT / "benchmarks" / "c" / "bench_codegen.c"
TARGET_NS = {"tau_hat": 100.0, "tau_hat_gmr@10": 2000.0}


def python_costs(pi: np.ndarray, gmr: GMR, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> dict[str, float]:
    """Python/NumPy cost [ns]: per sample (vectorised over the trial) and per single-sample call."""
    X = np.hstack([q, dq, ddq])
    n, single = len(q), 300
    one = (q[:1], dq[:1], ddq[:1])
    return {
        "tau_hat per sample (vectorised)": best_time(lambda: RIGID.predict(pi, q, dq, ddq)) / n * 1e9,
        "tau_hat per call (1 sample)": best_time(lambda: [RIGID.predict(pi, *one) for _ in range(single)])
        / single
        * 1e9,
        "gmr mean per sample (vectorised)": best_time(lambda: gmr.predict_mean(X)) / n * 1e9,
        "gmr mean per call (1 sample)": best_time(lambda: [gmr.predict_mean(X[:1]) for _ in range(single)])
        / single
        * 1e9,
    }


def c_costs(pi: np.ndarray, gmr: GMR, compiler: list[str], calls: int) -> dict[str, float]:
    """Generate, compile with the timing loop (-O2, as firmware would), run: ns per call per function."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        source, _ = codegen.generate_sources(codegen.build_functions(RIGID, pi, gmr), out)
        exe = out / "bench"
        cmd = [
            *compiler,
            "-O2",
            "-std=c99",
            "-Wall",
            "-Wextra",
            "-Werror",
            f"-I{out}",
            str(TIMING_LOOP),
            "-x",
            "c",
            "-Wno-unused-parameter",
            str(source),
            "-o",
            str(exe),
            "-lm",
        ]
        subprocess.run(cmd, check=True)
        done = subprocess.run([str(exe), str(calls)], check=True, capture_output=True, text=True)
    return {line.split()[0]: float(line.split()[1]) for line in done.stdout.splitlines()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problem", default=str(ROOT / "problems" / "tudor_2dof.toml"))
    parser.add_argument("--components", type=int, nargs="+", default=[5, 10, 20])
    parser.add_argument("--calls", type=int, default=200000, help="C calls per timed repetition")
    parser.add_argument("--json", metavar="F", help="also write the figures as JSON")
    args = parser.parse_args(argv)

    problem = load_problem(args.problem)
    trial = load_dataset(problem.data.trials[0], problem.data, problem.robot)
    q, dq, ddq, tau = trial.q, trial.dq, trial.ddq, trial.tau
    pi = fit_constrained(Stats.from_data(RIGID, q, dq, ddq, tau), RIGID).pi
    X, R = np.hstack([q, dq, ddq]), tau - RIGID.predict(pi, q, dq, ddq)
    compiler = codegen.find_compiler()
    print(
        f"{trial.source}: {trial.n} samples; compiler {' '.join(compiler)}; {args.calls} C calls x 7 repetitions (best)"
    )

    rows = []
    for k in args.components:
        gmr = GMR(n_components=k, max_train_samples=4000).fit(X, R)
        c = c_costs(pi, gmr, compiler, args.calls)
        py = python_costs(pi, gmr, q, dq, ddq)
        rows.append({"K": k, "c_ns": c, "python_ns": py})
        print(f"\nK = {k}")
        print(
            f"  C      tau_hat {c['tau_hat']:9.1f} ns/call   tau_hat_gmr {c['tau_hat_gmr']:9.1f} ns/call   "
            f"ddq_hat {c['ddq_hat']:7.1f} ns/call"
        )
        for name, ns in py.items():
            print(f"  Python {name:34s} {ns:12.1f} ns")
        py_gmr = py["tau_hat per call (1 sample)"] + py["gmr mean per call (1 sample)"]
        print(
            f"  ratio  Python per call / C: tau_hat {py['tau_hat per call (1 sample)'] / c['tau_hat']:.0f}x, "
            f"tau_hat_gmr {py_gmr / c['tau_hat_gmr']:.0f}x"
        )

    tau_ns = min(r["c_ns"]["tau_hat"] for r in rows)
    gmr10 = [r["c_ns"]["tau_hat_gmr"] for r in rows if r["K"] == 10]
    print(
        f"\ntargets: tau_hat {tau_ns:.1f} ns (<= {TARGET_NS['tau_hat']:.0f}: "
        f"{'met' if tau_ns <= TARGET_NS['tau_hat'] else 'NOT met'})",
        end="",
    )
    if gmr10:
        ok = gmr10[0] <= TARGET_NS["tau_hat_gmr@10"]
        print(
            f"; tau_hat_gmr K=10 {gmr10[0]:.1f} ns (<= {TARGET_NS['tau_hat_gmr@10']:.0f}: {'met' if ok else 'NOT met'})"
        )
    else:
        print()
    write_json(args.json, {"samples": trial.n, "calls": args.calls, "rows": rows, "targets_ns": TARGET_NS})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
