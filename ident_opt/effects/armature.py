"""``armature``: extra reflected rotor inertia on the diagonal of M, beyond the datasheet's.

Model extension ``armature``: the joint-2 reflected rotor inertia ia2 on M22 (joint 1's is folded into a1).
Simulator: the extra J1 on a1 and J2 on ia2 (the diagonal of M). Diagnosis: J1·ddq1 on joint 1's row and
J2·ddq2 on joint 2's (the a1 and ia2 directions), J ≥ 0, against the datasheet.
"""

from __future__ import annotations

from ident_opt import wording
from ident_opt.effects.base import Effect, arm_values, np
from ident_opt.effects.families import (
    ChainFamily,
    one_coefficient_per_joint,
    per_joint_columns,
    selected,
)
from ident_opt.effects.keys import Key
from ident_opt.parameters import Parameter

#: An n-joint arm's default extra inertia, as a share of each joint's nominal diagonal inertia.
ARM_SHARE = 0.3


#: Plausibility (`diagnosis.plausibility`, docs/effects.md "Plausibility"): no range beyond J ≥ 0, which the fit holds:
#: a reflected rotor inertia N² J_rotor can exceed the link's own many times over on a high-ratio drive (230:1 with a
#: 1e-5 kg m² rotor is 0.5 kg m²), and the problem gives no motor data to bound it.
PLAUSIBLE: tuple = ()


class Armature(Effect):
    summary = "extra reflected rotor inertia on the diagonal of M, beyond the datasheet's"
    order = 1
    keys = {  # noqa: RUF012
        "inertia": Key("pair", (0.25, 0.025), "kg m^2, joint side, per joint", magnitude=True, maximum=1e3),
    }

    # ------------------------------------------------------------------ model: ia2 on M22
    parameters = (Parameter("ia2", "kg m^2", "joint-2 reflected rotor inertia N² J", "armature", 2),)

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

    # ------------------------------------------------------------------ any arm: J on the diagonal of M
    def chain_default(self, key: str, joints) -> object:
        """An n-joint arm: a third of each joint's nominal diagonal inertia (`ArmScale.inertia`)."""
        return tuple(ARM_SHARE * J for J in joints.scale.inertia)

    def chain_plant(self, plant, p: dict) -> None:
        plant.inertia = plant.inertia + np.asarray(p["inertia"])

    def chain_families(self, ctx) -> list:
        """J_j ddq_j on joint j's row, J ≥ 0, on the joints where it is resolved, against the datasheet."""
        return [
            ChainFamily(
                self.name,
                extra=_arm_columns,
                baselines=("datasheet",),
                **one_coefficient_per_joint("inertia", "j"),
            )
        ]

    def chain_draw(self, rng, joints, chosen) -> dict:
        return {"inertia": arm_values(joints.n, chosen, 0.0, lambda j: rng.uniform(0.2, 0.5) * joints.scale.inertia[j])}

    # ------------------------------------------------------------------ diagnosis
    judged = ("inertia",)
    plausible = PLAUSIBLE

    def families(self, ctx) -> list:
        return [
            self.family(
                extra=_columns,
                baselines=("datasheet",),
                nonnegative=("j1", "j2"),
                estimate=_estimate,
            )
        ]

    def sentence(self, d, base: str, gain: str) -> str:
        return (
            f"The {base} model lacks inertia on the diagonal of M: reflected rotor inertia of "
            f"J = {wording.pair(d.estimate['inertia'], 'kg m²')} (joint side) explains the residual; {gain}"
        )

    def draw(self, rng, robot) -> dict:
        u = rng.uniform
        return {"inertia": (u(0.1, 0.4), u(0.01, 0.04))}


def _columns(ds, theta: dict, dt: float, ctx) -> tuple[np.ndarray, list[str]]:
    """Extra reflected inertia J_j on the diagonal of M: J1·ddq1 on joint 1's row, J2·ddq2 on joint 2's
    (the a1 and ia2 columns of the nominal structure)."""
    X = np.zeros((ds.n, 2, 2))
    X[:, 0, 0], X[:, 1, 1] = ds.ddq[:, 0], ds.ddq[:, 1]
    return X, ["j1", "j2"]


def _estimate(p: dict, se: dict, ctx) -> tuple[dict, dict]:
    return {"inertia": [p["j1"], p["j2"]]}, {"se": [se["j1"], se["j2"]]}


def _arm_columns(ds, theta: dict, ctx, baseline: str) -> tuple[np.ndarray, list[str]]:
    """J_j ddq_j on joint j's row, for the joints θ selects (an n-joint arm)."""
    return per_joint_columns(ds.ddq, selected(theta, "armature", ctx.n), "j")


EFFECT = Armature()
