"""``armature``: extra reflected rotor inertia on the diagonal of M, beyond the datasheet's.

Model extension ``armature``: the joint-2 reflected rotor inertia ia2 on M22 (joint 1's is folded into a1).
"""

from __future__ import annotations

from ident_opt.effects.base import Effect, Key, deferred
from ident_opt.parameters import Parameter

np = deferred("numpy")


class Armature(Effect):
    name = "armature"
    summary = "extra reflected rotor inertia on the diagonal of M, beyond the datasheet's"
    order = 1
    keys = {  # noqa: RUF012
        "inertia": Key("pair", (0.25, 0.025), "kg m^2, joint side, per joint", magnitude=True),
    }

    # ------------------------------------------------------------------ model: ia2 on M22
    parameters = (Parameter("ia2", "kg m^2", "joint-2 reflected rotor inertia N² J", "armature"),)

    def columns(self, model) -> dict:
        return {"ia2": lambda q, dq, a: (np.zeros_like(a[:, 1]), a[:, 1])}

    def add_terms(self, model, q, dq, p: dict, M: list, G: list, F: list) -> None:
        M[1][1] = M[1][1] + p["ia2"]

    # ------------------------------------------------------------------ simulator: J1 on a1, J2 on ia2
    def true_plant(self, plant, p: dict) -> None:
        J1, J2 = p["inertia"]
        plant.pi["a1"] += J1
        plant.pi["ia2"] += J2
        plant.armature = [a + J for a, J in zip(plant.armature, p["inertia"])]

    def true_physical(self, physical: dict, p: dict) -> None:
        physical["armature"] = [a + J for a, J in zip(physical["armature"], p["inertia"])]


EFFECT = Armature()
