"""What an excitation design works in (`Setup`, `make_setup`): the arm and the base parameters the motion must excite, a
periodic Fourier trajectory's shape (duration, harmonics, base frequency), the problem's `[limits]`, the noise the
information is weighed with, and the grids the limits and the objective are read on."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from ident_opt.arm.base import Arm, Robot
from ident_opt.data.dataset import Dataset
from ident_opt.errors import InputError
from ident_opt.fitting.base import ZERO_COLUMN
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


def _grid(setup: Setup, rate: float) -> np.ndarray:
    """Times over one period [s] at `rate` [Hz]."""
    period = setup.fourier.period
    return np.arange(int(np.ceil(period * rate))) * (period / np.ceil(period * rate))
