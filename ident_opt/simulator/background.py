"""Background realism in the closed loop: the terms of `ident_opt.effects.background` around the truth plant.

All act on the joint (motor-side, collocated with the encoder) torques of the truth plant, whatever its kind
(rigid, elastic joint, flexible link); with none active the plant is untouched. Each term's physics is in its
own module; here they are combined, in the background's order:

- external torques d (a term that `disturbs`, e.g. drift) are an extra input of the plant per tick;
- states z (e.g. stiction's bristle deflections) extend the plant's state; their force resists the motion;
- currents (e.g. ripple) are added to the commanded torque: part of the actual motor current, held over the
  tick and logged.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ident_opt.arm.datasheet import PlanarRobot
from ident_opt.effects import BACKGROUND


def _terms(background: dict) -> list:
    """(term, its keys) of the active background, in the background's order."""
    return [(term, background[name]) for name, term in BACKGROUND.items() if name in background]


def n_states(background: dict) -> int:
    """How many states the background adds to the plant."""
    return sum(term.states(p) for term, p in _terms(background))


def with_background(base: ca.Function, nx: int, background: dict) -> ca.Function:
    """The plant with background terms: (x, τ, d) -> (ẋ, y), x = [base state (nx), the terms' states].

    τ [N m] is the actual motor torque (commanded + currents), d [N m] the external torque; with no
    background the result is `base` evaluated at τ, exactly (d unused).
    """
    terms = _terms(background)
    x, tau, d = ca.SX.sym("x", nx + n_states(background)), ca.SX.sym("tau", 2), ca.SX.sym("d", 2)
    applied = tau
    if any(term.disturbs for term, _ in terms):
        applied = applied + d
    states, start = [], nx
    for term, p in terms:
        z = x[start : start + term.states(p)]
        start += term.states(p)
        if term.states(p):
            applied = applied - term.force(p, z)
            states.append((term, p, z))
    xdot, y = base(x[:nx], applied)
    v = y[2:4]  # encoder-side rates: the motor side at an elastic joint, where the gearbox is
    for term, p, z in states:
        xdot = ca.vertcat(xdot, term.rate(p, z, v))
    return ca.Function("plant_bg", [x, tau, d], [xdot, y], ["x", "tau", "d"], ["xdot", "y"])


def current(background: dict, robot: PlanarRobot, q_enc: ca.SX, dq_enc: ca.SX) -> ca.SX | None:
    """The torque [N m] the background adds to the commanded one at encoder angles q_enc [rad] and rates
    dq_enc [rad/s] (e.g. a current ripple); None when none does."""
    out = None
    for term, p in _terms(background):
        r = term.current(p, robot, q_enc, dq_enc)
        if r is not None:
            out = r if out is None else out + r
    return out


def disturbance(background: dict, n: int, dt: float, rng: np.random.Generator) -> np.ndarray:
    """The external torque d (n, 2) [N m] on a grid of step dt [s] (zeros when there is none; no draw then)."""
    out = np.zeros((n, 2))
    for term, p in _terms(background):
        if term.disturbs:
            out = out + term.disturbance(p, n, dt, rng)
    return out


def initial_states(background: dict, rng: np.random.Generator) -> np.ndarray:
    """The background's states at the start (empty when it has none)."""
    parts = [term.initial(p, rng) for term, p in _terms(background) if term.states(p)]
    return np.concatenate(parts) if parts else np.zeros(0)


def rates(background: dict, inertia: np.ndarray) -> list[float]:
    """Bounds of the fastest rates [1/s] the background adds, for the RK4 step (J [kg m²] a lower bound of
    each joint's inertia)."""
    return [r for term, p in _terms(background) for r in term.rates(p, inertia)]
