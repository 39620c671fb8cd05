"""``payload``: an unmodelled point mass at the tip of link 2."""

from __future__ import annotations

from dataclasses import replace

from ident_opt.effects.base import Effect, Key


class Payload(Effect):
    name = "payload"
    summary = "an unmodelled point mass at the tip of link 2"
    order = 5
    keys = {"mass": Key("float", 0.2, "kg", magnitude=True)}  # noqa: RUF012

    # ------------------------------------------------------------------ simulator: the robot carries it
    def true_robot(self, robot, p: dict):
        return replace(robot, payload_mass=robot.payload_mass + p["mass"])


EFFECT = Payload()
