"""The vocabulary a cause's diagnosis candidates are declared in (each cause's module, `Effect.families` and
`Effect.chain_families`): a candidate family on the planar two-link arm (`PlanarFamily`) or on an arm of n joints
(`ChainFamily`), and the per-joint helpers their columns and estimates are written with. The engines that fit them
are `ident_opt.diagnosis.planar` and `ident_opt.diagnosis.chain`; they pass their context to the hooks.

Light at load time (NumPy on first use): the catalogue is read for `--help`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

from ident_opt.effects.lazy import deferred

np = deferred("numpy")

#: Most samples an IPOPT polish of a planar candidate is set up on (per joint for Stribeck): CasADi builds the
#: expression graph per sample, so a 2 kHz trial would otherwise cost seconds just to set up.
POLISH_ROWS = 6000
#: A coefficient more than this many standard errors from its untouched value marks its joint as touched.
RESOLVED = 3.0


@dataclass
class PlanarFamily:
    """How to build one cause's candidate on the planar two-link arm (`diagnosis.planar`): the PlanarArm for θ, which π
    are freed from the datasheet, extra columns, how the prediction is transformed, the θ axes, how to read the estimate
    and how to polish it.

    `angles(θ)`: a shift δ (2,) [rad] of the angles the model is evaluated at (q + δ), or None.
    `transform(o, X, names, θ, step)`: the whole prediction changed after the columns are built (e.g.
    delayed), `step` [s] the sample step of the rows used.
    `polish(baseline, ctx, o, X, β, θ, bounds)`: IPOPT on θ from the search's answer: (θ proposal or None,
    info); the caller re-solves β at the proposal and keeps it only if the training objective drops.
    `refine(ctx, o, X, names, β, θ)`: (β, θ, statuses) refined jointly where it fits better (kept as is).
    """

    cause: str
    model: Callable[[dict], object] | None  # the PlanarArm at θ; None: the engine's nominal model
    free: tuple[str, ...] | None  # names freed against the datasheet (None: the effect adds no π names)
    extra: Callable | None = None
    angles: Callable[[dict], np.ndarray] | None = None
    transform: Callable | None = None
    axes: Callable = lambda rate: []
    baselines: tuple[str, ...] = ("datasheet", "rigid_fit")
    nonnegative: tuple[str, ...] = ()  # coefficients with a physical sign (held at 0 rather than negative)
    estimate: Callable = lambda p, se, ctx: ({}, {})
    polish: Callable | None = None
    refine: Callable | None = None
    #: `center(ctx, baseline)`: θ values the search axes are centred on (added to each axis' bounds), or None.
    center: Callable | None = None
    #: Names of the columns `extra` adds, and θ held fixed (set by `compose` for earlier causes).
    fixed: dict = field(default_factory=dict)
    members: tuple = ()  # (cause, Family) of a composed family, in the order the causes were added
    #: `units(p)`: (s (2,), own names) when the family rescales the logged torque (torque_scale): every
    #: other coefficient is then fitted in logged units, and s_j turns one on joint j's row into joint
    #: torque units (`physical_units`). None: the coefficients are in joint-torque units already.
    units: Callable | None = None
    #: `coupled(p)`: θ entries the columns depend on, read from the coefficients of the last solve (a found
    #: payload adds to the load torque that load-dependent friction scales with); `fit` iterates the solve
    #: to a fixed point. None: the columns do not depend on the coefficients.
    coupled: Callable[[dict], dict] | None = None
    #: Causes whose columns this family's contain (an elastic joint's motor inertia is an armature): it is
    #: named over such a cause only if it also clears the margin against that cause's own fit (`rounds._nested`).
    nests: tuple[str, ...] = ()
    #: `check(predict, θ, ctx, params) -> (detail, reason or None)`: a test of the fitted candidate on evidence its fit
    #: did not weigh (`ChainFamily.check`); a reason marks it unresolved.
    check: Callable | None = None


@dataclass
class ChainFamily:
    """One cause's candidate on an n-joint arm (`diagnosis.chain`): its columns `extra(ds, θ, ctx, baseline) -> (X (N,
    n, k), names)`, the datasheet parameters it replaces (`removed(ctx)` -> indices), an angle shift `angles(θ)` (n,)
    [rad], a delay `delay(θ)` [s], whether each joint's datasheet prediction becomes a column (`rows`: a torque scale),
    the θ axes and the nonlinear search of its own (`search(family, baseline, ctx) -> θ`), the baselines it allows, the
    nonnegative coefficients, how to read its estimate, `screen(params, se, ctx) -> joints` (the joints where it is
    resolved; None: not screened), `center` (θ the axes are centred on), `coupled` (θ read from the coefficients,
    re-solved to a fixed point) and `check(predict, θ, ctx, params) -> (detail, reason or None)` (a test of the fitted
    candidate on evidence its fit did not weigh alone; a reason marks it unresolved). `polish` and `refine` are the
    planar engine's (unused here)."""

    cause: str
    extra: Callable | None = None
    removed: Callable | None = None
    angles: Callable | None = None
    delay: Callable | None = None
    rows: bool = False
    axes: Callable = lambda rate, theta: []
    search: Callable | None = None
    baselines: tuple[str, ...] = ("datasheet", "rigid_fit")
    nonnegative: tuple[str, ...] = ()
    estimate: Callable = lambda p, se, ctx: ({}, {})
    screen: Callable | None = None
    center: Callable | None = None
    coupled: Callable | None = None
    check: Callable | None = None
    polish: Callable | None = None
    refine: Callable | None = None
    fixed: dict = field(default_factory=dict)
    members: tuple = ()
    units: Callable | None = None
    nests: tuple[str, ...] = ()  # causes whose columns this family's contain (`PlanarFamily.nests`)
    #: Screen the datasheet version with the rigid body's inertial parameters free beside the columns (`_screen`).
    screen_inertia_free: bool = False


def selected(theta: dict, cause: str, n: int) -> tuple[int, ...]:
    """The joints (0-based) a per-joint cause is fitted on: θ's `<cause>.joints` (set by the screen), else all."""
    return tuple(theta.get(f"{cause}.joints", range(n)))


def per_joint_columns(values: np.ndarray, joints: tuple[int, ...], prefix: str) -> tuple[np.ndarray, list[str]]:
    """(X (N, n, k), names): one column per joint j of `joints`, `values[:, j]` on joint j's row, named
    `<prefix><j + 1>`."""
    X = np.zeros((values.shape[0], values.shape[1], len(joints)))
    for k, j in enumerate(joints):
        X[:, j, k] = values[:, j]
    return X, [f"{prefix}{j + 1}" for j in joints]


def per_joint(p: dict, prefix: str, n: int, untouched: float = 0.0) -> list[float]:
    """A per-joint estimate of n entries from the coefficients `<prefix><j + 1>`: `untouched` where there is none."""
    return [float(p.get(f"{prefix}{j + 1}", untouched)) for j in range(n)]


def resolved_joints(p: dict, se: dict, prefixes: tuple[str, ...], n: int, untouched: float = 0.0) -> list[int]:
    """The joints (0-based) where some coefficient `<prefix><j + 1>` lies more than `RESOLVED` standard errors from
    `untouched`."""
    out = []
    for j in range(n):
        for prefix in prefixes:
            name = f"{prefix}{j + 1}"
            if name in p and abs(p[name] - untouched) > RESOLVED * se.get(name, math.inf):
                out.append(j)
                break
    return out


def one_coefficient_per_joint(key: str, prefix: str) -> dict:
    """A chain family's `nonnegative`, `estimate` and `screen` for one coefficient ≥ 0 per joint, `<prefix><j + 1>`:
    the estimate reports it under `key` (n entries, 0 where not fitted) with its standard errors, and the screen keeps
    the joints where it is resolved (`resolved_joints`)."""
    return {
        "nonnegative": (prefix,),
        "estimate": lambda p, se, ctx: ({key: per_joint(p, prefix, ctx.n)}, {"se": per_joint(se, prefix, ctx.n)}),
        "screen": lambda p, se, ctx: resolved_joints(p, se, (prefix,), ctx.n),
    }


def step(ds) -> float:
    """The sample step [s] of a data view (the search reads every few samples of the training part)."""
    return float(np.median(np.diff(ds.t)))


def view_key(ds) -> tuple:
    """What tells one data view from another in the caches: the object, its length, its first and last states
    (a view at shifted angles differs there; an object's id alone may be reused once it is gone)."""
    return id(ds), ds.n, ds.q[0].tobytes(), ds.q[-1].tobytes(), ds.dq[-1].tobytes()
