"""Candidate models of the causes on an arm with n joints, fitted on the training part: the n-joint engine of the
diagnosis (the planar two-link arm's is `candidates`), through the `Arm` and `Robot` interfaces alone.

Every candidate is τ̂ = o(θ) + Y(q + δ) π + X(θ) β, delayed by d(θ) where the cause has a delay:

- ``datasheet``: π held at the robot's nominal model (`Robot.datasheets()[Robot.datasheet]`), o = Y π without the
  parameters the cause replaces (a Coulomb level by direction replaces the symmetric one); β by weighted least
  squares (nonnegative where the cause says so).
- ``rigid_fit``: π refitted with the cause, by the diagnosis's estimator (the recommended fit unless --estimator
  says otherwise; `fitting.estimators.fit_for`, in `ArmContext.rigid`, the one place the diagnosis fits π): β
  first by variable projection against the rigid columns (|P⊥(τ − X β)|² with P⊥ the projection off the
  weighted regressor's column space: the least-squares π for any β, whatever the base parameters), then π by the
  estimator on τ − X β and β again on τ − Y π. With no column, this is the nominal rigid fit exactly, so every
  candidate is compared like with like.

Evidence per joint first, then few candidates (the search never grows combinatorially with n): a per-joint cause
(armature, asymmetric Coulomb, Stribeck, load friction, offsets, a torque scale) is one candidate with a column
(or two) per joint, fitted once on every joint and again on the joints where it is resolved (`screen`: more than
three standard errors); an elastic joint is a candidate on the joints whose residual rings most in the elastic band
(`elastic_joints`); a delay and a payload are one candidate each. Nonlinear parameters (a mode's f and ζ, a delay,
Stribeck velocities, a payload's centre of mass) are searched by variable projection (`linear.search`), encoder
offsets by Gauss–Newton on the angle Jacobian of the torque.

All arrays are per sample and joint: o, τ (N, n), X (N, n, k), Y (N, n, P); a joint's samples slower than
`signals.STICK_SPEEDS` rest speeds, where stiction may hold it, are left out of every fit and score
(`ArmContext.labels`; the planar engine compares its rest stretches about their means instead).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ident_opt.data.dataset import Dataset
from ident_opt.diagnosis.chain.context import ArmContext, advanced
from ident_opt.diagnosis.planar.compose import joint_estimate
from ident_opt.diagnosis.planar.families import Candidate, physical_units
from ident_opt.effects import CATALOGUE
from ident_opt.effects.families import (
    ChainFamily,
    per_joint_columns,
    selected,
    step,
)
from ident_opt.numerics import least_squares as linear
from ident_opt.numerics import signals

#: A column whose part outside the rigid model's column space is below this share of its norm lies in that
#: space: a refitted π explains it whole (e.g. a constant torque while moving beside the torque offsets), so it
#: is held at 0.
SPAN_TOL = 1e-6


# ---------------------------------------------------------------------------------------------- families
def families(ctx: ArmContext) -> list[ChainFamily]:
    """Every catalogue cause's candidates on this arm (`Effect.chain_families`, given the context), in catalogue
    order."""
    return [family for effect in CATALOGUE.values() for family in effect.chain_families(ctx)]


# ---------------------------------------------------------------------------------------------- design and fit
def design(
    family: ChainFamily, ds: Dataset, theta: dict, baseline: str, ctx: ArmContext
) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray | None, np.ndarray | None]:
    """(o (N, n), X (N, n, k), names, Y or None, δ or None) of `family` at θ on `ds` against `baseline`: o the
    datasheet's prediction (without what the cause replaces), X its columns, Y the rigid columns π is refitted on
    (rigid_fit), δ the angle shift they are evaluated at."""
    delta = None if family.angles is None else np.asarray(family.angles(theta), dtype=float)
    shifted = ds if delta is None else replace(ds, q=ds.q + delta)
    Y = ctx.regressor(ds, delta)
    N, n = ds.n, ctx.n
    X, names = family.extra(shifted, theta, ctx, baseline) if family.extra is not None else (np.zeros((N, n, 0)), [])
    if baseline != "datasheet":
        return np.zeros((N, n)), X, names, Y, delta
    pi = ctx.datasheet.copy()
    if family.removed is not None:
        pi[list(family.removed(theta, ctx))] = 0.0
    o = Y @ pi
    if family.rows:
        chosen = selected(theta, "torque_scale", n)
        R, scale_names = per_joint_columns(o, chosen, "c")
        o = o.copy()
        o[:, list(chosen)] = 0.0
        X, names = np.concatenate([X, R], axis=2), [*names, *scale_names]
    return o, X, names, None, delta


def target(family: ChainFamily, ds: Dataset, theta: dict, ctx: ArmContext) -> np.ndarray:
    """The measured torque as the candidate fits it: read back by the cause's delay (`advanced`), if it has one."""
    if family.delay is None:
        return ds.tau
    return advanced(ds.tau, family.delay(theta), step(ds))


def projection(
    Q: np.ndarray, X: np.ndarray, t: np.ndarray, ds: Dataset, ctx: ArmContext
) -> tuple[np.ndarray, np.ndarray]:
    """(A (N, n, k), y (N, n)): the columns and the target, weighted and projected off the rigid columns (P⊥ = 1 − Q Qᵀ;
    variable projection: π at its least-squares value for every β); columns lying in Q's span (`SPAN_TOL`) are
    zeroed, so they are held at 0."""
    A = ctx.rows(X, ds)
    y = ctx.rows(t[:, :, None], ds)[:, 0]
    A_perp = A - Q @ (Q.T @ A)
    y_perp = y - Q @ (Q.T @ y)
    norms = np.linalg.norm(A, axis=0)
    inside = np.linalg.norm(A_perp, axis=0) <= SPAN_TOL * np.maximum(norms, 1e-300)
    A_perp[:, inside] = 0.0
    n = ctx.n
    N = len(y) // n
    return A_perp.reshape(N, n, A.shape[1]), y_perp.reshape(N, n)


def projected(Q: np.ndarray, X: np.ndarray, t: np.ndarray, ds: Dataset, ctx: ArmContext, nonneg, with_se):
    """β minimising |P⊥ (t − X β)|² (`projection`), nonnegative where `nonneg` says."""
    A, y = projection(Q, X, t, ds, ctx)
    return linear.solve_nonnegative(np.zeros_like(y), A, y, np.ones(ctx.n), nonneg, with_se)


def problem(family: ChainFamily, ds: Dataset, theta: dict, baseline: str, ctx: ArmContext):
    """The weighted least-squares problem β solves at θ: (A (N, n, k), y (N, n), joint weights w (n,), the indices of
    the nonnegative coefficients, o, X, names, Y, δ) — datasheet: X and τ − o rest-demeaned with the context's
    weights; rigid_fit: weighted and projected off the rigid columns (`projection`), unit weights."""
    o, X, names, Y, delta = design(family, ds, theta, baseline, ctx)
    t = target(family, ds, theta, ctx) - o
    nonneg = [i for i, name in enumerate(names) if name.rstrip("0123456789") in family.nonnegative]
    if Y is None:
        A, y, w = ctx.demean(X, ds), ctx.demean(t, ds), ctx.weights
    else:
        (A, y), w = projection(ctx.basis(ds, delta), X, t, ds, ctx), np.ones(ctx.n)
    return A, y, w, nonneg, o, X, names, Y, delta


def _solve(family: ChainFamily, ds: Dataset, theta: dict, baseline: str, ctx: ArmContext, with_se: bool):
    """(fit, o, X, names, Y, δ): β at θ (`problem`)."""
    A, y, w, nonneg, o, X, names, Y, delta = problem(family, ds, theta, baseline, ctx)
    ls = linear.solve_nonnegative(np.zeros_like(y), A, y, w, nonneg, with_se)
    return ls, o, X, names, Y, delta


def search_theta(family: ChainFamily, baseline: str, ctx: ArmContext) -> dict:
    """θ of the family: its own search, else variable projection over its axes (centred by `center`), else its
    fixed θ."""
    theta = dict(family.fixed)
    if family.search is not None:
        return {**theta, **family.search(family, baseline, ctx)}
    axes = family.axes(1.0 / ctx.dt, theta)
    if not axes:
        return theta
    if family.center is not None:
        c = family.center(family, baseline, ctx)
        axes = [
            linear.Axis(a.name, a.low + c.get(a.name, 0.0), a.high + c.get(a.name, 0.0), a.points, a.log) for a in axes
        ]

    view = ctx.search_view

    def cost(th: dict) -> float:
        return _solve(family, view, {**theta, **th}, baseline, ctx, False)[0].cost

    return {**theta, **linear.search(cost, axes)}


def fit(family: ChainFamily, baseline: str, ctx: ArmContext) -> Candidate:
    """Fit one family against one baseline on the training part: the joints screened first (`screen`, at the
    middle of its axes), θ searched on those, β (and π, for rigid_fit) solved; the joints whose estimate then fails
    the cause's own rule (`detail["failed_joints"]` of its `estimate`) left out and the rest fitted again, once. A
    `Candidate` whose `detail["theta"]` holds θ (the joints it touches included)."""
    key = f"{family.cause}.joints"
    if family.screen is not None and key not in family.fixed:
        start = {
            **family.fixed,
            **{a.name: float(a.grid()[len(a.grid()) // 2]) for a in family.axes(1.0 / ctx.dt, family.fixed)},
        }
        touched = _screen(family, baseline, start, ctx)
        family = replace(family, fixed={**family.fixed, key: touched})
    cand = _final(family, baseline, ctx, search_theta(family, baseline, ctx))
    failed = cand.detail.get("failed_joints", ())
    if failed and key in family.fixed and family.screen is not None:
        # the joints whose estimate fails the cause's own rule leave, the others are searched and fitted again: one
        # joint's narrow hump must not refuse the joints where the cause is read well
        family = replace(family, fixed={**family.fixed, key: tuple(j for j in family.fixed[key] if j not in failed)})
        cand = _final(family, baseline, ctx, search_theta(family, baseline, ctx))
        cand.detail["dropped_joints"] = [ctx.robot.joint_names[j] for j in failed]
    return _plausible_joints(family, baseline, ctx, cand)


def _plausible_joints(family: ChainFamily, baseline: str, ctx: ArmContext, cand: Candidate) -> Candidate:
    """The candidate fitted again, once, without the joints whose per-joint values fail their physical range (the
    plausibility rule, `ctx.failing`): an implausible value is never named, and the joints where the cause is read
    plausibly keep their chance. The joints left and why are in `detail["implausible_joints"]`."""
    key = f"{family.cause}.joints"
    touched = cand.detail.get("theta", {}).get(key)
    if ctx.failing is None or touched is None or cand.detail.get("empty"):
        return cand
    bad = {j: why for j, why in ctx.failing(family.cause, cand.estimate, cand.detail).items() if j in touched}
    if not bad:
        return cand
    family = replace(family, fixed={**family.fixed, key: tuple(j for j in touched if j not in bad)})
    again = _final(family, baseline, ctx, search_theta(family, baseline, ctx))
    again.detail["implausible_joints"] = {ctx.robot.joint_names[j]: why for j, why in bad.items()}
    return again


def _screen(family: ChainFamily, baseline: str, start: dict, ctx: ArmContext) -> tuple[int, ...]:
    """The joints `family.screen` reads as touched from one fit at `start` over every joint, standard errors by the
    sandwich (the residuals are correlated). With `screen_inertia_free`, against the datasheet, the columns and the
    residual are first projected off the rigid body's inertial columns (offsets and friction held at the
    datasheet's): a cause a refitted π cannot tell from its own terms (an asymmetric Coulomb level from a torque
    offset) has only the datasheet's side, where an inertia the datasheet lacks (an armature hidden beside it)
    otherwise widens its errors until it is screened out."""
    tr = ctx.train
    A, y, w, nonneg, o, X, names, _, _ = problem(family, tr, start, baseline, ctx)
    if family.screen_inertia_free and baseline == "datasheet":
        A, y = projection(ctx.inertial_basis(tr), X, target(family, tr, start, ctx) - o, tr, ctx)
        w = np.ones(ctx.n)
    ls = linear.solve_nonnegative(np.zeros_like(y), A, y, w, nonneg, True)
    se, free = ls.se.copy(), np.isfinite(ls.se) & (ls.se > 0)
    se[free] = linear.sandwich(A[:, :, free], y - np.einsum("njk,k->nj", A, ls.beta), w)
    return tuple(family.screen(dict(zip(names, ls.beta)), dict(zip(names, se)), ctx))


def _final(family: ChainFamily, baseline: str, ctx: ArmContext, theta: dict) -> Candidate:
    """The candidate at θ: β (with π refitted by the estimator for rigid_fit), coupled θ settled, its estimate and
    predictor."""
    tr = ctx.train
    ls, _, X, names, Y, delta = _solve(family, tr, theta, baseline, ctx, True)
    for _ in range(5 if family.coupled is not None else 0):
        update = family.coupled(dict(zip(names, map(float, ls.beta))), theta)
        if all(abs(v - theta.get(k, 0.0)) <= 1e-6 * (1 + abs(v)) for k, v in update.items()):
            break
        theta = {**theta, **update}
        ls, _, X, names, Y, delta = _solve(family, tr, theta, baseline, ctx, True)
    pi = None
    if Y is not None:
        t = target(family, tr, theta, ctx)
        nonneg = [i for i, name in enumerate(names) if name.rstrip("0123456789") in family.nonnegative]
        # π by the estimator given β (with no effect, exactly the nominal rigid fit), then β given π
        beta = ls.beta
        same = not np.any(beta != 0) and delta is None and family.delay is None  # the nominal problem itself
        pi = ctx.pi_rigid if same else ctx.rigid(Y, t - np.einsum("njk,k->nj", X, beta), tr)
        ls = linear.solve_nonnegative(
            np.zeros_like(t), ctx.demean(X, tr), ctx.demean(t - Y @ pi, tr), ctx.weights, nonneg, True
        )
    beta = ls.beta
    params = dict(zip(names, map(float, beta)))
    se = dict(zip(names, map(float, ls.se)))
    if family.units is not None:
        params, se = physical_units(family.units(params), X, names, params, se, ctx.weights)
    if pi is not None:
        params.update(ctx.arm.as_dict(pi))
    estimate, detail = family.estimate({**params, **theta}, se, ctx)
    detail["theta"] = dict(theta)
    if theta.get(f"{family.cause}.joints", None) == ():
        # screened to no joint: the candidate is the model without the cause, whatever it scores (`result._row`)
        detail["empty"] = True
    params.update({k: v for k, v in theta.items() if isinstance(v, float)})
    searched = [k for k in theta if isinstance(theta[k], float) and k not in family.fixed]
    n_added = len(names) + len(searched)

    def predict(ds: Dataset) -> np.ndarray:
        o_, X_, _, Y_, _ = design(family, ds, theta, baseline, ctx)
        out = o_ + np.einsum("njk,k->nj", X_, beta)
        if Y_ is not None:
            out = out + Y_ @ pi
        return out if family.delay is None else signals.delayed(out, family.delay(theta), step(ds))

    if family.check is not None:
        found, reason = family.check(predict, theta, ctx, params)
        detail.update(found)
        if reason is not None:
            detail["unresolved"] = reason
    return Candidate(family.cause, baseline, estimate, params, se, n_added, predict, detail)


# ---------------------------------------------------------------------------------------------- the loop's engine
def compose(earlier: list[tuple[ChainFamily, dict]], new: ChainFamily) -> ChainFamily:
    """One family for several causes: the earlier ones (each with its θ held) and `new` (searched): every family's
    columns, the parameters any replaces, the angle shift and the delay of the one that has them, the torque-scale
    rows if any has them; the baselines every member allows; each cause's estimate and detail in
    `detail["members"]` and `detail["member_details"]` (`planar.compose.joint_estimate`)."""
    fams = [f for f, _ in earlier] + [new]
    fixed = {**{k: v for _, th in earlier for k, v in th.items()}, **new.fixed}
    extras = [f.extra for f in fams if f.extra is not None]
    removed = [f.removed for f in fams if f.removed is not None]
    angles = next((f.angles for f in fams if f.angles is not None), None)
    delay = next((f.delay for f in fams if f.delay is not None), None)

    def extra(ds, theta, ctx, baseline):
        parts = [e(ds, theta, ctx, baseline) for e in extras]
        return np.concatenate([p[0] for p in parts], axis=2), [n for p in parts for n in p[1]]

    def replaced(theta, ctx):
        return sorted({i for r in removed for i in r(theta, ctx)})

    estimate = joint_estimate(fams, new.cause)
    coupled_parts = [f.coupled for f in fams if f.coupled is not None]

    def coupled(p: dict, theta: dict) -> dict:
        return {k: v for c in coupled_parts for k, v in c(p, theta).items()}

    return ChainFamily(
        new.cause,
        extra=extra if extras else None,
        removed=replaced if removed else None,
        angles=angles,
        delay=delay,
        rows=any(f.rows for f in fams),
        axes=new.axes,
        search=new.search,
        baselines=tuple(b for b in new.baselines if all(b in f.baselines for f in fams)),
        nonnegative=tuple(x for f in fams for x in f.nonnegative),
        estimate=estimate,
        screen=new.screen,
        center=new.center,
        coupled=coupled if coupled_parts else None,
        check=new.check,
        screen_inertia_free=new.screen_inertia_free,
        nests=new.nests,
        fixed=fixed,
        members=tuple((f.cause, f) for f in fams),
        units=next((f.units for f in fams if f.units is not None), None),
    )


def frozen(family: ChainFamily, theta: dict) -> ChainFamily:
    """`family` with θ held (its joints included): no search, no screen; only its linear coefficients move."""
    return replace(
        family, axes=lambda rate, theta: [], search=None, center=None, screen=None, check=None, fixed=dict(theta)
    )


def theta(family: ChainFamily, cand: Candidate, ctx: ArmContext) -> dict:
    """The θ a later round holds the cause at: the candidate's (`detail["theta"]`)."""
    return dict(cand.detail.get("theta", {}))
