"""Benchmark: the generated contact observer `observer_step` (`ident-opt codegen`), ns per call from a C loop, and
its agreement with Python, on the planar two-link arm and the 6- and 7-joint arms.

Run: .venv/bin/python benchmarks/bench_contacts.py [--calls 200000]
Per arm: a 20 s contact-free simulated trial trains the recommended fit and calibrates the thresholds; a 10 s trial
with a push every 3 s is run through the compiled step (from a zero state) and through the Python watch
(`contact.casadi_step.check`); a C loop then calls `observer_step` on that trial's samples, cycled, `--calls` times
(best of 3 runs), compiled with the generated library's own flags (`cbuild.CFLAGS`).
"""

from __future__ import annotations

import argparse
import subprocess
import tempfile
from pathlib import Path

import numpy as np

import ident_opt as iopt
from ident_opt.cbuild import CFLAGS, compile_library, find_compiler, generate_sources, load_external
from ident_opt.contact.casadi_step import check, for_codegen, state_size
from ident_opt.simulator.trial import simulate_trial

ROOT = Path(__file__).resolve().parents[1]
ARMS = {"planar (2)": "tudor_sim.toml", "TX40 (6)": "staubli_tx40.toml", "KUKA LWR4+ (7)": "kuka_lwr4.toml"}

MAIN = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <string.h>
#include <time.h>
#include "obs.h"
#define N %(n)d
#define S %(s)d
#define K %(k)d
static const double Q[K][N] = {%(q)s}, DQ[K][N] = {%(dq)s}, TAU[K][N] = {%(tau)s};
int main(int argc, char** argv) {
  long calls = %(calls)d;
  double state[S] = {0}, next[S], tau_ext[N], alarm = 0, sum = 0;
  const casadi_real* arg[observer_step_SZ_ARG + 1];
  casadi_real* res[observer_step_SZ_RES + 1];
  casadi_int iw[observer_step_SZ_IW + 1];
  casadi_real w[observer_step_SZ_W + 1];
  struct timespec a, b;
  clock_gettime(CLOCK_MONOTONIC, &a);
  for (long i = 0; i < calls; ++i) {
    long k = i %% K;
    arg[0] = Q[k]; arg[1] = DQ[k]; arg[2] = TAU[k]; arg[3] = state;
    res[0] = tau_ext; res[1] = next; res[2] = &alarm;
    observer_step(arg, res, iw, w, 0);
    memcpy(state, next, sizeof state);
    sum += tau_ext[0] + alarm;
  }
  clock_gettime(CLOCK_MONOTONIC, &b);
  printf("%%.3f %%g\n", ((b.tv_sec - a.tv_sec) * 1e9 + (b.tv_nsec - a.tv_nsec)) / calls, sum);
  return 0;
}
"""


def _rows(a: np.ndarray) -> str:
    return ",".join("{" + ",".join(repr(float(v)) for v in row) + "}" for row in a)


def time_step(step, trial, calls: int, folder: Path) -> float:
    """ns per call of `step` (a CasADi Function) from a C loop over the trial's first 1000 samples, best of 3."""
    source, _ = generate_sources([step], folder, "obs")
    n, k = trial.q.shape[1], min(1000, trial.n)
    main = MAIN % {
        "n": n,
        "s": state_size(n),
        "k": k,
        "q": _rows(trial.q[:k]),
        "dq": _rows(trial.dq[:k]),
        "tau": _rows(trial.tau[:k]),
        "calls": calls,
    }
    (folder / "main.c").write_text(main)
    exe = folder / "bench"
    subprocess.run([*find_compiler(), *CFLAGS, str(folder / "main.c"), str(source), "-o", str(exe), "-lm"], check=True)
    return min(
        float(subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout.split()[0])
        for _ in range(3)
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=200000)
    args = parser.parse_args()
    print(f"{'arm':<16} {'ns/call':>9} {'C vs Python':>12} {'alarm samples':>14} {'mismatches':>10}")
    for name, path in ARMS.items():
        problem = iopt.load_problem(ROOT / "problems" / path)
        effects = list(problem.simulate.effects) if problem.simulate is not None else []
        train = simulate_trial(problem.robot, duration=20, seed=1, effects=effects, progress=False).dataset()
        push = "contact:joint=2,torque=%g,start=1.5,duration=0.5,every=3" % (0.4 * np.abs(train.tau[:, 1]).max())
        test = simulate_trial(problem.robot, duration=10, seed=2, effects=[*effects, push], progress=False).dataset()
        fit = iopt.fit(problem, [train])
        step, watch, _ = for_codegen(fit.model, fit.pi, [train])
        with tempfile.TemporaryDirectory() as tmp:
            ns = time_step(step, test, args.calls, Path(tmp))
            source, _ = generate_sources([step], Path(tmp), "obs")
            found = check(
                load_external(compile_library(source, Path(tmp), name="obs"), "observer_step"),
                watch,
                test.q,
                test.dq,
                test.tau,
            )
        print(
            f"{name:<16} {ns:>9.1f} {found['max_relative_difference']:>12.2e} {found['alarm_samples']:>14d} "
            f"{found['alarm_mismatches']:>10d}",
            flush=True,
        )


if __name__ == "__main__":
    main()
