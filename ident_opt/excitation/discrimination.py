"""Discrimination design: the excitation that best tells two suspected causes apart (T-optimal design).

The two causes' candidate models are the diagnosis's own (`diagnosis.planar.families`: each cause's families,
refitted with every π of the nominal structure, baseline ``rigid_fit``), fitted on the problem's first trial
(the data the diagnosis could not separate well), each cause's best family kept. On a trajectory, with A
true: τ_A is A's prediction, and B fitted to it (weighted least squares on B's columns, its nonlinear
parameters θ held where the data put them) leaves a lack of fit LOF_j(A→B) per joint. With independent
Gaussian noise σ_j² per joint (the rigid fit's residual variance on the data, the diagnosis's joint
weights), the diagnosis's expected score gap between the true cause and the other is

    gap(A true) = (n/2) Σ_j ln(1 + LOF_j(A→B) / (n σ_j²)) − ((k_B − k_A)/2) ln n

(`diagnosis.scoring`: held-out log-likelihood gain with a BIC penalty; n samples at the data's rate over the
design's duration). The design maximises the geometric mean of gap(A true) and gap(B true), in the same limits
as every design; its value, the smaller of the two, is reported against the first `duration` seconds of the
trial the data came from, and the whole of it.

The other cause's nonlinear parameters (e.g. a mode's frequency and damping) are not held where the data put
them: the diagnosis searches them, so the lack of fit is the least over a coarse grid of them (`theta_grid`)
— the T-optimal design's inner minimum. The objective is computed in NumPy (the diagnosis's columns: filters,
indicators), so IPOPT sees it through a CasADi callback whose gradient is central finite differences (a step
of `FD_STEP` in the coefficients, wide enough to average over the sign changes of Coulomb columns) with the
inner minimisers held (envelope theorem); the limits stay exact CasADi expressions.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ident_opt.arm.datasheet import PlanarRobot, datasheet_pi, rigid_body
from ident_opt.data.dataset import Dataset
from ident_opt.diagnosis.planar import families as cands
from ident_opt.diagnosis.planar.engine import weights_of
from ident_opt.diagnosis.split import prepare
from ident_opt.effects import CATALOGUE
from ident_opt.effects.families import PlanarFamily
from ident_opt.errors import InputError
from ident_opt.excitation import design as excitation
from ident_opt.excitation.design import Design
from ident_opt.excitation.information import NumpyFunction
from ident_opt.excitation.setup import Setup
from ident_opt.numerics import least_squares as linear
from ident_opt.numerics import signals
from ident_opt.numerics.signals import TORQUE_FILTER_HZ
from ident_opt.outputs import shown

#: The series a discriminating design uses unless told otherwise: harmonics of about 0.25 Hz up to 4 Hz. Causes
#: told apart by their dynamics (a mode searched in 1.5–12 Hz, a delay) show only in fast motion; 5 harmonics of
#: 0.1 Hz (the identification default) leave a 3 Hz mode unexcited and the two causes indistinguishable.
HARMONICS, BASE_HZ = 16, 0.25
#: Sharpness of the soft minimum of the two log gaps (1/k of log 2 above the minimum at most).
SOFTMIN = 4.0
#: Finite-difference step in the Fourier coefficients [rad/s; rad for offsets].
FD_STEP = 1e-3
#: Most grid points per nonlinear parameter when the design searches a rival's θ as the diagnosis would.
GRID_POINTS = 6
#: IPOPT iterations per start (each gradient is 2 × size objective evaluations).
MAX_ITER = 60


@dataclass
class Rival:
    """One cause's fitted candidate: its family, its nonlinear parameters θ, its predictor and added count."""

    cause: str
    family: PlanarFamily
    theta: dict
    candidate: cands.Candidate

    @property
    def n_added(self) -> int:
        return self.candidate.n_added


@dataclass
class Rivals:
    """The two causes' candidates, the diagnosis context they were fitted in, the data's step dt [s]."""

    a: Rival
    b: Rival
    ctx: cands.Context
    dt: float


def parse_between(text: str) -> tuple[str, str]:
    """ "A,B" -> (A, B), two different catalogue causes; `InputError` naming --between otherwise."""
    names = [n.strip() for n in text.split(",")]
    if len(names) != 2 or names[0] == names[1] or not all(names):
        raise InputError(f"--between {text!r}: give two different causes, CAUSE_A,CAUSE_B")
    unknown = [n for n in names if n not in CATALOGUE]
    if unknown:
        raise InputError(f"--between: unknown cause(s) {', '.join(unknown)}; known: {', '.join(CATALOGUE)}")
    return names[0], names[1]


def fit_rivals(
    robot: PlanarRobot, trial: Dataset, causes: tuple[str, str], torque_filter_hz: float = TORQUE_FILTER_HZ
) -> Rivals:
    """Each cause's best family (least weighted training cost) fitted on the whole `trial` against the refitted
    nominal model, in the diagnosis's context (`diagnosis.split.prepare`, `weights_of` weights)."""
    data = prepare(trial, torque_filter_hz)
    dt = float(np.median(np.diff(data.t)))
    weights = weights_of(data)
    ctx = cands.Context(
        robot,
        data,
        data,
        weights,
        datasheet_pi(robot, "physical"),
        dt,
        signals.rest_runs(data.dq),
        rigid_body(robot, "physical").armature,
    )
    rivals = []
    for cause in causes:
        best = None
        for family in CATALOGUE[cause].families(ctx):
            if "rigid_fit" not in family.baselines:
                continue
            cand = cands.fit(family, "rigid_fit", ctx)
            r = signals.demean_runs(data.tau - cand.predict(data), ctx.rest)
            cost = float(weights @ np.sum(r**2, axis=0))
            if best is None or cost < best[0]:
                theta = {k: cand.parameters[k] for k in (a.name for a in family.axes(1.0 / dt))}
                best = (cost, Rival(cause, family, theta, cand))
        if best is None:
            raise InputError(f"--between: {cause} has no candidate against the refitted nominal model")
        rivals.append(best[1])
    return Rivals(rivals[0], rivals[1], ctx, dt)


def trajectory_dataset(t: np.ndarray, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> Dataset:
    """A motion as a Dataset (no torque): what the candidates' columns are built from."""
    return Dataset("design", t, q, dq, ddq, np.zeros_like(q))


def lack_of_fit(rivals: Rivals, true: Rival, other: Rival, ds: Dataset, theta: dict | None = None) -> np.ndarray:
    """LOF_j (n,) [N² m²]: the RSS per joint of `other` (at its nonlinear parameters `theta`, default where the
    data put them) fitted to `true`'s prediction on the motion `ds`."""
    tau = true.candidate.predict(ds)
    o, X, _ = cands.design(other.family, ds, other.theta if theta is None else theta, "rigid_fit", rivals.ctx)
    return linear.solve(o, X, tau, rivals.ctx.weights, with_se=False).rss


def theta_grid(rivals: Rivals, rival: Rival) -> list[dict]:
    """The nonlinear parameters the diagnosis would search for `rival`: its family's axes on a coarse grid (at
    most `GRID_POINTS` per axis), and where the data put them."""
    axes = rival.family.axes(1.0 / rivals.dt)
    grids = [a.grid()[:: max(1, -(-len(a.grid()) // GRID_POINTS))] for a in axes]
    mesh = np.meshgrid(*grids, indexing="ij") if grids else []
    points = [dict(zip((a.name for a in axes), map(float, values))) for values in zip(*(m.ravel() for m in mesh))]
    return [rival.theta, *points]


def closest_theta(rivals: Rivals, true: Rival, other: Rival, ds: Dataset) -> dict:
    """`other`'s nonlinear parameters on `theta_grid` that fit `true`'s prediction best (weighted RSS): the
    diagnosis searches them, so a design must separate the causes whatever they are."""
    grid = theta_grid(rivals, other)
    if len(grid) == 1:
        return grid[0]
    costs = [float(rivals.ctx.weights @ lack_of_fit(rivals, true, other, ds, theta)) for theta in grid]
    return grid[int(np.argmin(costs))]


def expected_gaps(
    rivals: Rivals, ds: Dataset, samples: int | None = None, thetas: dict[str, dict] | None = None
) -> dict:
    """The diagnosis's expected score gap with A true and with B true on `ds` (module docstring), and its
    smaller one ("discrimination"). `samples`: n of the trial `ds` stands for (its lack of fit scaled by
    samples / ds.n: a whole number of periods of a periodic motion), default ds.n. `thetas`: the other cause's
    nonlinear parameters per true cause (default: the closest on the grid, `closest_theta`); returned as
    "thetas"."""
    n = samples or ds.n
    sigma2 = 1.0 / rivals.ctx.weights
    out: dict = {"thetas": {}}
    for true, other in ((rivals.a, rivals.b), (rivals.b, rivals.a)):
        theta = thetas[true.cause] if thetas else closest_theta(rivals, true, other, ds)
        out["thetas"][true.cause] = theta
        lof = lack_of_fit(rivals, true, other, ds, theta) * (n / ds.n)
        gain = 0.5 * n * float(np.sum(np.log1p(lof / (n * sigma2))))
        out[f"gap_{true.cause}_true"] = gain - 0.5 * (other.n_added - true.n_added) * math.log(n)
        out[f"lof_{true.cause}_true"] = lof.tolist()
    gaps = [out[f"gap_{r.cause}_true"] for r in (rivals.a, rivals.b)]
    out["discrimination"] = min(gaps)
    out["samples"] = n
    return out


def _objective_value(
    rivals: Rivals, setup: Setup, t: np.ndarray, samples: int, x: np.ndarray, thetas: dict | None = None
) -> tuple[float, dict]:
    """(−softmin(log gap_A, log gap_B), the rivals' closest θ) of coefficients x on times t standing for
    `samples` (gaps floored at 1e-3): the smaller gap is what a diagnosis risks, the soft minimum keeps the
    objective smooth. With `thetas` given, the rivals' θ are held there (the gradient's envelope theorem)."""
    q, dq, ddq = setup.fourier.evaluate(x, t)
    gaps = expected_gaps(rivals, trajectory_dataset(t, q, dq, ddq), samples, thetas)
    logs = np.log(np.maximum([gaps[f"gap_{r.cause}_true"] for r in (rivals.a, rivals.b)], 1e-3))
    k = SOFTMIN
    return float(np.log(np.sum(np.exp(-k * (logs - logs.min())))) / k - logs.min()), gaps["thetas"]


def _gradient(fn, x: np.ndarray) -> np.ndarray:
    """∂f/∂x (1, size) of the objective `fn` (x, θ) -> (f, θ*) by central differences of `FD_STEP`, with the
    rivals' θ held at their minimisers at x (the envelope theorem: the minimum's gradient is the gradient at the
    minimiser), so the gradient costs one θ search, not one per perturbation."""
    _, thetas = fn(x)
    grad = np.zeros(x.size)
    for i in range(x.size):
        e = np.zeros(x.size)
        e[i] = FD_STEP
        grad[i] = (fn(x + e, thetas)[0] - fn(x - e, thetas)[0]) / (2 * FD_STEP)
    return grad[None, :]


def reference_gaps(rivals: Rivals, trial: Dataset, duration: float) -> dict:
    """Expected gaps on the trial the data came from: its first `duration` seconds, and the whole of it."""
    first = trial.subset(np.flatnonzero(trial.t - trial.t[0] < duration))
    return {"same_duration": expected_gaps(rivals, first), "whole_trial": expected_gaps(rivals, trial)}


def design(
    setup: Setup,
    robot: PlanarRobot,
    trial: Dataset | None,
    between: str,
    *,
    starts: int = 3,
    seed: int = 0,
    rate: float = excitation.CHECK_HZ,
    progress: bool = True,
    max_iter: int = MAX_ITER,
    workers: int = 1,
) -> Design:
    """The T-optimal design between the two causes of `between` ("A,B"), fitted on `trial` (required); `workers`:
    processes running the starts at once (`excitation.design`)."""
    causes = parse_between(between)
    if trial is None:
        raise InputError(
            "--criterion discriminate needs data (the problem's [data] trials or --data) to fit the causes"
        )
    rivals = fit_rivals(robot, trial, causes)
    t = np.arange(round(setup.duration / rivals.dt)) * rivals.dt  # the data's rate: the diagnosis's samples
    callback = _objective_callback(rivals, setup, t)
    d = excitation.design(
        setup,
        "discriminate",
        starts=starts,
        seed=seed,
        rate=rate,
        objective=lambda x: callback(x),
        evaluate=_evaluator(rivals, setup, t),
        progress=progress,
        max_iter=max_iter,
        expand=False,
        workers=workers,
    )
    d.discrimination = _discrimination(rivals, causes, setup, trial, d.criteria)
    return d


def _objective_callback(rivals: Rivals, setup: Setup, t: np.ndarray) -> NumpyFunction:
    """The NLP's objective as a CasADi callback: NumPy gaps on the first two periods, gradient by differences."""
    # The NLP sees the first two periods (the start from rest, then the steady state), standing for all of them.
    t_nlp = t[t < min(setup.duration, 2 * setup.fourier.period)]

    def objective(x: np.ndarray, thetas: dict | None = None) -> tuple[float, dict]:
        return _objective_value(rivals, setup, t_nlp, len(t), x, thetas)

    return NumpyFunction(
        "discrimination", setup.fourier.size, 1, lambda x: [objective(x)[0]], lambda x: _gradient(objective, x)
    )


def _evaluator(rivals: Rivals, setup: Setup, t: np.ndarray) -> Callable[[np.ndarray, np.ndarray, np.ndarray], dict]:
    """(q, dq, ddq) -> the information criteria and the expected gaps at the data's rate (times `t`), as diagnosed."""

    def evaluate(q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> dict:
        # Criteria on the data's rate over the duration (q etc. may come at another rate: resample by time).
        tt = np.linspace(0.0, setup.duration, len(q), endpoint=False)
        qi, dqi, ddqi = (np.column_stack([np.interp(t, tt, v[:, j]) for j in range(v.shape[1])]) for v in (q, dq, ddq))
        return {**excitation.criteria(setup, q, dq, ddq), **expected_gaps(rivals, trajectory_dataset(t, qi, dqi, ddqi))}

    return evaluate


def _discrimination(rivals: Rivals, causes: tuple[str, str], setup: Setup, trial: Dataset, criteria: dict) -> dict:
    """The design's `discrimination` entry: the causes' candidates, the noise, and its gap against `trial`'s."""
    ref = reference_gaps(rivals, trial, setup.duration)
    source = shown(trial.source)
    same, mine = ref["same_duration"]["discrimination"], criteria["discrimination"]
    ratio = mine / same if same > 0 else float("inf")
    return {
        "between": list(causes),
        "candidates": {
            r.cause: {
                "estimate": r.candidate.estimate,
                "theta": r.theta,
                "parameters": r.candidate.parameters,
                "added_parameters": r.n_added,
            }
            for r in (rivals.a, rivals.b)
        },
        "noise_sigma": np.sqrt(1.0 / rivals.ctx.weights).tolist(),
        "noise_source": f"residual of the refitted nominal model on {source} (the diagnosis's joint weights)",
        "design": {k: v for k, v in criteria.items() if k not in ("log_det", "cond", "rank")},
        "reference": ref,
        "ratio_same_duration": ratio,
        "summary": (
            f"expected score gap {mine:.3g} vs {same:.3g} on the first {setup.duration:g} s of {source} "
            f"({ratio:.2f}×; whole trial: {ref['whole_trial']['discrimination']:.3g})"
        ),
    }
