"""The searches of the n-joint candidates that span more than one fit: which joints an elastic joint is tried on
(`elastic_joints`, the per-joint evidence of a mode) and the encoder offsets by Gauss–Newton (`offset_search`);
and `ChainContext`, the context the engine hands the causes' hooks (`ArmContext` with these searches)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from ident_opt.diagnosis.chain.context import MASSLESS, ArmContext
from ident_opt.diagnosis.chain.families import design, projected, target
from ident_opt.effects.families import RESOLVED, ChainFamily
from ident_opt.numerics import least_squares as linear


class ChainContext(ArmContext):
    """The context of the n-joint engine as the causes' hooks see it (`Effect.chain_families(ctx)`): `ArmContext`
    with the searches of this module."""

    def elastic_joints(self, columns: Callable) -> list[int]:
        """The joints an elastic joint is tried on (`elastic_joints`), for a cause's columns."""
        return elastic_joints(self, columns)

    def offset_search(self, family: ChainFamily, baseline: str) -> dict:
        """θ of an encoder-offset family by Gauss–Newton (`offset_search`)."""
        return offset_search(family, baseline, self)


#: Gauss–Newton steps of the encoder offsets, and the step below which they stop [rad].
OFFSET_STEPS, OFFSET_STOP = 5, 1e-5
#: Joints an elastic joint is tried on: those whose residual rings most in the elastic band.
ELASTIC_CANDIDATES = 2
#: The modes an elastic joint is screened at [Hz] (`elastic_joints`), with a light damping ratio.
SCREEN_HZ, SCREEN_DAMPING = (2.0, 3.0, 4.5, 6.5, 9.0), 0.03


def elastic_joints(ctx: ArmContext, columns: Callable) -> list[int]:
    """The `ELASTIC_CANDIDATES` joints (0-based) whose elastic-joint column (`columns(joint)`, the elasticity
    cause's) explains most of the rigid fit's training residual at any of the screening modes `SCREEN_HZ`: the
    per-joint evidence of a mode, n × 5 one-column fits. A joint whose link carries no inertia about its axis in
    the datasheet (the shipped TX40's last link) is not one: nothing behind its spring could ring (and the
    deflection's drive, τ_link,j / M_jj, would be 0/0)."""
    tr = ctx.train
    Q = ctx.basis(tr)
    inertia = np.array([float(np.mean(ctx.inertia_column(tr, j)[:, j])) for j in range(ctx.n)])
    gains = []
    for j in range(ctx.n):
        if not inertia[j] > MASSLESS * max(float(np.max(inertia)), np.finfo(float).tiny):
            gains.append(-np.inf)
            continue
        costs = []
        for f in SCREEN_HZ:
            X, _ = columns(j)(tr, {"frequency_hz": f, "damping": SCREEN_DAMPING}, ctx, "rigid_fit")
            costs.append(projected(Q, X, tr.tau, tr, ctx, [0], False).cost)
        gains.append(-min(costs))
    ranked = [int(j) for j in np.argsort(gains)[::-1] if np.isfinite(gains[j])]
    chosen = ranked[: min(ELASTIC_CANDIDATES, ctx.n)]
    ctx.evidence["elastic_joints"] = chosen
    return chosen


def offset_search(family: ChainFamily, baseline: str, ctx: ArmContext) -> dict:
    """Encoder offsets by Gauss–Newton (`gauss_newton`) on every joint, then again on the joints where the offset
    is resolved (more than `RESOLVED` standard errors from 0): θ = {`delta<j>` of those joints,
    `<cause>.joints`}. With the joints already held (a later round), on those only."""
    key = f"{family.cause}.joints"
    if key in family.fixed:
        return gauss_newton(family, baseline, ctx, family.fixed[key])[0]
    theta, se = gauss_newton(family, baseline, ctx, tuple(range(ctx.n)), exact=False)
    touched = tuple(j for j in range(ctx.n) if abs(theta[f"delta{j + 1}"]) > RESOLVED * ctx.correlation * se[j])
    if not touched:
        return {key: ()}
    return gauss_newton(replace(family, fixed={**family.fixed, key: touched}), baseline, ctx, touched)[0]


def gauss_newton(
    family: ChainFamily, baseline: str, ctx: ArmContext, joints: tuple[int, ...], exact: bool = True
) -> tuple[dict, np.ndarray]:
    """Encoder offsets δ on `joints`: τ(q + δ + Δ) ≈ τ(q + δ) + (∂τ/∂q) Δ, Δ fitted by least squares with the
    family's other columns (and π, for rigid_fit, by projection), at most `OFFSET_STEPS` steps. (θ with `delta<j>`
    of `joints` and `<cause>.joints`, the standard error of each joint's δ from the last step [rad] (inf off
    `joints`)). Not `exact`: the rigid columns projected out at the logged angles throughout (the screening pass:
    a sixth of the cost, and the same δ to first order)."""
    tr, n = ctx.train, ctx.n
    key = f"{family.cause}.joints"
    theta = {**family.fixed, key: tuple(joints)}
    delta = np.array([theta.get(f"delta{j + 1}", 0.0) for j in range(n)])
    se = np.full(n, np.inf)
    for _ in range(OFFSET_STEPS):
        theta.update({f"delta{j + 1}": float(delta[j]) for j in joints})
        o, X, _, Y, _ = design(family, tr, theta, baseline, ctx)
        J = ctx.torque_jacobian(tr, delta, ctx.datasheet if Y is None else ctx.pi_rigid)
        XJ = np.concatenate([X, J[:, :, list(joints)]], axis=2)
        t = target(family, tr, theta, ctx) - o
        if Y is None:
            step_fit = linear.solve(np.zeros_like(t), ctx.demean(XJ, tr), ctx.demean(t, tr), ctx.weights)
        else:
            step_fit = projected(ctx.basis(tr, delta if exact else None), XJ, t, tr, ctx, [], True)
        step = np.zeros(n)
        step[list(joints)] = np.clip(step_fit.beta[X.shape[2] :], -0.5, 0.5)  # beyond that, no linearisation
        se[list(joints)] = step_fit.se[X.shape[2] :]
        delta = delta + step
        if np.max(np.abs(step)) < OFFSET_STOP:
            break
    theta.update({f"delta{j + 1}": float(delta[j]) for j in joints})
    return theta, se
