"""``elasticity``: a lightly damped mode, an elastic joint (two-mass, motor angle logged) or a flexible link."""

from __future__ import annotations

import math

from ident_opt.effects.base import Effect, Key


class Elasticity(Effect):
    name = "elasticity"
    summary = "a lightly damped mode: an elastic joint (two-mass, motor angle logged) or a flexible link"
    order = 4
    keys = {  # noqa: RUF012
        "joint": Key("joint", 2, "1 or 2"),
        "frequency_hz": Key("float", 3.0, "Hz, the mode's natural frequency with the joints held", 0.0, True),
        "damping": Key("float", 0.02, "damping ratio of that mode"),
        "kind": Key(
            "choice",
            "joint",
            "joint: two-mass elastic joint; link: link `joint` cut in two halves joined by a spring",
            None,
            choices=("joint", "link"),
        ),
    }

    def scaled(self, p: dict, s: float, coulomb: tuple[tuple, tuple]) -> dict:
        # Magnitude = compliance 1/k ∝ 1/f²: scale 0 is a rigid joint.
        p["frequency_hz"] = p["frequency_hz"] / math.sqrt(s) if s > 0 else math.inf
        return p

    def is_active(self, p: dict, coulomb: tuple[tuple, tuple]) -> bool:
        return math.isfinite(p["frequency_hz"])


EFFECT = Elasticity()
