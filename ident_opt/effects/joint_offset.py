"""``joint_offset``: encoder zero offsets, the true angle is the logged q + offset.

Model extension ``joint_offset`` (alias ``offset``): b1s b2s, the sin gravity columns an encoder zero
offset adds by rotating G.
"""

from __future__ import annotations

from ident_opt.effects.base import Effect, Key, deferred
from ident_opt.parameters import Parameter

np = deferred("numpy")
ca = deferred("casadi")


class JointOffset(Effect):
    name = "joint_offset"
    summary = "encoder zero offsets: the true angle is the logged q + offset"
    order = 7
    keys = {"offset": Key("pair", (0.02, -0.03), "rad, per joint", None, magnitude=True)}  # noqa: RUF012

    # ------------------------------------------------------------------ model: G rotated by δ
    parameters = (
        Parameter("b1s", "N m", "sin q1 gravity column: an encoder zero offset rotates G", "gravity"),
        Parameter("b2s", "N m", "sin(q1 + q2) gravity column", "gravity"),
    )
    aliases = ("offset",)

    def check_model(self, model) -> None:
        if model.gravity == "paper":
            raise ValueError("the offset extension needs the physical gravity vector")

    def columns(self, model) -> dict:
        zero, s = np.zeros_like, np.sin
        return {
            "b1s": lambda q, dq, a: (s(q[:, 0]), zero(q[:, 0])),
            "b2s": lambda q, dq, a: (s(q[:, 0] + q[:, 1]), s(q[:, 0] + q[:, 1])),
        }

    def add_terms(self, model, q, dq, p: dict, M: list, G: list, F: list) -> None:
        s1, s12 = ca.sin(q[0]), ca.sin(q[0] + q[1])
        G[0] = G[0] + (p["b1s"] * s1 + p["b2s"] * s12)
        G[1] = G[1] + p["b2s"] * s12

    # ------------------------------------------------------------------ simulator: the encoders' zero
    def true_plant(self, plant, p: dict) -> None:
        plant.offset = [a + b for a, b in zip(plant.offset, p["offset"])]


EFFECT = JointOffset()
