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
from pathlib import Path

import casadi as ca
import numpy as np
import scipy.linalg
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from ident_opt.arm.base import Arm, Robot
from ident_opt.cache import cache_root
from ident_opt.cbuild import CompiledRows
from ident_opt.data.dataset import Dataset
from ident_opt.errors import InputError
from ident_opt.fitting.base import ZERO_COLUMN
from ident_opt.fitting.fit import base_combinations
from ident_opt.outputs import shown
from ident_opt.problem.spec import Limits
from ident_opt.simulator.fourier import Fourier, default_base_hz

CRITERIA = ("d", "cond", "discriminate")
#: Grid of the NLP's limits over one period [Hz] (the highest harmonic is far slower: at 0.5 Hz the worst
#: overshoot between grid points is (2π·0.5/12)²/8 ≈ 0.9 % of its amplitude, inside `SAFETY`; IPOPT's time per
#: iteration grows with the number of limits (a 7-joint design: 0.2 s at 20 Hz, 0.1 s at 12 Hz on a loaded
#: machine), and the 1 kHz check has the final word).
CONSTRAINT_HZ = 12.0
#: Grid of the information matrix in the NLP over one period [Hz].
OBJECTIVE_HZ = 25.0
#: Fraction of each limit the NLP keeps free (the 1 kHz check has the final word).
SAFETY = 0.01
#: Rate the limits are checked at [Hz].
CHECK_HZ = 1000.0
#: Power of the smooth condition-number surrogate.
COND_POWER = 8
#: Speeds below this [rad/s] are rest for the nominal torque (the Coulomb term's sign is 0 there).
STILL = 1e-9
#: Eigenvalues of an information matrix below this fraction of its largest count as this fraction (log of 0).
TINY = 1e-300
#: Random states for the base-column QR.
BASE_STATES = 2000
#: Relative diagonal of R below which a column is dependent (as `fitting.fit.RANK_TOL`).
BASE_TOL = 1e-7
#: IPOPT's iteration limit per start.
MAX_ITER = 200
#: Poses searched for a rest pose within the torque limit (a grid for two joints, random for more).
MAX_POSES = 20000


@dataclass(frozen=True)
class Setup:
    """What every design of one problem shares: the model, the nominal torque model (`Robot.datasheets`: the planar
    arm's physical datasheet, an n-joint arm's URDF), limits, the series, the noise model (σ [N m] per joint, where
    it came from) and the base columns of the model's regressor."""

    arm: Arm
    torque_model: Arm
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
def noise_from_data(trial: Dataset | None, robot: Robot) -> tuple[np.ndarray, str]:
    """(σ (n,) [N m], source): the RMS residual per joint of the robot's nominal model (`Robot.datasheets`) on
    `trial`, or 1 N m without data."""
    arm, pi = robot.datasheets()[robot.datasheet]
    if trial is None:
        return np.ones(arm.n_joints), "unit (no data: σ = 1 N m per joint)"
    r = trial.tau - arm.predict(pi, trial.q, trial.dq, trial.ddq)
    sigma = np.sqrt(np.mean(r**2, axis=0))
    return np.maximum(sigma, 1e-6), f"RMS residual of the datasheet model on {shown(trial.source)}"


def random_states(limits: Limits, n: int, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """n states uniform in the limits: q, dq, ddq (n, joints) [rad, rad/s, rad/s²]."""
    lo, hi = np.array(limits.position_min), np.array(limits.position_max)
    v, a = np.array(limits.velocity), np.array(limits.acceleration)
    J = len(lo)
    return rng.uniform(lo, hi, (n, J)), rng.uniform(-v, v, (n, J)), rng.uniform(-a, a, (n, J))


def base_columns(arm: Arm, limits: Limits, seed: int = 0) -> tuple[tuple[int, ...], np.ndarray]:
    """(indices of independent columns, 1/RMS of each at random states): pivoted QR of the column-equilibrated
    regressor at `BASE_STATES` random states within the limits."""
    Y = arm.regressor(*random_states(limits, BASE_STATES, np.random.default_rng([seed, 15])))
    A = Y.reshape(-1, arm.n_params)
    rms = np.sqrt(np.mean(A**2, axis=0))
    # A column of round-off (gravity on a vertical axis: ~1e-14 of the others) is zero, as for the base parameters.
    nonzero = np.flatnonzero(rms > ZERO_COLUMN * rms.max())
    _, R, perm = scipy.linalg.qr(A[:, nonzero] / rms[nonzero], mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > BASE_TOL * d[0]))
    base = tuple(sorted(int(nonzero[i]) for i in perm[:rank]))
    return base, 1.0 / rms[list(base)]


def make_setup(
    robot: Robot,
    limits: Limits,
    duration: float,
    *,
    harmonics: int = 5,
    base_hz: float | None = None,
    extensions: tuple[str, ...] = (),
    trial: Dataset | None = None,
) -> Setup:
    """The shared part of every design: model = the structure of the robot's nominal model (`Robot.datasheets`: the
    planar arm's physical one with its armature, an n-joint arm's chain) with `extensions`; the nominal model gives
    the torques the limits apply to."""
    nominal, pi = robot.datasheets()[robot.datasheet]
    arm = robot.model((*nominal.extensions, *extensions))
    sigma, noise = noise_from_data(trial, robot)
    base, scale = base_columns(arm, limits)
    fourier = Fourier(arm.n_joints, harmonics, base_hz or default_base_hz(duration))
    setup = Setup(arm, nominal, np.asarray(pi, dtype=float), limits, fourier, duration, sigma, noise, base, scale)
    check_feasible(setup)
    return setup


def poses(limits: Limits, grid: int = 61, inset: int = 0) -> np.ndarray:
    """Poses q (N, n) [rad] within the position limits: the full grid of `grid` values per joint (less `inset` at
    each end) while it has at most `MAX_POSES` poses (the two-link arm), else `MAX_POSES` random ones (seeded) and
    the centre."""
    lo, hi = np.array(limits.position_min), np.array(limits.position_max)
    if (grid - 2 * inset) ** len(lo) <= MAX_POSES:
        axes = [np.linspace(a, b, grid)[inset : grid - inset] for a, b in zip(lo, hi)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(axes))
    margin = inset / (grid - 1) * (hi - lo)
    rng = np.random.default_rng([len(lo), 61])
    return np.vstack([0.5 * (lo + hi), rng.uniform(lo + margin, hi - margin, (MAX_POSES, len(lo)))])


def check_feasible(setup: Setup, grid: int = 61) -> None:
    """`InputError` naming `torque` in [limits] when no pose within the position limits (`poses`) can be held at
    rest within the torque limit (gravity alone needs more)."""
    lim = setup.limits
    if lim.torque is None:
        return
    q = poses(lim, grid)
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


class SampleFunctions:
    """Per-sample functions of a setup's arms, compiled to C once per machine (`cbuild.CompiledRows`, cached by
    their source's hash; CasADi's own evaluation where no C compiler works), each mapped over many samples at once:
    the states s = [q; dq; ddq] (3n) in, one small matrix out.

    - `columns(S)`: Y_B (N, n, r) of the model's base columns, scaled by `Setup.scale`;
    - `pullback(S, M)`: ∂/∂s Σ_jp M_jp Y_B,jp(s) (N, 3n), the gradient of an information criterion through Y_B;
    - `torques(S)`, `torque_jacobian(S)`: the nominal model's τ (N, n) and ∂τ/∂s (N, n, 3n)."""

    def __init__(self, setup: Setup):
        arm, nominal = setup.arm, setup.torque_model
        s = arm.symbols
        state = ca.vertcat(s["q"], s["dq"], s["ddq"])
        Yb = s["Y"][:, list(setup.base)] @ ca.diag(ca.DM(setup.scale))
        n, r = Yb.shape
        M = ca.SX.sym("M", n, r)
        self.n, self.r = n, r
        self._columns = _rows(ca.Function("excite_columns", [state], [ca.densify(Yb).T]))
        pull = ca.gradient(ca.sum1(ca.sum2(M * Yb)), state)
        self._pull = _rows(ca.Function("excite_pullback", [ca.vertcat(state, ca.vec(M))], [ca.densify(pull)]))
        t = nominal.symbols
        nominal_state = ca.vertcat(t["q"], t["dq"], t["ddq"])
        tau = nominal.tau_expression(t["q"], t["dq"], t["ddq"], ca.DM(setup.pi_datasheet))
        self._tau = _rows(ca.Function("excite_torques", [nominal_state], [ca.densify(tau)]))
        dtau = ca.densify(ca.jacobian(tau, nominal_state).T)  # dense: the compiled rows are read as full matrices
        self._dtau = _rows(ca.Function("excite_torque_jacobian", [nominal_state], [dtau]))

    def columns(self, S: np.ndarray) -> np.ndarray:
        """Y_B (N, n, r) at states S (N, 3n), the base columns scaled."""
        return self._columns(_at_rest(S, self.n))

    def pullback(self, S: np.ndarray, M: np.ndarray) -> np.ndarray:
        """∂/∂s Σ_jp M_jp Y_B,jp(s) (N, 3n) at states S (N, 3n) for weights M (N, n, r)."""
        flat = np.swapaxes(M, 1, 2).reshape(len(S), -1)  # CasADi's vec: column-major
        return self._pull(np.hstack([_at_rest(S, self.n), flat]))[:, 0, :]

    def torques(self, S: np.ndarray) -> np.ndarray:
        """The nominal model's τ (N, n) [N m] at states S (N, 3n)."""
        return self._tau(_at_rest(S, self.n))[:, 0, :]

    def torque_jacobian(self, S: np.ndarray) -> np.ndarray:
        """∂τ/∂s (N, n, 3n) at states S (N, 3n)."""
        return self._dtau(_at_rest(S, self.n))


def _at_rest(S: np.ndarray, n: int) -> np.ndarray:
    """S with speeds below `STILL` set to 0: the series is at rest at its ends up to the rest constraints' round-off,
    where the Coulomb terms' sign (in the torques and in the regressor) would otherwise follow that round-off from one
    iterate to the next, and IPOPT see a constraint or the objective jump."""
    S = S.copy()
    speeds = S[:, n : 2 * n]
    speeds[np.abs(speeds) < STILL] = 0.0
    return S


def _rows(function: ca.Function):
    """`function` (one sample's input column → one dense output) over many samples: X (N, k) → (N, c, r), each
    output transposed (`cbuild.CompiledRows`); CasADi's evaluation when it cannot be compiled."""
    try:
        return CompiledRows(function, cache_root(Path(__file__)) / "excitation")
    except (InputError, OSError):
        mapped = {}

        def evaluate(X: np.ndarray) -> np.ndarray:
            f = mapped.setdefault(len(X), function.map(len(X)))
            out = np.asarray(f(np.asarray(X, dtype=float).T))  # (r, c·N): sample k in columns k·c … k·c + c − 1
            r, c = function.size1_out(0), function.size2_out(0)
            return out.reshape(r, len(X), c).transpose(1, 2, 0)

        return evaluate


def criterion_value(criterion: str, Fw: np.ndarray, Fu: np.ndarray) -> tuple[float, np.ndarray]:
    """(value to minimise, its gradient with respect to F (r, r)) of "d": −log det Fw (Fw = Σ Y_Bᵀ W Y_B / N), or of
    "cond": the smooth surrogate ½ log(λ_max/λ_min) ≈ (log tr G^p + log tr G^-p)/(2p) of the equilibrated
    G = E Fu E, E = diag(Fu)^-½, p = `COND_POWER` (its gradient with respect to Fu)."""
    if criterion == "d":
        lam, V = np.linalg.eigh(Fw)
        lam = np.maximum(lam, TINY * max(lam.max(), TINY))
        return -float(np.log(lam).sum()), -(V / lam) @ V.T
    e = 1.0 / np.sqrt(np.maximum(np.diag(Fu), TINY))
    G = Fu * np.outer(e, e)
    lam, V = np.linalg.eigh(G)
    lam = np.maximum(lam, TINY * max(lam.max(), TINY))
    p = COND_POWER
    up, down = (lam / lam.max()) ** p, (lam.min() / lam) ** p  # scaled: the logs take the scales back
    value = (np.log(up.sum()) + p * np.log(lam.max()) + np.log(down.sum()) - p * np.log(lam.min())) / (2 * p)
    dphi = (V * ((up / lam) / up.sum() - (down / lam) / down.sum())) @ V.T / 2  # ∂value/∂G
    # G_kl = Fu_kl e_k e_l with e = Fu_kk^-½: back to Fu
    dF = dphi * np.outer(e, e)
    dF[np.diag_indices_from(dF)] -= e**2 * np.einsum("kl,kl->k", dphi, G)
    return float(value), dF


# ---------------------------------------------------------------------------------------------- numeric callbacks
class NumpyFunction(ca.Callback):
    """x (size) → y (m): a NumPy function `value(x)` as a CasADi function, with `jacobian(x)` (m, size) its
    Jacobian (exact here, so IPOPT calls compiled C through NumPy instead of CasADi's expression interpreter; the
    discrimination design's, central differences with its rivals held)."""

    def __init__(self, name: str, size: int, m: int, value, jacobian, opts: dict | None = None):
        ca.Callback.__init__(self)
        self._size, self._m, self._value, self._jac = size, m, value, jacobian
        self.construct(name, opts or {})

    def get_n_in(self) -> int:
        return 1

    def get_n_out(self) -> int:
        return 1

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self._size, 1)

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self._m, 1)

    def eval(self, arg):
        return [ca.DM(self._value(np.array(arg[0]).ravel()))]

    def has_jacobian(self) -> bool:
        return True

    def get_jacobian(self, name, inames, onames, opts):
        self._jacobian = _Jacobian(name, self._size, self._m, self._jac, opts)  # kept: CasADi holds no Python ref
        return self._jacobian


class _Jacobian(ca.Callback):
    """(x, y) → ∂y/∂x (m, size) for `NumpyFunction`."""

    def __init__(self, name: str, size: int, m: int, jacobian, opts: dict):
        ca.Callback.__init__(self)
        self._size, self._m, self._jac = size, m, jacobian
        self.construct(name, opts)

    def get_n_in(self) -> int:
        return 2

    def get_n_out(self) -> int:
        return 1

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self._size, 1) if i == 0 else ca.Sparsity.dense(self._m, 1)

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self._m, self._size)

    def eval(self, arg):
        return [ca.DM(self._jac(np.array(arg[0]).ravel()))]


class _Trajectory:
    """The states along the series at fixed times, and the chain rule back to its coefficients x."""

    def __init__(self, setup: Setup, t: np.ndarray):
        self.f = setup.fourier
        self.B = self.f.basis(t)  # (Bq, Bv, Ba), each (N, 2H + 1)

    def states(self, x: np.ndarray) -> np.ndarray:
        """S (N, 3n) = [q dq ddq] at the times."""
        return np.hstack(self.f.evaluate(x, None, self.B))

    def back(self, V: np.ndarray) -> np.ndarray:
        """Σ_k (∂s_k/∂x)ᵀ v_k for V (N, 3n) (a gradient with respect to the states): (size,)."""
        n = self.f.n_joints
        out = np.zeros(self.f.size)
        for j in range(n):
            sl = self.f.joint_slice(j)
            out[sl] = sum(B.T @ V[:, i * n + j] for i, B in enumerate(self.B))
        return out

    def jacobian(self, D: np.ndarray) -> np.ndarray:
        """(N·m, size) of outputs y_k (m per sample, in sample order) with ∂y_k/∂s_k = D[k] (N, m, 3n)."""
        N, m, _ = D.shape
        n = self.f.n_joints
        out = np.zeros((N, m, self.f.size))
        for j in range(n):
            sl = self.f.joint_slice(j)
            for i, B in enumerate(self.B):
                out[:, :, sl] += D[:, :, i * n + j, None] * B[:, None, :]
        return out.reshape(N * m, self.f.size)


def information_callback(setup: Setup, criterion: str, functions: SampleFunctions | None = None) -> NumpyFunction:
    """x → the NLP objective of `criterion` ("d": −log det F; "cond": the surrogate of log cond) on the
    objective grid (`OBJECTIVE_HZ` over a period), with its exact gradient (`criterion_value`, the pullback)."""
    functions = functions or SampleFunctions(setup)
    path = _Trajectory(setup, _grid(setup, OBJECTIVE_HZ))
    w = 1.0 / setup.sigma**2

    def parts(x):
        S = path.states(x)
        Y = functions.columns(S)  # (N, n, r)
        N = len(S)
        A = Y.reshape(-1, Y.shape[2])
        Fu = A.T @ A / N
        Fw = (A * np.repeat(w[None, :], N, axis=0).reshape(-1, 1)).T @ A / N
        return S, Y, Fw, Fu

    def value(x):
        _, _, Fw, Fu = parts(x)
        return [criterion_value(criterion, Fw, Fu)[0]]

    def gradient(x):
        S, Y, Fw, Fu = parts(x)
        _, dF = criterion_value(criterion, Fw, Fu)
        scale = w[None, :, None] if criterion == "d" else 1.0
        M = (2.0 / len(S)) * scale * (Y @ dF)  # ∂value/∂Y_B per sample (dF symmetric)
        return path.back(functions.pullback(S, M))[None, :]

    return NumpyFunction(f"excite_{criterion}", setup.fourier.size, 1, value, gradient)


def torque_callback(setup: Setup, t: np.ndarray, functions: SampleFunctions | None = None) -> NumpyFunction:
    """x → the nominal model's τ at times t (N·n, sample by sample), with its exact Jacobian."""
    functions = functions or SampleFunctions(setup)
    path = _Trajectory(setup, t)
    n = setup.fourier.n_joints
    return NumpyFunction(
        "excite_torques",
        setup.fourier.size,
        len(t) * n,
        lambda x: functions.torques(path.states(x)).ravel(),
        lambda x: path.jacobian(functions.torque_jacobian(path.states(x))),
    )


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
    solver, lbg, ubg = build_nlp(setup, objective or information_objective(setup, criterion), max_iter, expand)
    rng = np.random.default_rng([seed, 15])
    centre = 0.5 * (np.array(setup.limits.position_min) + np.array(setup.limits.position_max))
    centre = rest_pose(setup, centre)
    grid = np.arange(round(setup.duration * 100.0)) / 100.0  # criteria on the whole duration at 100 Hz
    best, records = None, []
    # One BLAS thread: the callbacks' matrices are small (r × r, r ≈ 70), and on a shared machine a threaded BLAS
    # mostly waits for cores (measured 30× slower per objective evaluation under load).
    blas = threadpool_limits(limits=1)
    x0s = [into_limits(setup, setup.fourier.random(rng, centre)) for _ in range(starts)]
    bar = tqdm(total=starts, desc=f"excite ({criterion})", disable=not progress, leave=False)
    runs = _run_starts((solver, lbg, ubg), x0s, workers, bar.update)
    bar.close()
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
    blas.restore_original_limits()
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
