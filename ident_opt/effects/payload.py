"""``payload``: an unmodelled point mass at the tip of link 2."""

from __future__ import annotations

from ident_opt.effects.base import Effect, Key


class Payload(Effect):
    name = "payload"
    summary = "an unmodelled point mass at the tip of link 2"
    order = 5
    keys = {"mass": Key("float", 0.2, "kg", magnitude=True)}  # noqa: RUF012


EFFECT = Payload()
