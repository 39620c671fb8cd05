"""``armature``: extra reflected rotor inertia on the diagonal of M, beyond the datasheet's.

Model extension ``armature``: the joint-2 reflected rotor inertia ia2 on M22 (joint 1's is folded into a1).
"""

from __future__ import annotations

from ident_opt.effects.base import Effect, Key


class Armature(Effect):
    name = "armature"
    summary = "extra reflected rotor inertia on the diagonal of M, beyond the datasheet's"
    order = 1
    keys = {  # noqa: RUF012
        "inertia": Key("pair", (0.25, 0.025), "kg m^2, joint side, per joint", magnitude=True),
    }


EFFECT = Armature()
