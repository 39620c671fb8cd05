"""``delay``: the torque (or current) channel lags the encoder channel."""

from __future__ import annotations

from ident_opt.effects.base import Effect, Key


class Delay(Effect):
    name = "delay"
    summary = "the torque (or current) channel lags the encoder channel"
    order = 6
    keys = {"seconds": Key("float", 0.02, "s", magnitude=True)}  # noqa: RUF012


EFFECT = Delay()
