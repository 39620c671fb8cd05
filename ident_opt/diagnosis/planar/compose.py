"""How the planar candidates of several causes are fitted together: one model with every extension (`merged_model`), one
family for a cause and those named before it (`compose`), a family held at its θ (`frozen`), and the estimate of a joint
fit (`joint_estimate`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from ident_opt.arm.planar import PlanarArm
from ident_opt.diagnosis.planar.families import NOMINAL, Candidate, Context, model_of
from ident_opt.effects import CATALOGUE
from ident_opt.effects.families import PlanarFamily


# ---------------------------------------------------------------------------------------------- composition
def merged_model(models: list[PlanarArm]) -> PlanarArm:
    """One PlanarArm with every extension of `models` (the Stribeck velocities of the one that sets them)."""
    extensions: list[str] = []
    velocity = NOMINAL.stribeck_velocity
    for m in models:
        extensions += [e for e in m.extensions if e not in extensions]
        if m.stribeck_velocity != NOMINAL.stribeck_velocity:
            velocity = m.stribeck_velocity
    order = list(CATALOGUE)
    extensions.sort(key=lambda e: order.index(e) if e in order else -1)
    if tuple(extensions) == NOMINAL.extensions:
        return NOMINAL
    return PlanarArm(tuple(extensions), stribeck_velocity=velocity)


def joint_estimate(families: list, new: str) -> Callable[[dict, dict, object], tuple[dict, dict]]:
    """The estimate of a joint fit of several causes (`families`, each with its own `estimate`), `new` the cause
    added last: its estimate and detail, plus every cause's estimate (`members`) and detail (`member_details`: what
    the report says of a cause named in an earlier round, e.g. an elastic joint's k, link inertia and damping
    ratio, from the joint fit's coefficients rather than the new cause's)."""

    def estimate(p: dict, se: dict, ctx) -> tuple[dict, dict]:
        members = {f.cause: f.estimate(p, se, ctx) for f in families}
        est, det = members[new]
        return est, {
            **det,
            "members": {c: e for c, (e, _) in members.items()},
            "member_details": {c: d for c, (_, d) in members.items()},
        }

    return estimate


def compose(earlier: list[tuple[PlanarFamily, dict]], new: PlanarFamily) -> PlanarFamily:
    """One family for several causes: the earlier ones (each with its θ held) and `new` (searched, polished).

    Columns: the union of the models' extensions, every family's extra columns (the new one's last, so its
    polish sees them where it expects), the angle shift of the one that has one, every transform in
    catalogue order. Baselines: those every member allows. The estimate is the new cause's; each cause's
    estimate and detail in the joint fit are `detail["members"]` and `detail["member_details"]`
    (`joint_estimate`)."""
    fams = [f for f, _ in earlier] + [new]
    fixed = {**{k: v for _, th in earlier for k, v in th.items()}, **new.fixed}
    extras = [f.extra for f in fams if f.extra is not None]
    shifts = [f.angles for f in fams if f.angles is not None]
    transforms = [f.transform for f in sorted(fams, key=lambda f: list(CATALOGUE).index(f.cause)) if f.transform]
    frees = [f.free for f in fams if f.free is not None]

    def model(theta: dict) -> PlanarArm:
        return merged_model([model_of(f, theta) for f in fams])

    def extra(ds, theta, dt, ctx):
        parts = [e(ds, theta, dt, ctx) for e in extras]
        return np.concatenate([p[0] for p in parts], axis=2), [n for p in parts for n in p[1]]

    def transform(o, X, names, theta, step):
        for t in transforms:
            o, X, names = t(o, X, names, theta, step)
        return o, X, names

    estimate = joint_estimate(fams, new.cause)
    units = next((f.units for f in fams if f.units is not None), None)
    coupled_parts = [f.coupled for f in fams if f.coupled is not None]

    def coupled(p: dict) -> dict:
        return {k: v for c in coupled_parts for k, v in c(p).items()}

    baselines = tuple(b for b in new.baselines if all(b in f.baselines for f in fams))
    return PlanarFamily(
        new.cause,
        model,
        tuple(n for fr in frees for n in fr) if frees else None,
        extra=extra if extras else None,
        angles=shifts[-1] if shifts else None,
        transform=transform if transforms else None,
        axes=new.axes,
        baselines=baselines,
        nonnegative=tuple(n for f in fams for n in f.nonnegative),
        estimate=estimate,
        polish=new.polish if not earlier or (new.extra is not None and not transforms) else None,
        refine=new.refine,
        check=new.check,
        center=new.center,
        fixed=fixed,
        members=tuple((f.cause, f) for f in fams),
        units=units,
        coupled=coupled if coupled_parts else None,
    )


def frozen(family: PlanarFamily, theta: dict) -> PlanarFamily:
    """`family` with its θ held at `theta`: no search, no polish (a cause refitted linearly only)."""
    return replace(family, axes=lambda rate: [], polish=None, refine=None, center=None, fixed=dict(theta))


def theta(family: PlanarFamily, cand: Candidate, ctx: Context) -> dict:
    """The θ a later round holds a cause at: the candidate's values on the family's axes."""
    return {a.name: cand.parameters[a.name] for a in family.axes(1.0 / ctx.dt)}
