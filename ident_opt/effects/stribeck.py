"""``stribeck``: a friction excess fs sgn(dq) exp(−(dq/vs)²) above the Coulomb level at low speed.

Model extension ``stribeck``: fs1 fs2, with the Stribeck velocities vs given (`ArmModel.stribeck_velocity`).
"""

from __future__ import annotations

from ident_opt.effects.base import Effect, Key, deferred
from ident_opt.parameters import Parameter

np = deferred("numpy")
ca = deferred("casadi")


class Stribeck(Effect):
    name = "stribeck"
    summary = "friction excess fs sgn(dq) exp(-(dq/vs)^2) above the Coulomb level at low speed"
    order = 3
    keys = {  # noqa: RUF012
        "static": Key("pair", (0.3, 0.2), "N m, static excess fs over the Coulomb level, per joint", magnitude=True),
        "velocity": Key("pair", (0.05, 0.05), "rad/s, Stribeck velocity vs, per joint", 0.0, True),
    }

    # ------------------------------------------------------------------ model: fsj sgn(dq_j) exp(−(dq_j/vs_j)²)
    parameters = tuple(
        Parameter(f"fs{j}", "N m", f"joint-{j} Stribeck excess over the Coulomb level", "friction") for j in (1, 2)
    )

    def columns(self, model) -> dict:
        zero, vs = np.zeros_like, model.stribeck_velocity
        return {
            "fs1": lambda q, dq, a: (np.sign(dq[:, 0]) * np.exp(-((dq[:, 0] / vs[0]) ** 2)), zero(dq[:, 0])),
            "fs2": lambda q, dq, a: (zero(dq[:, 1]), np.sign(dq[:, 1]) * np.exp(-((dq[:, 1] / vs[1]) ** 2))),
        }

    def add_terms(self, model, q, dq, p: dict, M: list, G: list, F: list) -> None:
        for j in range(2):
            vs = model.stribeck_velocity[j]
            F[j] = F[j] + p["fs" + str(j + 1)] * ca.sign(dq[j]) * ca.exp(-((dq[j] / vs) ** 2))

    # ------------------------------------------------------------------ simulator: the model extension's friction
    def true_plant(self, plant, p: dict) -> None:
        plant.extensions.append(self.name)
        plant.pi["fs1"], plant.pi["fs2"] = p["static"]
        plant.options["stribeck_velocity"] = tuple(p["velocity"])

    def truth_entry(self, truth, p: dict) -> dict:
        # The static level fs is above the true plant's (mean) Coulomb level.
        levels = [truth.pi_rigid["fc1"], truth.pi_rigid["fc2"]]
        return {**p, "static_level": [c + s for c, s in zip(levels, p["static"])]}


EFFECT = Stribeck()
