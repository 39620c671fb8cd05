"""``stribeck``: a friction excess fs sgn(dq) exp(−(dq/vs)²) above the Coulomb level at low speed.

Model extension ``stribeck``: fs1 fs2, with the Stribeck velocities vs given (`ArmModel.stribeck_velocity`).
"""

from __future__ import annotations

from ident_opt.effects.base import Effect, Key


class Stribeck(Effect):
    name = "stribeck"
    summary = "friction excess fs sgn(dq) exp(-(dq/vs)^2) above the Coulomb level at low speed"
    order = 3
    keys = {  # noqa: RUF012
        "static": Key("pair", (0.3, 0.2), "N m, static excess fs over the Coulomb level, per joint", magnitude=True),
        "velocity": Key("pair", (0.05, 0.05), "rad/s, Stribeck velocity vs, per joint", 0.0, True),
    }


EFFECT = Stribeck()
