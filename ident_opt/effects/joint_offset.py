"""``joint_offset``: encoder zero offsets, the true angle is the logged q + offset.

Model extension ``joint_offset`` (alias ``offset``): b1s b2s, the sin gravity columns an encoder zero
offset adds by rotating G.
"""

from __future__ import annotations

from ident_opt.effects.base import Effect, Key


class JointOffset(Effect):
    name = "joint_offset"
    summary = "encoder zero offsets: the true angle is the logged q + offset"
    order = 7
    keys = {"offset": Key("pair", (0.02, -0.03), "rad, per joint", None, magnitude=True)}  # noqa: RUF012


EFFECT = JointOffset()
