"""``load_friction``: Coulomb friction that grows with the torque the gears transmit, fc + μ·|τ_load|.

τ_load is the link-side rigid-body torque of the joint: inertial (without the rotor's reflected inertia),
Coriolis/centrifugal and gravity, friction excluded. μ is dimensionless, one per joint (0: untouched).
Simulator: the plant's friction gains μ_j sgn(dq_j) |τ_load,j(q, dq, ddq)|, solved with the acceleration
it depends on (`simulator.truth`). Diagnosis: the columns sgn(dq_j)|τ_load,j| with τ_load from the
datasheet's link-side π at the measured motion, μ ≥ 0 linear, against both nominal models; beside a payload
the diagnosis has found, τ_load includes the payload's torque (the mass re-read until it settles).
"""

from __future__ import annotations

from ident_opt import wording
from ident_opt.effects.base import Effect, arm_values, np, per_joint_draw
from ident_opt.effects.families import (
    ChainFamily,
    one_coefficient_per_joint,
    per_joint_columns,
    selected,
)
from ident_opt.effects.keys import Key
from ident_opt.effects.payload import EFFECT as PAYLOAD

#: A hidden coefficient is found within this relative error (or within `ZERO_TOL` of an untouched 0).
COEFFICIENT_TOL = 0.25
#: Largest |μ| [-] that still reads as an untouched joint.
ZERO_TOL = 0.02
#: Least efficiency of a gear (`PLAUSIBLE`): a drive that loses more than half the torque it transmits is no gear.
LEAST_EFFICIENCY = 0.5
#: Plausibility (`diagnosis.plausibility`, docs/effects.md "Plausibility"): the physical range of the estimate, as data.
PLAUSIBLE = (
    {
        "key": "coefficient",
        "most": 1.0 / LEAST_EFFICIENCY - 1.0,
        "se": "se",
        "unit": "",
        "why": "a gear of efficiency η passes η of the torque its motor gives, so the friction that grows with the "
        "transmitted torque is μ = 1/η − 1 of it; an efficiency of at least 50 % (harmonic drives 60–90 %, "
        "planetary and spur gears 70–95 %, worm gears down to 50 %) bounds μ ≤ 1 (MERIt's 230:1 drive at μ 0.44 "
        "is a 70 % gear)",
    },
)


class LoadFriction(Effect):
    summary = "Coulomb friction that grows with the transmitted torque: fc + mu |tau_load|"
    order = 9
    keys = {  # noqa: RUF012
        "coefficient": Key("pair", (0.1, 0.1), "mu per joint, dimensionless (< 0.9)", magnitude=True, maximum=0.9),
    }

    # ------------------------------------------------------------------ simulator: friction on the link torque
    def true_plant(self, plant, p: dict) -> None:
        plant.load_friction = [a + b for a, b in zip(plant.load_friction, p["coefficient"])]

    def chain_plant(self, plant, p: dict) -> None:
        plant.load_friction = plant.load_friction + np.asarray(p["coefficient"])

    def chain_families(self, ctx) -> list:
        """sgn(dq_j)|τ_load,j| on joint j's row (τ_load the datasheet's link-side torque at the measured motion),
        μ ≥ 0, on the joints where it is resolved; against both nominal models."""
        return [
            ChainFamily(
                self.name,
                extra=lambda ds, theta, ctx, baseline: per_joint_columns(
                    np.abs(ctx.link_torque(ds)) * np.sign(ds.dq), selected(theta, self.name, ctx.n), "mu"
                ),
                **one_coefficient_per_joint("coefficient", "mu"),
            )
        ]

    def chain_draw(self, rng, joints, chosen) -> dict:
        return {"coefficient": arm_values(joints.n, chosen, 0.0, lambda j: rng.uniform(0.08, 0.25))}

    def chain_judge(self, estimate: dict, truth: dict) -> list[tuple[bool, float]]:
        return self.judge(estimate, truth)

    # ------------------------------------------------------------------ diagnosis
    judged = ("coefficient",)
    plausible = PLAUSIBLE

    def families(self, ctx) -> list:
        return [self.family(extra=_columns, nonnegative=("mu1", "mu2"), estimate=_estimate)]

    def sentence(self, d, base: str, gain: str) -> str:
        return (
            f"Friction grows with the torque the joints transmit: a Coulomb level fc + μ·|τ_load| with "
            f"μ = {wording.pair(d.estimate['coefficient'])} explains the residual; {gain}"
        )

    def draw(self, rng, robot) -> dict:
        return {"coefficient": per_joint_draw(rng, 0.0, lambda: rng.uniform(0.08, 0.25))}

    def judge(self, estimate: dict, truth: dict) -> list[tuple[bool, float]]:
        checks = []
        for e, t in zip(estimate["coefficient"], truth["coefficient"]):
            if t == 0:
                checks.append((abs(e) <= ZERO_TOL, abs(e)))
            else:
                rel = abs(e - t) / abs(t)
                checks.append((rel <= COEFFICIENT_TOL, rel))
        return checks


def link_torque(ds, ctx) -> np.ndarray:
    """τ_load (N, 2) [N m]: the datasheet's link-side rigid torque at the measured motion (friction and the
    rotors' reflected inertia removed)."""
    model = ctx.nominal
    pi = model.link_side(model.vector(ctx.datasheet), ctx.armature)
    return model.predict(pi, ds.q, ds.dq, ds.ddq)


def _columns(ds, theta: dict, dt: float, ctx) -> tuple[np.ndarray, list[str]]:
    """sgn(dq_j)·|τ_load,j| on joint j's row (coefficient μ_j). A payload the model has found
    (θ's `payload_mass` [kg], `Family.coupled`) is part of the load the gears transmit."""
    tau_load = link_torque(ds, ctx)
    if theta.get("payload_mass", 0.0):
        tau_load = tau_load + theta["payload_mass"] * PAYLOAD.column(ds, ctx)[:, :, 0]
    load = np.abs(tau_load) * np.sign(ds.dq)
    X = np.zeros((ds.n, 2, 2))
    X[:, 0, 0], X[:, 1, 1] = load[:, 0], load[:, 1]
    return X, ["mu1", "mu2"]


def _estimate(p: dict, se: dict, ctx) -> tuple[dict, dict]:
    """μ per joint; a joint whose μ is not resolved from zero (≤ 3 standard errors) reports 0."""
    mu = [p[k] if p[k] > 3.0 * se[k] else 0.0 for k in ("mu1", "mu2")]
    return {"coefficient": mu}, {"se": [se["mu1"], se["mu2"]]}


EFFECT = LoadFriction()
