"""``stiction``: presliding (Dahl) friction, a resting joint holds a torque that depends on how it came to rest."""

from __future__ import annotations

from ident_opt.effects.base import Background, Key


class Stiction(Background):
    name = "stiction"
    summary = (
        "presliding (Dahl) friction: F = σ0 z, dz/dt = v − σ0 |v| z / Fb; a resting joint holds a torque that "
        "depends on how it came to rest; adds Fb to the sliding friction"
    )
    order = 1
    keys = {  # noqa: RUF012
        "breakaway": Key("pair", (0.6, 0.6), "N m, Fb: the friction the bristles carry, per joint", magnitude=True),
        "stiffness": Key("pair", (300.0, 150.0), "N m/rad, σ0: presliding stiffness, per joint", 0.0, True),
    }


EFFECT = Stiction()
