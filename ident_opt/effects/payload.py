"""``payload``: an unmodelled point mass at the tip of link 2.

Simulator: the datasheet robot carries the mass (π changes along that direction). Diagnosis: the column
Y·∂π/∂m (π is affine in a tip mass m), m ≥ 0, against the datasheet.
"""

from __future__ import annotations

from dataclasses import replace

from ident_opt.effects.base import Effect, Key, cands, datasheet, report


class Payload(Effect):
    summary = "an unmodelled point mass at the tip of link 2"
    order = 5
    keys = {"mass": Key("float", 0.2, "kg", magnitude=True)}  # noqa: RUF012

    # ------------------------------------------------------------------ simulator: the robot carries it
    def true_robot(self, robot, p: dict):
        return replace(robot, payload_mass=robot.payload_mass + p["mass"])

    # ------------------------------------------------------------------ diagnosis
    judged = ("mass",)

    def families(self, robot) -> list:
        return [
            self.family(
                extra=lambda ds, th, dt, ctx: (self.column(ds, robot), ["mass"]),
                baselines=("datasheet",),
                nonnegative=("mass",),
                estimate=lambda p, se, ctx: ({"mass": p["mass"]}, {"se": se["mass"]}),
                # the mass found is carried by the joints: load-dependent friction scales with it too
                coupled=lambda p: {"payload_mass": p["mass"]},
            )
        ]

    def column(self, ds, robot):
        """Y·∂π/∂m (N, 2, 1): π is affine in a tip mass m (the combined link-2 inertia about joint 2 and its
        first moment are both linear in m), so the difference quotient at m = 1 kg is exact."""
        model = cands.NOMINAL
        heavier = self.true_robot(robot, {"mass": 1.0})
        d = model.vector(datasheet.datasheet_pi(heavier)) - model.vector(datasheet.datasheet_pi(robot))
        return (model.regressor(ds.q, ds.dq, ds.ddq) @ d)[:, :, None]

    def sentence(self, d, base: str, gain: str) -> str:
        return (
            f"Gravity and inertia are both off along the direction of a point mass at the tip of link 2: "
            f"an unmodelled payload of {report.num(d.estimate['mass'], 'kg')} explains it; {gain}"
        )

    def draw(self, rng, robot) -> dict:
        return {"mass": rng.uniform(0.1, 0.4)}


EFFECT = Payload()
