"""Hidden-effect trials: realistic random magnitudes per cause, and the tolerance check on an estimate.

Shared by the end-to-end tests and `benchmarks/confusion_matrix.py`, so that both hide the same effects
and judge estimates the same way. Ranges are realistic for a TUDOR-like arm (around the simulator's
defaults); tolerances are the issue's: magnitudes 15 %, frequency 20 %, delay 2 ms or 20 %, offsets
0.01 rad or 20 %.
"""

from __future__ import annotations

import numpy as np

from ident_opt.datasheet import rigid_body
from ident_opt.problem import Robot

#: Relative tolerance on magnitudes, on a mode's frequency, and the delay / offset rules.
MAGNITUDE_TOL = 0.15
FREQUENCY_TOL = 0.20
DELAY_TOL = (0.002, 0.20)  # s absolute, or relative
OFFSET_TOL = (0.01, 0.20)  # rad absolute, or relative


def draw(cause: str, rng: np.random.Generator, robot: Robot) -> dict:
    """Keys for `simulate_trial(effects={cause: keys})`, drawn from a realistic range."""
    u = rng.uniform
    if cause == "armature":
        return {"inertia": (u(0.1, 0.4), u(0.01, 0.04))}
    if cause == "asymmetric_coulomb":
        body = rigid_body(robot, "physical")
        pos, neg = [], []
        for fc in body.fc:  # a per-direction split of the datasheet's mean level by ±30..60 %
            a = u(0.3, 0.6) * rng.choice([-1.0, 1.0])
            pos.append(fc * (1 + a))
            neg.append(fc * (1 - a))
        return {"positive": tuple(pos), "negative": tuple(neg)}
    if cause == "stribeck":
        return {"static": (u(0.2, 0.4), u(0.15, 0.3)), "velocity": (u(0.03, 0.1), u(0.03, 0.1))}
    if cause == "elasticity":
        return {"joint": int(rng.integers(1, 3)), "frequency_hz": u(2.0, 8.0), "damping": u(0.01, 0.05)}
    if cause == "payload":
        return {"mass": u(0.1, 0.4)}
    if cause == "delay":
        return {"seconds": u(0.01, 0.04)}
    if cause == "joint_offset":
        return {"offset": tuple(u(0.02, 0.06) * rng.choice([-1.0, 1.0]) for _ in range(2))}
    raise ValueError(f"unknown cause {cause!r}")


def _rel(est: float, true: float) -> float:
    return abs(est - true) / abs(true) if true != 0 else abs(est)


def errors(cause: str, estimate: dict, truth: dict) -> tuple[bool, float]:
    """(within tolerance, worst relative error) of `estimate` against the simulator's `truth` (both in the
    estimate keys of `spec/diagnose.md`). Every key the effect touches counts; none may miss."""
    checks: list[tuple[bool, float]] = []
    if cause == "elasticity":
        rel = _rel(estimate["frequency_hz"], truth["frequency_hz"])
        checks.append((estimate["joint"] == truth["joint"], 0.0 if estimate["joint"] == truth["joint"] else 1.0))
        checks.append((rel <= FREQUENCY_TOL, rel))
    elif cause == "delay":
        d, t = estimate["seconds"], truth["seconds"]
        checks.append((abs(d - t) <= DELAY_TOL[0] or _rel(d, t) <= DELAY_TOL[1], _rel(d, t)))
    elif cause == "joint_offset":
        for e, t in zip(estimate["offset"], truth["offset"]):
            checks.append((abs(e - t) <= OFFSET_TOL[0] or _rel(e, t) <= OFFSET_TOL[1], _rel(e, t)))
    else:
        keys = {
            "armature": ["inertia"],
            "asymmetric_coulomb": ["positive", "negative"],
            "stribeck": ["static", "velocity"],
            "payload": ["mass"],
        }[cause]
        for key in keys:
            for e, t in zip(np.atleast_1d(estimate[key]), np.atleast_1d(truth[key])):
                rel = _rel(float(e), float(t))
                checks.append((rel <= MAGNITUDE_TOL, rel))
    return all(ok for ok, _ in checks), max(r for _, r in checks)
