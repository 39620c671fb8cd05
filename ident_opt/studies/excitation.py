"""Excitation design: the periodic trajectory to run next, optimised by IPOPT (CasADi) within the problem's limits.

The trajectory is a finite Fourier series per joint (`ident_opt.trajectory.Fourier`, Swevers style, with
offsets), at rest at its start and end. Its coefficients x are the NLP's variables. Criteria:

- ``d`` (D-optimality): maximise log det of the per-sample information matrix of the base parameters,
  F = (1/N) Σ_k Y_B,kᵀ W Y_B,k with W = diag(1/σ_j²). Noise model: independent Gaussian torque noise per
  joint j with standard deviation σ_j, the RMS residual of the datasheet model on the problem's first
  trial when it has data, else 1 N m (`noise_from_data`). Y_B holds the base columns of the model's
  regressor: a pivoted QR of the column-equilibrated regressor at random states in the limits picks the
  independent columns (`base_columns`), so F is non-singular.
- ``cond``: minimise the condition number of the column-equilibrated regressor (the anchors' criterion,
  `identify.fit.base_combinations`), through a smooth surrogate in the NLP: the p-norm estimate
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

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import scipy.linalg
from tqdm import tqdm

from ident_opt.arm.datasheet import PlanarRobot, datasheet_pi
from ident_opt.arm.planar import PHYSICAL, PlanarArm
from ident_opt.data import Dataset
from ident_opt.errors import InputError
from ident_opt.identify.fit import base_combinations
from ident_opt.problem.spec import Limits
from ident_opt.report import shown
from ident_opt.trajectory import Fourier, default_base_hz

CRITERIA = ("d", "cond", "discriminate")
#: Grid of the NLP's limits over one period [Hz] (the highest harmonic is far slower: at 0.5 Hz the worst
#: overshoot between grid points is (2π·0.5/20)²/8 ≈ 0.3 % of its amplitude, inside `SAFETY`; a finer grid
#: costs IPOPT time superlinearly, and the 1 kHz check has the final word).
CONSTRAINT_HZ = 20.0
#: Grid of the information matrix in the NLP over one period [Hz].
OBJECTIVE_HZ = 25.0
#: Fraction of each limit the NLP keeps free (the 1 kHz check has the final word).
SAFETY = 0.01
#: Rate the limits are checked at [Hz].
CHECK_HZ = 1000.0
#: Power of the smooth condition-number surrogate.
COND_POWER = 8
#: Random states for the base-column QR.
BASE_STATES = 2000
#: Relative diagonal of R below which a column is dependent (as `identify.fit.RANK_TOL`).
BASE_TOL = 1e-7
#: IPOPT's iteration limit per start.
MAX_ITER = 200


@dataclass(frozen=True)
class Setup:
    """What every design of one problem shares: the model, the datasheet torque model, limits, the series,
    the noise model (σ [N m] per joint, where it came from) and the base columns of the model's regressor."""

    arm: PlanarArm
    torque_model: PlanarArm
    pi_datasheet: np.ndarray
    limits: Limits
    fourier: Fourier
    duration: float
    sigma: np.ndarray
    noise: str
    base: tuple[int, ...]
    scale: np.ndarray  # per base column: 1/RMS at the random states (keeps the NLP's numbers near 1)

    @property
    def base_names(self) -> list[str]:
        """The names of the base columns (the parameters the information matrix is about)."""
        return [self.arm.names[i] for i in self.base]


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


# ---------------------------------------------------------------------------------------------- setup
def noise_from_data(trial: Dataset | None, robot: PlanarRobot, arm: PlanarArm = PHYSICAL) -> tuple[np.ndarray, str]:
    """(σ (n,) [N m], source): the RMS residual per joint of the datasheet model on `trial`, or 1 N m without data."""
    if trial is None:
        return np.ones(arm.n_joints), "unit (no data: σ = 1 N m per joint)"
    pi = arm.vector(datasheet_pi(robot))
    r = trial.tau - arm.predict(pi, trial.q, trial.dq, trial.ddq)
    sigma = np.sqrt(np.mean(r**2, axis=0))
    return np.maximum(sigma, 1e-6), f"RMS residual of the datasheet model on {shown(trial.source)}"


def random_states(limits: Limits, n: int, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """n states uniform in the limits: q, dq, ddq (n, joints) [rad, rad/s, rad/s²]."""
    lo, hi = np.array(limits.position_min), np.array(limits.position_max)
    v, a = np.array(limits.velocity), np.array(limits.acceleration)
    J = len(lo)
    return rng.uniform(lo, hi, (n, J)), rng.uniform(-v, v, (n, J)), rng.uniform(-a, a, (n, J))


def base_columns(arm: PlanarArm, limits: Limits, seed: int = 0) -> tuple[tuple[int, ...], np.ndarray]:
    """(indices of independent columns, 1/RMS of each at random states): pivoted QR of the column-equilibrated
    regressor at `BASE_STATES` random states within the limits."""
    Y = arm.regressor(*random_states(limits, BASE_STATES, np.random.default_rng([seed, 15])))
    A = Y.reshape(-1, arm.n_params)
    rms = np.sqrt(np.mean(A**2, axis=0))
    A = A / np.where(rms > 0, rms, 1.0)
    _, R, perm = scipy.linalg.qr(A, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > BASE_TOL * d[0]))
    base = tuple(sorted(int(i) for i in perm[:rank]))
    return base, 1.0 / rms[list(base)]


def make_setup(
    robot: PlanarRobot,
    limits: Limits,
    duration: float,
    *,
    harmonics: int = 5,
    base_hz: float | None = None,
    extensions: tuple[str, ...] = (),
    trial: Dataset | None = None,
) -> Setup:
    """The shared part of every design: model = the nominal structure (`robot.PHYSICAL`) with `extensions`."""
    arm = PlanarArm((*PHYSICAL.extensions, *extensions))
    sigma, noise = noise_from_data(trial, robot)
    base, scale = base_columns(arm, limits)
    fourier = Fourier(arm.n_joints, harmonics, base_hz or default_base_hz(duration))
    pi = PHYSICAL.vector(datasheet_pi(robot))
    setup = Setup(arm, PHYSICAL, pi, limits, fourier, duration, sigma, noise, base, scale)
    check_feasible(setup)
    return setup


def check_feasible(setup: Setup, grid: int = 61) -> None:
    """`InputError` naming `torque` in [limits] when no pose within the position limits can be held at rest
    within the torque limit (gravity alone needs more)."""
    lim = setup.limits
    if lim.torque is None:
        return
    axes = [np.linspace(a, b, grid) for a, b in zip(lim.position_min, lim.position_max)]
    q = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(axes))
    tau = np.abs(setup.torque_model.predict(setup.pi_datasheet, q, np.zeros_like(q), np.zeros_like(q)))
    allowed = np.array(lim.torque) * (1 - 2 * SAFETY)
    if np.any(np.all(tau <= allowed, axis=1)):
        return
    need = tau.min(axis=0)
    worst = int(np.argmax(need / allowed))
    raise InputError(
        f"key 'torque' in [limits]: joint {worst + 1} needs at least {need[worst]:.3g} N m to hold the arm at rest "
        f"anywhere within the position limits (gravity, datasheet model), above its limit {lim.torque[worst]:g} N m "
        f"less the {SAFETY:.0%} safety margin; no trajectory can start at rest"
    )


# ---------------------------------------------------------------------------------------------- criteria
def information(setup: Setup, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(F, H): F = (1/N) Σ Y_Bᵀ W Y_B of the base columns (own units, W = 1/σ²) and H = Σ_j Y_jᵀY_j (all columns)."""
    Y = setup.arm.regressor(q, dq, ddq)
    Yb = Y[:, :, list(setup.base)] / setup.sigma[None, :, None]
    F = np.einsum("njp,njr->pr", Yb, Yb) / len(q)
    H = np.einsum("njp,njr->pr", Y, Y)
    return F, H


def criteria(setup: Setup, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> dict:
    """log det F (base parameters, per sample, noise-weighted), cond of the column-equilibrated regressor and
    its rank (as `LinearFit.cond` / `.rank`)."""
    F, H = information(setup, q, dq, ddq)
    sign, logdet = np.linalg.slogdet(F)
    rank, cond, _, _ = base_combinations(H, setup.arm.names)
    return {"log_det": float(logdet) if sign > 0 else float("-inf"), "cond": float(cond), "rank": int(rank)}


def _cholesky_logdet_inv(G: ca.SX) -> tuple[ca.SX, ca.SX]:
    """(log det G, G⁻¹) of a symmetric positive definite SX matrix, by a scalar Cholesky factorisation."""
    n = G.shape[0]
    L = [[ca.SX(0) for _ in range(n)] for _ in range(n)]
    for i in range(n):
        for j in range(i + 1):
            s = G[i, j] - sum((L[i][k] * L[j][k] for k in range(j)), ca.SX(0))
            L[i][j] = ca.sqrt(ca.fmax(s, 1e-300)) if i == j else s / L[j][j]
    logdet = 2 * sum((ca.log(L[i][i]) for i in range(n)), ca.SX(0))
    Li = [[ca.SX(0) for _ in range(n)] for _ in range(n)]  # L⁻¹, lower triangular
    for i in range(n):
        Li[i][i] = 1 / L[i][i]
        for j in range(i):
            Li[i][j] = -sum((L[i][k] * Li[k][j] for k in range(j, i)), ca.SX(0)) / L[i][i]
    Linv = ca.vertcat(*[ca.horzcat(*row) for row in Li])
    return logdet, Linv.T @ Linv


def _matrix_power_trace(G: ca.SX, p: int) -> ca.SX:
    """tr(G^p) for p a power of 2, by squaring."""
    while p > 1:
        G, p = G @ G, p // 2
    return ca.trace(G)


def _objective_functions(setup: Setup) -> tuple[ca.Function, ca.Function]:
    """(per-sample information (q, dq, ddq) -> (Y_Bᵀ W Y_B, Y_Bᵀ Y_B) scaled, criterion (F_w, F_u) -> (−log det
    F_w, cond surrogate))."""
    s = setup.arm.symbols
    Yb = s["Y"][:, list(setup.base)] @ ca.diag(ca.DM(setup.scale))
    W = ca.diag(ca.DM(1.0 / setup.sigma**2))
    sample = ca.Function("info", [s["q"], s["dq"], s["ddq"]], [Yb.T @ W @ Yb, Yb.T @ Yb])
    r = len(setup.base)
    Fw, Fu = ca.SX.sym("Fw", r, r), ca.SX.sym("Fu", r, r)
    logdet, _ = _cholesky_logdet_inv(Fw)
    e = 1 / ca.sqrt(ca.diag(Fu))
    G = Fu * (e @ e.T)
    _, Ginv = _cholesky_logdet_inv(G)
    p = COND_POWER
    surrogate = (ca.log(_matrix_power_trace(G, p)) + ca.log(_matrix_power_trace(Ginv, p))) / (2 * p)
    return sample, ca.Function("criterion", [Fw, Fu], [-logdet, surrogate])


# ---------------------------------------------------------------------------------------------- the NLP
def constraint_rate(setup: Setup) -> float:
    """The NLP's limit grid [Hz]: `CONSTRAINT_HZ`, or 12 samples per period of the highest harmonic if faster."""
    return max(CONSTRAINT_HZ, 12.0 * setup.fourier.harmonics * setup.fourier.base_hz)


def _grid(setup: Setup, rate: float) -> np.ndarray:
    """Times over one period [s] at `rate` [Hz]."""
    period = setup.fourier.period
    return np.arange(int(np.ceil(period * rate))) * (period / np.ceil(period * rate))


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
    setup: Setup, objective: Callable[[ca.MX], ca.MX], max_iter: int = MAX_ITER, expand: bool = True
) -> tuple[ca.Function, list, list]:
    """(IPOPT solver, lbg, ubg) for minimising `objective(x)` within the limits and at rest at t = 0
    (`expand`: evaluate as SX, faster; not possible with a callback in the objective)."""
    f = setup.fourier
    x = ca.MX.sym("x", f.size)
    tc = _grid(setup, constraint_rate(setup))
    q, dq, ddq = _trajectory_mx(setup, x, tc)
    tau = None
    if setup.limits.torque is not None:
        m = setup.torque_model
        qs, dqs, ddqs = m.symbols["q"], m.symbols["dq"], m.symbols["ddq"]
        tau_f = ca.Function("tau", [qs, dqs, ddqs], [m.tau_expression(qs, dqs, ddqs, ca.DM(setup.pi_datasheet))])
        tau = tau_f.map(len(tc))(q, dq, ddq)
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
        "expand": expand,
    }
    solver = ca.nlpsol("excite", "ipopt", {"x": x, "f": objective(x), "g": ca.vertcat(*g)}, opts)
    return solver, lbg, ubg


def information_objective(setup: Setup, criterion: str) -> Callable[[ca.MX], ca.MX]:
    """x -> the NLP objective of `criterion` ("d": −log det F; "cond": the surrogate of log cond)."""
    sample, crit = _objective_functions(setup)
    to = _grid(setup, OBJECTIVE_HZ)
    n = len(to)
    summed = sample.map("info_sum", "serial", n, [], [0, 1])

    def objective(x: ca.MX) -> ca.MX:
        q, dq, ddq = _trajectory_mx(setup, x, to)
        Fw, Fu = summed(q, dq, ddq)
        out = crit(Fw / n, Fu / n)
        return out[0] if criterion == "d" else out[1]

    return objective


# ---------------------------------------------------------------------------------------------- limits
def limit_values(setup: Setup, x: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
    """q, dq, ddq and the datasheet τ (N, n) of coefficients x at times t."""
    q, dq, ddq = setup.fourier.evaluate(x, t)
    tau = setup.torque_model.predict(setup.pi_datasheet, q, dq, ddq)
    return {"position": q, "velocity": dq, "acceleration": ddq, "torque": tau}


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
    expand: bool = True,
) -> Design:
    """The best of `starts` IPOPT runs from random feasible starts (seeded by `seed`), sampled at `rate` [Hz].

    `objective` (x -> MX to minimise) and `evaluate` ((q, dq, ddq) -> criteria dict) default to the information
    criteria; the discrimination design passes its own. A start that does not converge still counts if its
    answer is feasible; the result says whether the kept one converged."""
    if criterion not in CRITERIA:
        raise InputError(f"--criterion {criterion!r}: known criteria are {', '.join(CRITERIA)}")
    t0 = time.perf_counter()
    evaluate = evaluate or (lambda q, dq, ddq: criteria(setup, q, dq, ddq))
    solver, lbg, ubg = build_nlp(setup, objective or information_objective(setup, criterion), max_iter, expand)
    rng = np.random.default_rng([seed, 15])
    centre = 0.5 * (np.array(setup.limits.position_min) + np.array(setup.limits.position_max))
    centre = _rest_pose(setup, centre)
    grid = np.arange(round(setup.duration * 100.0)) / 100.0  # criteria on the whole duration at 100 Hz
    best, records = None, []
    for k in tqdm(range(starts), desc=f"excite ({criterion})", disable=not progress, leave=False):
        x0 = into_limits(setup, setup.fourier.random(rng, centre))
        start_values = evaluate(*setup.fourier.evaluate(x0, grid))
        s0 = time.perf_counter()
        sol = solver(x0=x0, lbg=lbg, ubg=ubg)
        stats = solver.stats()
        x = repaired(setup, np.array(sol["x"]).ravel())
        record = {
            "start": k,
            "status": stats["return_status"],
            "converged": bool(stats["success"]),
            "iterations": int(stats["iter_count"]),
            "seconds": time.perf_counter() - s0,
            "feasible": x is not None,
            "start_criteria": start_values,
        }
        if x is not None:
            record["criteria"] = evaluate(*setup.fourier.evaluate(x, grid))
            if _score(criterion, start_values) > _score(criterion, record["criteria"]) and feasible(setup, x0):
                x, record["criteria"], record["kept_start"] = x0, start_values, True  # IPOPT ended worse
            if best is None or _score(criterion, record["criteria"]) > _score(criterion, best[1]["criteria"]):
                best = (x, record)
        records.append(record)
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
    )


def _rest_pose(setup: Setup, centre: np.ndarray) -> np.ndarray:
    """`centre` if the arm can rest there within the torque limit, else the nearest grid pose where it can."""
    lim = setup.limits
    if lim.torque is None:
        return centre
    axes = [np.linspace(a, b, 61)[3:-3] for a, b in zip(lim.position_min, lim.position_max)]
    q = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(axes))
    tau = np.abs(setup.torque_model.predict(setup.pi_datasheet, q, np.zeros_like(q), np.zeros_like(q)))
    ok = np.all(tau <= 0.7 * np.array(lim.torque), axis=1)
    if not ok.any():
        ok = np.all(tau <= np.array(lim.torque) * (1 - 2 * SAFETY), axis=1)
    span = np.array(lim.position_max) - np.array(lim.position_min)
    d = np.where(ok, np.linalg.norm((q - centre) / span, axis=1), np.inf)
    return q[int(np.argmin(d))]
