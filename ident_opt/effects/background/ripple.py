"""``ripple``: a current (torque) ripple locked to the motor angle, its amplitude ∝ joint speed."""

from __future__ import annotations

from ident_opt.effects.base import Background, Key


class Ripple(Background):
    name = "ripple"
    summary = "current (torque) ripple locked to the motor angle, amplitude ∝ joint speed: a v sin(c N q)"
    order = 3
    keys = {  # noqa: RUF012
        "amplitude": Key("pair", (1.3, 0.75), "N m per rad/s of joint speed, a, per joint", magnitude=True),
        "cycles": Key("pair", (1.0, 1.0), "c: cycles per motor revolution, per joint", 0.0, True),
    }


EFFECT = Ripple()
