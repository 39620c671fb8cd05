"""Hidden-effect trials: realistic random magnitudes per cause, and the tolerance check on an estimate.

Shared by the end-to-end tests and `benchmarks/confusion_matrix.py`, so that both hide the same effects and
judge estimates the same way. Each cause's module in `ident_opt.effects` says how (`Effect.draw`: ranges
realistic for a TUDOR-like arm, around the simulator's defaults; `Effect.judge`: magnitudes within 15 %, a
mode's frequency within 20 %, a delay within 2 ms or 20 %, offsets within 0.01 rad or 20 %).
"""

from __future__ import annotations

import numpy as np

from ident_opt.arm.datasheet import PlanarRobot
from ident_opt.effects import CATALOGUE


def draw(cause: str, rng: np.random.Generator, robot: PlanarRobot) -> dict:
    """Keys for `simulate_trial(effects={cause: keys})`, drawn from a realistic range."""
    if cause not in CATALOGUE:
        raise ValueError(f"unknown cause {cause!r}")
    return CATALOGUE[cause].draw(rng, robot)


def scaled(cause: str, keys: dict, factor: float, robot: PlanarRobot) -> dict:
    """`keys` of a hidden `cause` with its magnitude multiplied by `factor` (`Effect.scaled`: e.g. a payload's
    mass, a mode's compliance 1/k, a torque scale's deviation from 1)."""
    from ident_opt.simulator.truth import coulomb_levels

    return CATALOGUE[cause].scaled(dict(keys), factor, coulomb_levels(robot))


def errors(cause: str, estimate: dict, truth: dict) -> tuple[bool, float]:
    """(within tolerance, worst relative error) of `estimate` against the simulator's `truth` (both in the
    cause's estimate keys, `docs/effects.md`). Every key the effect touches counts; none may miss."""
    checks = CATALOGUE[cause].judge(estimate, truth)
    return all(ok for ok, _ in checks), max(r for _, r in checks)


def chain_errors(cause: str, estimate: dict, truth: dict) -> tuple[bool, float]:
    """`errors` on an n-joint arm (`Effect.chain_judge`: an untouched joint judged against the largest true value)."""
    checks = CATALOGUE[cause].chain_judge(estimate, truth)
    return all(ok for ok, _ in checks), max(r for _, r in checks)


def chain_joints(robot, limits=None):
    """The effect syntax's view of an n-joint arm's joints (`effects.base.Joints`: the datasheet's Coulomb levels,
    the names, the reference magnitudes the draws are relative to), as the simulator builds it for `limits`."""
    from ident_opt.simulator.chain import box_of
    from ident_opt.simulator.chain_plant import arm_scale, joints_of

    box = box_of(robot, limits)
    return joints_of(robot, arm_scale(robot, box, box.v_max))


def chain_draw(cause: str, rng: np.random.Generator, joints, chosen: tuple[int, ...]) -> dict:
    """Keys of a hidden `cause` on an n-joint arm (`Effect.chain_draw`), on the 0-based joints `chosen`."""
    if cause not in CATALOGUE:
        raise ValueError(f"unknown cause {cause!r}")
    return CATALOGUE[cause].chain_draw(rng, joints, tuple(chosen))


def chain_draws(causes, rng: np.random.Generator, joints, chosen: tuple[int, ...]) -> dict:
    """Keys of several hidden `causes` on the same n-joint arm, drawn in order, each seeing the Coulomb levels the
    earlier ones set: Stribeck friction drawn beside asymmetric Coulomb friction rises above those levels, not
    above the datasheet's (drawn alone against the datasheet's level, its static level could sit below the
    per-direction ones: a friction that falls at low speed, which no catalogue cause is)."""
    out = {}
    for cause in causes:
        keys = chain_draw(cause, rng, joints, chosen)
        out[cause] = keys
        if "positive" in keys and "negative" in keys:
            joints = type(joints)(keys["positive"], keys["negative"], joints.names, joints.scale)
    return out
