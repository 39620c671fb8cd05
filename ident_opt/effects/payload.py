"""``payload``: an unmodelled point mass at the tip of link 2.

Simulator: the datasheet robot carries the mass (π changes along that direction). Diagnosis: the column
Y·∂π/∂m (π is affine in a tip mass m), m ≥ 0, against the datasheet.
"""

from __future__ import annotations

import math
from dataclasses import replace

from ident_opt import wording
from ident_opt.effects.base import MAGNITUDE_TOL, Effect, least_squares, np, relative_error, signals
from ident_opt.effects.families import ChainFamily
from ident_opt.effects.keys import Key
from ident_opt.errors import InputError

#: How far [m] the centre-of-mass search reaches on each axis around its centre (`_centre`).
COM_SPAN = 0.06
#: A hidden payload's centre of mass is found within this distance [m] or this share of its distance from the
#: last link's origin.
COM_TOL = (0.02, 0.25)
#: Heaviest payload the simulator accepts [kg].
MAX_MASS = 1e3
#: An n-joint arm's default payload: this share of its moving links' mass, at `ARM_COM` [m] in the last link's frame.
ARM_SHARE, ARM_COM = 0.05, (0.0, 0.0, 0.05)
#: Plausibility (`diagnosis.plausibility`, docs/effects.md "Plausibility"): the physical range of the estimate, as data.
#: "rated_payload" and "flange" are the arm's own bounds, which the rule reads from the arm (`plausibility.Facts`).
PLAUSIBLE = (
    {
        "key": "mass",
        "most": "rated_payload",
        "unit": "kg",
        "why": "an arm carries at most its rated payload (a tool, a part); a heavier unmodelled mass is a wrong "
        "link mass or frame in the description",
    },
    {
        "key": "com",
        "most_norm": "flange",
        "unit": "m",
        "why": "a payload rides on the flange: its centre of mass lies near the last link's frame (a gripper's a "
        "decimetre or two out), not across the arm",
    },
)


class Payload(Effect):
    summary = "an unmodelled point mass at the tip of link 2"
    order = 5
    keys = {  # noqa: RUF012
        "mass": Key("float", 0.2, "kg", magnitude=True, maximum=MAX_MASS),
        "com": Key(
            "vector", None, "m, centre of mass in the last link's frame (n-joint arms; default [0,0,0.05])", None
        ),
    }

    def checked(self, params: dict, where: str, coulomb) -> dict:
        full = super().checked(params, where, coulomb)
        reach = getattr(getattr(coulomb, "scale", None), "reach", None)
        if full["com"] is not None and reach is not None and math.dist(full["com"], (0.0, 0.0, 0.0)) > reach:
            raise InputError(
                f"effect {where!r}: the payload's centre of mass {list(full['com'])} m lies "
                f"{math.dist(full['com'], (0.0, 0.0, 0.0)):.3g} m from the last link's frame, beyond the arm's "
                f"length ({reach:.3g} m): a payload rides on the last link"
            )
        return full

    def chain_default(self, key: str, joints) -> object:
        """An n-joint arm: `ARM_SHARE` of its moving mass, `ARM_COM` m out along the last link's z."""
        return ARM_SHARE * (joints.scale.mass or 4.0) if key == "mass" else ARM_COM

    # ------------------------------------------------------------------ simulator: the robot carries it
    def true_robot(self, robot, p: dict):
        if p.get("com") is not None:
            raise InputError(
                "effect payload: the planar two-link arm's payload is a point mass at the tip of link 2; it takes "
                "no com"
            )
        return replace(robot, payload_mass=robot.payload_mass + p["mass"])

    def truth_entry(self, truth, p: dict) -> dict:
        return {"mass": p["mass"]}

    def chain_plant(self, plant, p: dict) -> None:
        plant.pi = plant.pi + plant.robot.payload(plant.arm, p["mass"], p["com"])

    def chain_truth(self, plant, p: dict) -> dict:
        return {"mass": p["mass"], "com": list(p["com"])}

    def chain_families(self, ctx) -> list:
        """m · Y Δπ(1 kg at c) (`Robot.payload`: π is linear in the mass for a given centre of mass c), m ≥ 0,
        against the datasheet; c searched ±`COM_SPAN` m per axis around the centre a linear fit of (m, m c) gives
        (`_centre`)."""
        return [
            ChainFamily(
                self.name,
                extra=_arm_column,
                axes=lambda rate, theta: [least_squares.Axis(f"com_{a}", -COM_SPAN, COM_SPAN, 7) for a in "xyz"],
                center=_centre,
                baselines=("datasheet",),
                nonnegative=("mass",),
                estimate=lambda p, se, ctx: (
                    {"mass": p["mass"], "com": [p["com_x"], p["com_y"], p["com_z"]]},
                    {"se_mass": se.get("mass")},
                ),
            )
        ]

    def chain_draw(self, rng, joints, chosen) -> dict:
        """3–8 % of the arm's moving mass, a few centimetres off the last link's origin (z outward)."""
        u = rng.uniform
        return {
            "mass": u(0.03, 0.08) * (joints.scale.mass or 4.0),
            "com": (u(-0.03, 0.03), u(-0.03, 0.03), u(0.02, 0.08)),
        }

    def chain_judge(self, estimate: dict, truth: dict) -> list[tuple[bool, float]]:
        """The mass within `MAGNITUDE_TOL`; the centre of mass within `COM_TOL` m, or that share of its distance."""
        mass = relative_error(estimate["mass"], truth["mass"])
        miss = math.dist(estimate["com"], truth["com"])
        far = math.dist(truth["com"], (0.0, 0.0, 0.0))
        return [(mass <= MAGNITUDE_TOL, mass), (miss <= max(COM_TOL[0], COM_TOL[1] * far), miss / max(far, 1e-9))]

    # ------------------------------------------------------------------ diagnosis
    judged = ("mass",)
    plausible = PLAUSIBLE

    def families(self, ctx) -> list:
        return [
            self.family(
                extra=lambda ds, th, dt, ctx: _moving_and_held(self.column(ds, ctx), ds.dq),
                baselines=("datasheet",),
                nonnegative=("mass_held", "mass_extra"),
                estimate=_estimate,
                # the mass found is carried by the joints: load-dependent friction scales with it too
                coupled=lambda p: {"payload_mass": p["mass_held"] + p["mass_extra"]},
            )
        ]

    def column(self, ds, ctx):
        """Y·∂π/∂m (N, 2, 1) in the planar diagnosis's context `ctx`: π is affine in a tip mass m (the combined
        link-2 inertia about joint 2 and its first moment are both linear in m), so the difference quotient at
        m = 1 kg is exact."""
        model, robot = ctx.nominal, ctx.robot
        heavier = self.true_robot(robot, {"mass": 1.0})
        d = model.vector(heavier.grouped("physical")) - model.vector(robot.grouped("physical"))
        return (model.regressor(ds.q, ds.dq, ds.ddq) @ d)[:, :, None]

    def sentence(self, d, base: str, gain: str) -> str:
        return (
            f"Gravity and inertia are both off along the direction of a point mass at the tip of link 2: "
            f"an unmodelled payload of {wording.num(d.estimate['mass'], 'kg')} explains it; {gain}"
        )

    def draw(self, rng, robot) -> dict:
        return {"mass": rng.uniform(0.1, 0.4)}


def _arm_column(ds, theta: dict, ctx, baseline: str) -> tuple[np.ndarray, list[str]]:
    """Y Δπ (N, n, 1) of a 1 kg point mass at θ's centre of mass on the last link."""
    com = [theta.get(f"com_{a}", 0.0) for a in "xyz"]
    return (ctx.regressor(ds) @ ctx.robot.payload(ctx.arm, 1.0, com))[:, :, None], ["mass"]


def _centre(family, baseline: str, ctx) -> dict:
    """Where the centre-of-mass search is centred [m]: c = h / m from a linear fit of (m, h = m c) to the datasheet's
    training residual, the inertia of the point mass left out (second order in c); (0, 0, 0) when m ≤ 0."""
    tr = ctx.train
    Y = ctx.regressor(tr)
    unit = ctx.robot.payload(ctx.arm, 1.0, (0.0, 0.0, 0.0))
    eps = 1e-6
    basis = [unit] + [(ctx.robot.payload(ctx.arm, 1.0, e) - unit) / eps for e in (eps * np.eye(3)).tolist()]
    X = np.stack([Y @ b for b in basis], axis=2)
    labels = ctx.labels(tr)
    r = tr.tau - Y @ ctx.datasheet
    fit = least_squares.solve(
        np.zeros_like(r), signals.demean_runs(X, labels), signals.demean_runs(r, labels), ctx.weights, False
    )
    m, h = fit.beta[0], fit.beta[1:]
    if not m > 0:
        return {"com_x": 0.0, "com_y": 0.0, "com_z": 0.0}
    return {f"com_{a}": float(np.clip(v / m, -1.0, 1.0)) for a, v in zip("xyz", h)}


def _moving_and_held(column: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """The payload column (N, 2, 1) as two (N, 2, 2): `mass_held` on every sample, and `mass_extra` on every
    sample except the variation within a joint's rest stretches (on joint j's row). The mass is their sum:
    it sets the prediction where the joint moves and the level of each rest stretch; the variation within a
    rest stretch is `mass_held` × the column's.

    A joint at rest while the other moves is held by its friction: its logged torque follows what the
    controller commands (its feed-forward, the model without the payload) up to the friction the rest can
    hold, so only part of the payload's torque variation shows there (38–80 % of its gravity, 0–17 % of its
    inertial coupling on simulated trials). Read from every sample alike, the mass came out 3–6 % low; with
    a coefficient of its own the held variation no longer pulls it down, and every other estimate still sees
    those samples (an encoder offset shows whole there). Both coefficients ≥ 0 keep the held share between 0
    and the mass, also where joints rarely rest (a smooth trial) and that share is barely determined."""
    labels = signals.rest_runs(dq)
    variation = np.where((labels >= 0)[:, :, None], signals.demean_runs(column, labels), 0.0)
    return np.concatenate([column, column - variation], axis=2), ["mass_held", "mass_extra"]


def _estimate(p: dict, se: dict, ctx) -> tuple[dict, dict]:
    """m = mass_held + mass_extra; its standard error bounded above by se_held + se_extra (their
    correlation, negative, not counted)."""
    detail = {"se": se["mass_held"] + se["mass_extra"], "mass_held": p["mass_held"]}
    return {"mass": p["mass_held"] + p["mass_extra"]}, detail


EFFECT = Payload()
