"""``stiction``: presliding (Dahl) friction, a resting joint holds a torque that depends on how it came to rest.

Per joint j, with its bristle deflection z_j [rad] an extra state of the plant,

    F_j = σ0_j z_j,   dz_j/dt = v_j − σ0_j |v_j| z_j / Fb_j,

v_j the encoder-side rate (the motor side at an elastic joint, where the gearbox is). Sliding,
F_j → Fb_j sgn(v_j) (a Coulomb-like level the rigid model absorbs); at rest z_j stays where the last motion
left it, so the joint holds a torque that depends on how it came to rest, and the PD (no integrator) keeps
whatever error it had. z starts at a random presliding state, uniform in |z| < Fb/σ0 (the arm came to rest
somehow before the trial).
"""

from __future__ import annotations

import math

from ident_opt.effects.base import Background, ca, np
from ident_opt.effects.keys import Key

#: rad/s: a bound of the joint speeds the trajectories reach (plateaus ≤ 1.33 rad/s, plus PD overshoot).
MAX_SPEED = 3.0


class Stiction(Background):
    summary = (
        "presliding (Dahl) friction: F = σ0 z, dz/dt = v − σ0 |v| z / Fb; a resting joint holds a torque that "
        "depends on how it came to rest; adds Fb to the sliding friction"
    )
    order = 1
    keys = {  # noqa: RUF012
        "breakaway": Key("pair", (0.6, 0.6), "N m, Fb: the friction the bristles carry, per joint", magnitude=True),
        "stiffness": Key("pair", (300.0, 150.0), "N m/rad, σ0: presliding stiffness, per joint", 0.0, True),
    }

    def states(self, p: dict) -> int:
        return 2

    def initial(self, p: dict, rng) -> np.ndarray:
        limit = np.asarray(p["breakaway"]) / np.asarray(p["stiffness"])
        return rng.uniform(-1.0, 1.0, 2) * limit

    def force(self, p: dict, z):
        return ca.DM(p["stiffness"]) * z

    def rate(self, p: dict, z, v):
        # Fb = 0 on a joint: its z stays at 0 (and starts there), so it adds no force.
        sigma = ca.DM(p["stiffness"])
        active = ca.DM([1.0 if b > 0 else 0.0 for b in p["breakaway"]])
        safe_fb = ca.DM([b if b > 0 else 1.0 for b in p["breakaway"]])
        return active * (v - sigma * ca.fabs(v) * z / safe_fb)

    def rates(self, p: dict, inertia) -> list[float]:
        # The bristle equation's σ0 v_max / Fb and the presliding oscillation √(σ0 / J).
        out = []
        for j in range(2):
            sigma, fb = p["stiffness"][j], p["breakaway"][j]
            if fb > 0:
                out += [sigma * MAX_SPEED / fb, math.sqrt(sigma / inertia[j])]
        return out


EFFECT = Stiction()
