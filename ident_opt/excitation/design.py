"""Excitation design: the periodic trajectory to run next, optimised by IPOPT (CasADi) within the problem's limits.

The trajectory is a finite Fourier series per joint (`ident_opt.simulator.fourier.Fourier`, Swevers style, with
offsets), at rest at its start and end. Its coefficients x are the NLP's variables. Criteria:

- ``d`` (D-optimality): maximise log det of the per-sample information matrix of the base parameters,
  F = (1/N) Σ_k Y_B,kᵀ W Y_B,k with W = diag(1/σ_j²). Noise model: independent Gaussian torque noise per
  joint j with standard deviation σ_j, the RMS residual of the datasheet model on the problem's first
  trial when it has data, else 1 N m (`noise_from_data`). Y_B holds the base columns of the model's
  regressor: a pivoted QR of the column-equilibrated regressor at random states in the limits picks the
  independent columns (`base_columns`), so F is non-singular.
- ``cond``: minimise the condition number of the column-equilibrated regressor (the anchors' criterion,
  `fitting.fit.base_combinations`), through a smooth surrogate in the NLP: the p-norm estimate
  ½ log(λ_max/λ_min) ≈ (log tr G^p + log tr G^-p)/(2p) of the equilibrated G = E YᵀY E, p = 8.
- ``discriminate``: T-optimal design between two causes (`discrimination.py`'s objective).

Both log det and cond are reported for every design, computed on the output grid of the whole duration.

Limits (`problem.Limits`): joint angles, |dq|, |ddq| and |τ| of the datasheet model, imposed on a grid of
`CONSTRAINT_HZ` over one period (the trajectory is periodic, so one period is all of it) with `SAFETY` of each
limit kept free, then checked on a 1 kHz grid; a design that crosses a limit there is scaled down towards its
offsets until it does not. Several random starts (each scaled into the limits); the best feasible design is
kept. An infeasible torque limit (below what gravity needs at rest everywhere in the position limits) is an
`InputError` naming the key.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from ident_opt.errors import InputError
from ident_opt.excitation.information import criteria, information_callback, torque_callback
from ident_opt.excitation.setup import (
    CHECK_HZ,
    CONSTRAINT_HZ,
    CRITERIA,
    SAFETY,
    Setup,
    _grid,
    poses,
)

#: IPOPT's iteration limit per start.
MAX_ITER = 200
#: Samples per block when the datasheet model's torques are predicted over a grid (`limit_values`): bounds the
#: regressor's temporary memory (N × n × P doubles) to a few tens of MB whatever the duration and rate.
PREDICT_BLOCK = 4096


@dataclass
class Design:
    """One designed trajectory: coefficients, samples at the output rate, criteria, limits' margins, how the
    search went. Units: t [s], q [rad], dq [rad/s], ddq [rad/s²], tau [N m] (datasheet feed-forward)."""

    criterion: str
    x: np.ndarray
    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    tau: np.ndarray
    criteria: dict
    start_criteria: dict
    margins: dict
    starts: list[dict]
    status: str
    converged: bool
    seconds: float
    warnings: list[str] = field(default_factory=list)
    discrimination: dict | None = None
    setup: Setup | None = None  # what it was designed on (the model, limits, noise, base parameters)


# ---------------------------------------------------------------------------------------------- the NLP
def constraint_rate(setup: Setup) -> float:
    """The NLP's limit grid [Hz]: `CONSTRAINT_HZ`, or 12 samples per period of the highest harmonic if faster."""
    return max(CONSTRAINT_HZ, 12.0 * setup.fourier.harmonics * setup.fourier.base_hz)


def _trajectory_mx(setup: Setup, x: ca.MX, t: np.ndarray) -> tuple[ca.MX, ca.MX, ca.MX]:
    """q, dq, ddq as MX (n × N) of the coefficients x at times t."""
    f = setup.fourier
    B = [ca.DM(b) for b in f.basis(t)]
    rows = [[b @ x[f.joint_slice(j)] for j in range(f.n_joints)] for b in B]
    return tuple(ca.horzcat(*r).T for r in rows)


def _limit_bounds(setup: Setup, n: int) -> tuple[list, list, list[str]]:
    """Lower and upper bounds of the stacked limit constraints (q, dq, ddq, τ per joint on n grid points)."""
    lim, lo, hi, names = setup.limits, [], [], []
    for j in range(setup.fourier.n_joints):
        margin = SAFETY * (lim.position_max[j] - lim.position_min[j])
        bounds = [
            ("position", lim.position_min[j] + margin, lim.position_max[j] - margin),
            ("velocity", -lim.velocity[j] * (1 - SAFETY), lim.velocity[j] * (1 - SAFETY)),
            ("acceleration", -lim.acceleration[j] * (1 - SAFETY), lim.acceleration[j] * (1 - SAFETY)),
        ]
        if lim.torque is not None:
            bounds.append(("torque", -lim.torque[j] * (1 - SAFETY), lim.torque[j] * (1 - SAFETY)))
        for name, a, b in bounds:
            lo += [a] * n
            hi += [b] * n
            names += [f"{name}{j + 1}"] * n
    return lo, hi, names


def build_nlp(
    setup: Setup, objective: Callable[[ca.MX], ca.MX], max_iter: int = MAX_ITER, expand: bool = False
) -> tuple[ca.Function, list, list]:
    """(IPOPT solver, lbg, ubg) for minimising `objective(x)` within the limits and at rest at t = 0: angles, speeds
    and accelerations are linear in x; the nominal torques come from `torque_callback` (`expand`: evaluate the rest
    as SX; not with a callback in the objective)."""
    f = setup.fourier
    x = ca.MX.sym("x", f.size)
    tc = _grid(setup, constraint_rate(setup))
    q, dq, ddq = _trajectory_mx(setup, x, tc)
    tau, keep = None, []
    if setup.limits.torque is not None:
        keep.append(torque_callback(setup, tc))
        tau = ca.reshape(keep[-1](x), f.n_joints, len(tc))
    g = []
    for j in range(f.n_joints):  # in the order of `_limit_bounds`
        g += [q[j, :].T, dq[j, :].T, ddq[j, :].T] + ([] if tau is None else [tau[j, :].T])
    lbg, ubg, _ = _limit_bounds(setup, len(tc))
    A = f.rest_matrix()
    g.append(ca.DM(A) @ x)
    lbg += [0.0] * A.shape[0]
    ubg += [0.0] * A.shape[0]
    opts = {
        "ipopt.print_level": 0,
        "print_time": False,
        "ipopt.sb": "yes",
        "ipopt.max_iter": max_iter,
        "ipopt.tol": 1e-5,
        "ipopt.acceptable_tol": 1e-3,
        "ipopt.acceptable_iter": 5,
        "ipopt.hessian_approximation": "limited-memory",
        "expand": expand and tau is None,
    }
    solver = ca.nlpsol("excite", "ipopt", {"x": x, "f": objective(x), "g": ca.vertcat(*g)}, opts)
    return Solver(solver, [*keep, getattr(objective, "callback", None)]), lbg, ubg


class Solver:
    """A CasADi NLP solver with the Python callbacks its graph calls (CasADi keeps no reference to them)."""

    def __init__(self, solver: ca.Function, callbacks: list):
        self.solver, self.callbacks = solver, callbacks

    def __call__(self, **kwargs):
        """The solver's answer for its keyword inputs (x0, lbg, ubg, …)."""
        return self.solver(**kwargs)

    def stats(self) -> dict:
        """IPOPT's statistics of the last solve."""
        return self.solver.stats()


def information_objective(setup: Setup, criterion: str) -> Callable[[ca.MX], ca.MX]:
    """x -> the NLP objective of `criterion` ("d": −log det F; "cond": the surrogate of log cond)
    (`information_callback`)."""
    callback = information_callback(setup, criterion)

    def objective(x: ca.MX) -> ca.MX:
        return callback(x)

    objective.callback = callback  # `build_nlp` keeps it alive with the solver
    return objective


# ---------------------------------------------------------------------------------------------- limits
def limit_values(setup: Setup, x: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
    """q, dq, ddq and the datasheet τ (N, n) of coefficients x at times t."""
    t = np.asarray(t, dtype=float)
    out = {
        key: np.empty((len(t), setup.fourier.n_joints)) for key in ("position", "velocity", "acceleration", "torque")
    }
    # In blocks: the Fourier basis is 3 (N, 2H + 1) doubles and the model's regressor (N, n, P) (5 kB a sample on a
    # 7-joint arm), where the samples kept are 32 n bytes each.
    for k in range(0, len(t), PREDICT_BLOCK):
        block = slice(k, k + PREDICT_BLOCK)
        q, dq, ddq = setup.fourier.evaluate(x, t[block])
        out["position"][block], out["velocity"][block], out["acceleration"][block] = q, dq, ddq
        out["torque"][block] = setup.torque_model.predict(setup.pi_datasheet, q, dq, ddq)
    return out


def margins(setup: Setup, x: np.ndarray, rate: float = CHECK_HZ) -> dict[str, dict]:
    """Per limit: the least distance to it over one period at `rate` [Hz], per joint, in the limit's unit and as
    a fraction of the limit (of the range for positions); negative means crossed."""
    lim, v = setup.limits, limit_values(setup, x, _grid(setup, rate))
    lo, hi = np.array(lim.position_min), np.array(lim.position_max)
    out = {
        "position": np.minimum(v["position"].min(0) - lo, hi - v["position"].max(0)),
        "velocity": np.array(lim.velocity) - np.abs(v["velocity"]).max(0),
        "acceleration": np.array(lim.acceleration) - np.abs(v["acceleration"]).max(0),
    }
    scale = {"position": hi - lo, "velocity": np.array(lim.velocity), "acceleration": np.array(lim.acceleration)}
    if lim.torque is not None:
        out["torque"] = np.array(lim.torque) - np.abs(v["torque"]).max(0)
        scale["torque"] = np.array(lim.torque)
    units = {"position": "rad", "velocity": "rad/s", "acceleration": "rad/s^2", "torque": "N m"}
    return {
        k: {"margin": m.tolist(), "fraction": (m / scale[k]).tolist(), "unit": units[k], "rate_hz": rate}
        for k, m in out.items()
    }


def feasible(setup: Setup, x: np.ndarray, rate: float = CHECK_HZ) -> bool:
    """Every limit respected at `rate` [Hz] over a period."""
    return all(min(m["margin"]) >= 0 for m in margins(setup, x, rate).values())


def into_limits(setup: Setup, x: np.ndarray, target: float = 0.8) -> np.ndarray:
    """x's harmonics scaled per joint so that position deviation, speed and acceleration use at most `target` of
    their limits, then all together down until the torque fits too (when it can)."""
    f, lim = setup.fourier, setup.limits
    t = _grid(setup, constraint_rate(setup))
    q, dq, ddq = f.evaluate(x, t)
    centre = np.array([x[f.joint_slice(j)][0] for j in range(f.n_joints)])
    room = np.minimum(centre - np.array(lim.position_min), np.array(lim.position_max) - centre)
    ratio = np.max(
        [
            np.abs(q - centre).max(0) / np.maximum(room, 1e-9),
            np.abs(dq).max(0) / np.array(lim.velocity),
            np.abs(ddq).max(0) / np.array(lim.acceleration),
        ],
        axis=0,
    )
    x = f.scaled(x, target / np.maximum(ratio, 1e-12))
    for _ in range(30):
        if feasible(setup, x, constraint_rate(setup)):
            break
        x = f.scaled(x, 0.8)
    return x


def repaired(setup: Setup, x: np.ndarray) -> np.ndarray | None:
    """x if it respects every limit at 1 kHz, else x scaled down towards its offsets until it does (bisection on
    the factor); None when even the offsets alone cross a limit."""
    if feasible(setup, x):
        return x
    lo, hi = 0.0, 1.0
    if not feasible(setup, setup.fourier.scaled(x, 0.0)):
        return None
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if feasible(setup, setup.fourier.scaled(x, mid)) else (lo, mid)
    return setup.fourier.scaled(x, lo)


# ---------------------------------------------------------------------------------------------- design
def output_samples(setup: Setup, x: np.ndarray, rate: float) -> tuple[np.ndarray, ...]:
    """t, q, dq, ddq, τ over the whole duration at `rate` [Hz]."""
    t = np.arange(round(setup.duration * rate)) / rate
    v = limit_values(setup, x, t)
    return t, v["position"], v["velocity"], v["acceleration"], v["torque"]


def _score(criterion: str, values: dict) -> float:
    """Higher is better: log det for "d", −cond for "cond", the discrimination value otherwise."""
    if criterion == "d":
        return values["log_det"]
    if criterion == "cond":
        return -values["cond"]
    return values["discrimination"]


def cores() -> int:
    """The cores this process may run on (the default number of workers of `design`)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


#: The solver and its bounds while `_run_starts` forks its workers (they inherit it: a CasADi solver with Python
#: callbacks cannot be pickled).
_FORKED: tuple | None = None


def _solve_start(x0: np.ndarray, nlp: tuple | None = None) -> tuple[np.ndarray, dict]:
    """One IPOPT run of the NLP (`nlp` = (solver, lbg, ubg), else the forked `_FORKED`) from `x0`: its answer
    and a record (status, convergence, iterations, wall and CPU seconds)."""
    solver, lbg, ubg = nlp or _FORKED
    s0, c0 = time.perf_counter(), time.process_time()
    sol = solver(x0=x0, lbg=lbg, ubg=ubg)
    stats = solver.stats()
    return np.array(sol["x"]).ravel(), {
        "status": stats["return_status"],
        "converged": bool(stats["success"]),
        "iterations": int(stats["iter_count"]),
        "seconds": time.perf_counter() - s0,
        "cpu_seconds": time.process_time() - c0,
    }


def _run_starts(nlp: tuple, x0s: list[np.ndarray], workers: int, done: Callable[[], object]) -> list:
    """`_solve_start` from every start in `x0s`, in order; `workers` > 1: that many forked processes at once (each
    start's answer is the same as in one process: IPOPT is deterministic and the starts are drawn beforehand).

    A worker that dies (a crash inherited through the fork) breaks the pool instead of leaving it waiting for ever
    (`concurrent.futures`, unlike `multiprocessing.Pool`); the starts it did not answer then run here."""
    global _FORKED
    workers = min(workers, len(x0s))
    out: list = []
    if workers > 1 and "fork" in multiprocessing.get_all_start_methods():
        _FORKED = nlp
        try:
            with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork")) as pool:
                for answer in pool.map(_solve_start, x0s):
                    out.append(answer)
                    done()
        except BrokenProcessPool:
            pass  # out holds the answers that came back, in order; the rest run below
        finally:
            _FORKED = None
    for x0 in x0s[len(out) :]:
        out.append(_solve_start(x0, nlp))
        done()
    return out


def design(
    setup: Setup,
    criterion: str = "d",
    *,
    starts: int = 4,
    seed: int = 0,
    rate: float = CHECK_HZ,
    objective: Callable[[ca.MX], ca.MX] | None = None,
    evaluate: Callable[[np.ndarray, np.ndarray, np.ndarray], dict] | None = None,
    progress: bool = True,
    max_iter: int = MAX_ITER,
    expand: bool = False,
    workers: int = 1,
) -> Design:
    """The best of `starts` IPOPT runs from random feasible starts (seeded by `seed`), sampled at `rate` [Hz];
    `workers`: processes running the starts at once (`_run_starts`; the result does not depend on it).

    `objective` (x -> MX to minimise) and `evaluate` ((q, dq, ddq) -> criteria dict) default to the information
    criteria; the discrimination design passes its own. A start that does not converge still counts if its
    answer is feasible; the result says whether the kept one converged."""
    if criterion not in CRITERIA:
        raise InputError(f"--criterion {criterion!r}: known criteria are {', '.join(CRITERIA)}")
    t0 = time.perf_counter()
    evaluate = evaluate or (lambda q, dq, ddq: criteria(setup, q, dq, ddq))
    nlp = build_nlp(setup, objective or information_objective(setup, criterion), max_iter, expand)
    best, records = _search(setup, criterion, nlp, evaluate, starts, seed, progress, workers)
    if best is None:
        raise InputError(
            f"no start of the {criterion} design ended within the limits ({starts} starts); widen [limits] or "
            "try more starts"
        )
    x, kept = best
    samples = output_samples(setup, x, rate)  # t, q, dq, ddq, tau at the output rate
    warnings = []
    if not kept["converged"]:
        warnings.append(
            f"IPOPT did not converge on the kept start ({kept['status']}); kept the best feasible design found"
        )
    return Design(
        criterion,
        x,
        *samples,
        criteria=evaluate(*samples[1:4]) if evaluate is not None else {},
        start_criteria=kept["start_criteria"],
        margins=margins(setup, x),
        starts=records,
        status=kept["status"],
        converged=kept["converged"],
        seconds=time.perf_counter() - t0,
        warnings=warnings,
        setup=setup,
    )


def _search(
    setup: Setup,
    criterion: str,
    nlp: tuple,
    evaluate: Callable[[np.ndarray, np.ndarray, np.ndarray], dict],
    starts: int,
    seed: int,
    progress: bool,
    workers: int,
) -> tuple[tuple[np.ndarray, dict] | None, list[dict]]:
    """Seeded random starts near a rest pose, solved by `nlp` and judged on one BLAS thread: (best or None, records)."""
    rng = np.random.default_rng([seed, 15])
    centre = 0.5 * (np.array(setup.limits.position_min) + np.array(setup.limits.position_max))
    centre = rest_pose(setup, centre)
    grid = np.arange(round(setup.duration * 100.0)) / 100.0  # criteria on the whole duration at 100 Hz
    # One BLAS thread: the callbacks' matrices are small (r × r, r ≈ 70), and on a shared machine a threaded BLAS
    # mostly waits for cores (measured 30× slower per objective evaluation under load).
    blas = threadpool_limits(limits=1)
    x0s = [into_limits(setup, setup.fourier.random(rng, centre)) for _ in range(starts)]
    bar = tqdm(total=starts, desc=f"excite ({criterion})", disable=not progress, leave=False)
    runs = _run_starts(nlp, x0s, workers, bar.update)
    bar.close()
    best, records = _judge(setup, criterion, evaluate, grid, x0s, runs)
    blas.restore_original_limits()
    return best, records


def _judge(
    setup: Setup,
    criterion: str,
    evaluate: Callable[[np.ndarray, np.ndarray, np.ndarray], dict],
    grid: np.ndarray,
    x0s: list[np.ndarray],
    runs: list,
) -> tuple[tuple[np.ndarray, dict] | None, list[dict]]:
    """Each answer repaired into the limits and scored on `grid` (its start if IPOPT ended worse): (best, records)."""
    best, records = None, []
    for k, (x0, (answer, run)) in enumerate(zip(x0s, runs)):
        start_values = evaluate(*setup.fourier.evaluate(x0, grid))
        x = repaired(setup, answer)
        record = {"start": k, **run, "feasible": x is not None, "start_criteria": start_values}
        if x is not None:
            record["criteria"] = evaluate(*setup.fourier.evaluate(x, grid))
            if _score(criterion, start_values) > _score(criterion, record["criteria"]) and feasible(setup, x0):
                x, record["criteria"], record["kept_start"] = x0, start_values, True  # IPOPT ended worse
            if best is None or _score(criterion, record["criteria"]) > _score(criterion, best[1]["criteria"]):
                best = (x, record)
        records.append(record)
    return best, records


def rest_pose(setup: Setup, centre: np.ndarray) -> np.ndarray:
    """`centre` if the arm can rest there within the torque limit, else the nearest grid pose where it can."""
    lim = setup.limits
    if lim.torque is None:
        return centre
    q = poses(lim, 61, inset=3)
    tau = np.abs(setup.torque_model.predict(setup.pi_datasheet, q, np.zeros_like(q), np.zeros_like(q)))
    ok = np.all(tau <= 0.7 * np.array(lim.torque), axis=1)
    if not ok.any():
        ok = np.all(tau <= np.array(lim.torque) * (1 - 2 * SAFETY), axis=1)
    span = np.array(lim.position_max) - np.array(lim.position_min)
    d = np.where(ok, np.linalg.norm((q - centre) / span, axis=1), np.inf)
    return q[int(np.argmin(d))]
