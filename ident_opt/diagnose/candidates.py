"""One candidate model extension per catalogue cause, fitted on the training part.

Each cause is a *family* of models τ̂ = o(θ) + X(θ) β (see `linear.py`) built from the `ArmModel`
extensions where the effect is linear in its parameters, plus a few nonlinear parameters θ searched by
variable projection. It is fitted against one or both nominal models:

- ``datasheet``: the problem file's π held fixed; only the effect's own parameters are fitted (this is
  where parameter-level causes show: armature, payload, mis-scaled or asymmetric friction).
- ``rigid_fit``: every π of the nominal structure refitted together with the effect (structural causes
  that no choice of π absorbs: friction shape, elasticity, delay, offsets).

| cause | columns (linear β) | nonlinear θ |
|---|---|---|
| armature | J1·ddq1, J2·ddq2 on the diagonal (the a1, ia2 directions), J ≥ 0 | — |
| payload | Y·∂π/∂m (π is affine in a tip mass m), m ≥ 0 | — |
| asymmetric_coulomb | fc1p fc1n fc2p fc2n (`asymmetric_coulomb` extension) | — |
| stribeck | fs1 fs2 ≥ 0 (`stribeck` extension) | vs1, vs2 [rad/s] |
| joint_offset | the nominal model at q + δ (gravity and inertia both see the true angle) | δ1, δ2 [rad] |
| delay | the whole prediction delayed by d | d [s] |
| elasticity | s·(m_link,j ë_j on row j + M_oj(q2) ë_j on the other), datasheet inertias (below) | f, ζ |

ë_j is the deflection acceleration of an elastic joint j driven by the measured motor-side acceleration
(`signals.deflection_acceleration`): an elastic-joint model driven by the logged motor-side angle.

After the search, IPOPT polishes θ (`polish.py`): Stribeck (fs, vs) per joint, the elastic mode (f, ζ)
jointly with every β by multiple shooting (`elastic_nlp.py`), the offsets (δ1, δ2) jointly with π; the
estimates before and after land in the candidate's `detail["polish"]` (the JSON's extra keys).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from ident_opt.data import Dataset
from ident_opt.datasheet import datasheet_pi
from ident_opt.diagnose import elastic_nlp, linear, polish, signals
from ident_opt.problem import Robot
from ident_opt.robot import ArmModel

#: The nominal structure under the physical convention (the datasheet has the joint-2 armature ia2).
NOMINAL = ArmModel(("armature",))
#: Rows used by the nonlinear search: longer trials are strided down to about this many samples
#: (the final linear solve always uses every sample).
SEARCH_ROWS = 12000
#: Where an elastic mode is searched [Hz]: the first modes of flexible-link arms lie at a few Hz; above
#: ~12 Hz a mode is no longer observable in accelerations estimated with the usual 15 Hz low-pass, and a
#: "mode" there only fits filter transients at starts and stops.
ELASTIC_BAND_HZ = (1.5, 12.0)


@dataclass
class Context:
    """What every candidate needs: the robot, the training and held-out parts, joint weights 1/σ_j²."""

    robot: Robot
    train: Dataset
    test: Dataset
    weights: np.ndarray
    datasheet: dict[str, float]
    dt: float
    rest: np.ndarray  # rest-stretch labels of the training part (`signals.rest_runs`)
    armature: tuple[float, float] = (0.0, 0.0)  # the datasheet's reflected rotor inertia per joint [kg m²]


@dataclass
class Candidate:
    """A fitted extension: its catalogue estimate, parameters (with standard errors) and a predictor."""

    cause: str
    baseline: str
    estimate: dict
    parameters: dict[str, float]
    se: dict[str, float]
    n_added: int
    predict: Callable[[Dataset], np.ndarray]
    detail: dict = field(default_factory=dict)


@dataclass
class Family:
    """How to build one cause's model: the ArmModel for θ, which π are freed from the datasheet, extra
    columns, whether the prediction is delayed, the θ axes and how to read the estimate."""

    cause: str
    model: Callable[[dict], ArmModel]
    free: tuple[str, ...] | None  # names freed against the datasheet (None: the effect adds no π names)
    extra: Callable[[Dataset, dict, float, Context], tuple[np.ndarray, list[str]]] | None = None
    shifted: bool = False
    angle_offset: bool = False  # the model is evaluated at q + (δ1, δ2)
    axes: Callable[[float], list[linear.Axis]] = lambda rate: []
    baselines: tuple[str, ...] = ("datasheet", "rigid_fit")
    nonnegative: tuple[str, ...] = ()  # coefficients with a physical sign (held at 0 rather than negative)
    estimate: Callable[[dict, dict, Context], tuple[dict, dict]] = lambda p, se, ctx: ({}, {})
    joint: int = 0  # the elastic joint (elasticity only)


_CACHE: dict = {}


def _regressor(model: ArmModel, ds: Dataset, rows: slice) -> np.ndarray:
    """model.regressor on ds[rows], remembered for the last few (model, data) pairs: the searches over a
    delay or a mode re-use the same regressor hundreds of times."""
    key = (model, id(ds), ds.n, rows.start, rows.stop, rows.step)
    if key not in _CACHE:
        if len(_CACHE) > 8:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = (ds, model.regressor(ds.q[rows], ds.dq[rows], ds.ddq[rows]))
    return _CACHE[key][1]


def design(
    family: Family, ds: Dataset, theta: dict, baseline: str, ctx: Context, rows: slice = slice(None)
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(o, X, names) of `family` at θ on `ds` (rows `rows`), against `baseline` (see the module docstring)."""
    model = family.model(theta)
    if family.angle_offset:  # the true angle is the logged one + δ: evaluate the model there (no cache)
        shift = np.array([theta["delta1"], theta["delta2"]])
        Y = model.regressor(ds.q[rows] + shift, ds.dq[rows], ds.ddq[rows])
    else:
        Y = _regressor(model, ds, rows)
    n = Y.shape[0]
    if baseline == "datasheet":
        pi = model.vector(ctx.datasheet)
        free = [i for i, n in enumerate(model.names) if n in (family.free or ())]
        fixed = [i for i in range(model.n_params) if i not in free]
        offset = Y[:, :, fixed] @ pi[fixed]
        X, names = Y[:, :, free], [model.names[i] for i in free]
    else:
        offset, X, names = np.zeros((n, 2)), Y, list(model.names)
    if family.extra is not None:
        cols, extra_names = family.extra(ds, theta, ctx.dt, ctx)
        X = np.concatenate([X, cols[rows]], axis=2)
        names = names + extra_names
    if family.shifted:
        d = theta["delay"]
        step = ctx.dt * (rows.step or 1)
        offset, X = signals.delayed(offset, d, step), signals.delayed(X, d, step)
    return offset, X, names


def fit(family: Family, baseline: str, ctx: Context) -> Candidate:
    """Fit one family against one baseline on the training part (θ by variable projection, β by WLS)."""
    rate = 1.0 / ctx.dt
    stride = max(1, -(-ctx.train.n // SEARCH_ROWS))  # ceil: at most SEARCH_ROWS rows
    # A delay needs a uniform grid: stride by whole samples and delay on the strided grid.
    rows = slice(None, None, stride)
    train_sub, rest_sub = ctx.train.tau[rows], ctx.rest[rows]

    def solve(o, X, names, tau, labels, with_se):
        # Within rest stretches only variations count (see `signals.demean_runs`): project data and columns.
        signed = [i for i, n in enumerate(names) if n in family.nonnegative]
        target = signals.demean_runs(tau - o, labels)
        return linear.solve_nonnegative(
            np.zeros_like(target), signals.demean_runs(X, labels), target, ctx.weights, signed, with_se
        )

    def cost(theta: dict) -> float:
        o, X, names = design(family, ctx.train, theta, baseline, ctx, rows)
        return solve(o, X, names, train_sub, rest_sub, False).cost

    axes = family.axes(rate)
    theta = linear.search(cost, axes) if axes else {}
    o, X, names = design(family, ctx.train, theta, baseline, ctx)
    ls = solve(o, X, names, ctx.train.tau, ctx.rest, True)
    proposal, nlp, tr = None, None, ctx.train
    bounds = {a.name: (a.low, a.high) for a in axes}
    if family.cause == "elasticity":  # (f, ζ) with every β by IPOPT, multiple shooting (elastic_nlp.py)
        u, P = elastic_drive(family.joint, tr, ctx)
        proposal, nlp = elastic_nlp.polish(
            u, P, tr.tau - o, X[:, :, :-1], ctx.rest, ctx.weights, ctx.dt, theta, ls.beta, bounds
        )
    elif family.cause == "joint_offset":  # (δ1, δ2) jointly, with π when it is refitted
        held = NOMINAL.vector(ctx.datasheet) if baseline == "datasheet" else None
        proposal, nlp = polish.offsets(
            NOMINAL, tr.q, tr.dq, tr.ddq, tr.tau, ctx.rest, ctx.weights, held, ls.beta, theta, bounds["delta1"]
        )
    if nlp is not None:
        searched = {**dict(zip(names, map(float, ls.beta))), **theta}
        nlp["before"] = family.estimate(searched, dict.fromkeys(searched, 0.0), ctx)
        nlp["cost_before"], nlp["kept"] = ls.cost, False
        if proposal is not None:
            o2, X2, _ = design(family, ctx.train, proposal, baseline, ctx)
            ls2 = solve(o2, X2, names, ctx.train.tau, ctx.rest, True)
            nlp["cost_after"] = ls2.cost
            if ls2.cost < ls.cost:  # β re-solved exactly at the polished θ; kept only if it fits better
                theta, o, X, ls, nlp["kept"] = proposal, o2, X2, ls2, True
    beta, polished = ls.beta.copy(), []
    if family.cause == "stribeck":  # the nonlinear vs: IPOPT polish from the search's start
        beta, theta, polished = polish.stribeck(ctx.rest, ctx.train.dq, ctx.train.tau, o, X, names, beta, theta)
    params = dict(zip(names, map(float, beta)))
    se = dict(zip(names, map(float, ls.se)))
    params.update(theta)
    estimate, detail = family.estimate(params, se, ctx)
    if polished:
        detail["ipopt"] = polished
    if nlp is not None:
        nlp["after"] = family.estimate(params, se, ctx)
        for key in ("before", "after"):  # (estimate, detail) -> one flat dict: f, ζ, k, c, inertia
            est, det = nlp[key]
            nlp[key] = {**est, **{k: v for k, v in det.items() if k != "se"}}
        detail["polish"] = nlp
    nominal_free = len(NOMINAL.names) if baseline == "rigid_fit" else 0
    n_added = len(names) - nominal_free + len(theta)

    def predict(ds: Dataset) -> np.ndarray:
        o, X, _ = design(family, ds, theta, baseline, ctx)
        return o + np.einsum("njk,k->nj", X, beta)

    return Candidate(family.cause, baseline, estimate, params, se, n_added, predict, detail)


# ---------------------------------------------------------------------------------------------- families
def _nominal(theta: dict) -> ArmModel:
    return NOMINAL


def _armature_estimate(p: dict, se: dict, ctx: Context) -> tuple[dict, dict]:
    inertia = [p["j1"], p["j2"]]
    return {"inertia": inertia}, {"se": [se["j1"], se["j2"]]}


def _armature_columns(ds: Dataset, theta: dict, dt: float, ctx: Context) -> tuple[np.ndarray, list[str]]:
    """Extra reflected inertia J_j on the diagonal of M: J1·ddq1 on joint 1's row, J2·ddq2 on joint 2's
    (the a1 and ia2 columns of the nominal structure)."""
    X = np.zeros((ds.n, 2, 2))
    X[:, 0, 0], X[:, 1, 1] = ds.ddq[:, 0], ds.ddq[:, 1]
    return X, ["j1", "j2"]


def _payload_column(ds: Dataset, theta: dict, dt: float, robot: Robot) -> np.ndarray:
    """Y·∂π/∂m: π is affine in a tip mass m (the combined link-2 inertia about joint 2 and its first
    moment are both linear in m), so the difference quotient at m = 1 kg is exact."""
    d = NOMINAL.vector(datasheet_pi(replace(robot, payload_mass=robot.payload_mass + 1.0))) - NOMINAL.vector(
        datasheet_pi(robot)
    )
    return (NOMINAL.regressor(ds.q, ds.dq, ds.ddq) @ d)[:, :, None]


def _asym_estimate(p: dict, se: dict, ctx: Context) -> tuple[dict, dict]:
    return (
        {"positive": [p["fc1p"], p["fc2p"]], "negative": [p["fc1n"], p["fc2n"]]},
        {"se_positive": [se["fc1p"], se["fc2p"]], "se_negative": [se["fc1n"], se["fc2n"]]},
    )


def _stribeck_estimate(p: dict, se: dict, ctx: Context) -> tuple[dict, dict]:
    static, velocity = [], []
    for j in ("1", "2"):
        fs, s = p["fs" + j], se["fs" + j]
        # A joint whose excess is not resolved from zero is "untouched": report 0 for both keys.
        resolved = fs > 3.0 * s
        static.append(fs if resolved else 0.0)
        velocity.append(p["vs" + j] if resolved else 0.0)
    return {"static": static, "velocity": velocity}, {"se_static": [se["fs1"], se["fs2"]]}


def elastic_drive(joint: int, ds: Dataset, ctx: Context) -> tuple[np.ndarray, np.ndarray]:
    """(u (N,) [rad/s²], P (N, 2) [kg m²]): the drive of elastic joint j's link and its inertia pattern.

    The link behind an elastic joint j is driven by its motor's acceleration and, through the off-diagonal
    inertia, by the other joint's: u = θ̈_j + (M_jo(q2) / M_jj,link(q2)) q̈_o, with the inertias from the
    datasheet (link side: without joint j's armature). The spring carries link j's inertia on its own row,
    m_link·ë; the other row feels the coupling M_oj·ë. One free scale s on that physical pattern: the pattern
    (which row rings how much) is what tells an elastic joint 1 from an elastic joint 2, so it is not free."""
    p, arm = ctx.datasheet, ctx.armature
    c2 = np.cos(ds.q[:, 1])
    m_cross = p["a3"] + p["a2"] * c2
    m_link = (p["a1"] - arm[0] + 2 * p["a2"] * c2) if joint == 1 else np.full(ds.n, p["a3"])
    other = 2 - joint
    u = ds.ddq[:, joint - 1] + m_cross / m_link * ds.ddq[:, other]
    P = np.zeros((ds.n, 2))
    P[:, joint - 1], P[:, other] = m_link, m_cross
    return u, P


def _elastic_columns(joint: int) -> Callable:
    def columns(ds: Dataset, theta: dict, dt: float, ctx: Context) -> tuple[np.ndarray, list[str]]:
        u, P = elastic_drive(joint, ds, ctx)
        e = signals.deflection_acceleration(u, theta["frequency_hz"], theta["damping"], dt)
        return (P * e[:, None])[:, :, None], ["scale"]

    return columns


def _elastic_estimate(joint: int) -> Callable:
    def estimate(p: dict, se: dict, ctx: Context) -> tuple[dict, dict]:
        c2 = np.cos(ctx.train.q[:, 1])
        p0, arm = ctx.datasheet, ctx.armature
        m_link = float(np.mean(p0["a1"] - arm[0] + 2 * p0["a2"] * c2)) if joint == 1 else p0["a3"]
        m_eff = p["scale"] * m_link  # the link inertia the spring carries [kg m²]
        w = 2 * math.pi * p["frequency_hz"]
        return (
            {"joint": joint, "frequency_hz": p["frequency_hz"]},
            {
                "damping_ratio": p["damping"],
                "inertia": m_eff,
                "stiffness": m_eff * w * w,
                "damping_coefficient": 2 * p["damping"] * w * m_eff,
            },
        )

    return estimate


def families(robot: Robot) -> list[Family]:
    """Every catalogue cause (elasticity once per joint) as a `Family`."""
    out = [
        Family(
            "armature",
            _nominal,
            (),
            extra=_armature_columns,
            baselines=("datasheet",),
            nonnegative=("j1", "j2"),
            estimate=_armature_estimate,
        ),
        Family(
            "payload",
            _nominal,
            (),
            extra=lambda ds, th, dt, ctx: (_payload_column(ds, th, dt, robot), ["mass"]),
            baselines=("datasheet",),
            nonnegative=("mass",),
            estimate=lambda p, se, ctx: ({"mass": p["mass"]}, {"se": se["mass"]}),
        ),
        Family(
            "asymmetric_coulomb",
            lambda th: ArmModel(("armature", "asymmetric_coulomb")),
            ("fc1p", "fc1n", "fc2p", "fc2n"),
            estimate=_asym_estimate,
        ),
        Family(
            "stribeck",
            lambda th: ArmModel(("armature", "stribeck"), stribeck_velocity=(th["vs1"], th["vs2"])),
            ("fs1", "fs2"),
            nonnegative=("fs1", "fs2"),
            axes=lambda rate: [
                linear.Axis("vs1", 0.005, 0.5, 11, True),
                linear.Axis("vs2", 0.005, 0.5, 11, True),
            ],
            estimate=_stribeck_estimate,
        ),
        Family(
            "joint_offset",
            _nominal,
            (),
            angle_offset=True,
            axes=lambda rate: [linear.Axis("delta1", -0.1, 0.1, 21), linear.Axis("delta2", -0.1, 0.1, 21)],
            estimate=lambda p, se, ctx: ({"offset": [p["delta1"], p["delta2"]]}, {}),
        ),
        Family(
            "delay",
            _nominal,
            (),
            shifted=True,
            axes=lambda rate: [linear.Axis("delay", 0.0, 0.15, 31)],
            estimate=lambda p, se, ctx: ({"seconds": p["delay"]}, {}),
        ),
    ]
    for joint in (1, 2):
        out.append(
            Family(
                "elasticity",
                _nominal,
                (),
                extra=_elastic_columns(joint),
                axes=lambda rate: [
                    linear.Axis("frequency_hz", *ELASTIC_BAND_HZ, 16, True),
                    linear.Axis("damping", 0.005, 0.3, 6, True),
                ],
                estimate=_elastic_estimate(joint),
                joint=joint,
            )
        )
    return out
