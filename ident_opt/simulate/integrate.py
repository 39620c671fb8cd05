"""The simulators' one integrator step: classical fourth-order Runge–Kutta on a CasADi expression.

Every simulated plant (the planar arm's closed loop `closed_loop`, any arm's `arm_loop`, the cut-off study's
`studies.cutoff_plant`) holds the torque over a control tick and takes a fixed number of these steps within it.
"""

from __future__ import annotations

from collections.abc import Callable

import casadi as ca


def rk4_step(f: Callable[[ca.SX], ca.SX], x: ca.SX, h) -> ca.SX:
    """x after one RK4 step of length h [s] of ẋ = f(x) (f: the state's rate as an expression of the state)."""
    k1 = f(x)
    k2 = f(x + h / 2 * k1)
    k3 = f(x + h / 2 * k2)
    k4 = f(x + h * k3)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
