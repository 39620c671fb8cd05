"""``drift``: a slow torque disturbance on the joints (cable drag, thermal), an Ornstein-Uhlenbeck process."""

from __future__ import annotations

from ident_opt.effects.base import Background, Key


class Drift(Background):
    name = "drift"
    summary = "a slow torque disturbance on the joints (cable drag, thermal): an Ornstein-Uhlenbeck process"
    order = 2
    keys = {  # noqa: RUF012
        "std": Key("pair", (0.7, 0.2), "N m, its standard deviation, per joint", magnitude=True),
        "time": Key("float", 4.0, "s, its correlation time", 0.0, True),
    }


EFFECT = Drift()
