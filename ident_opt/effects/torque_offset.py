"""``torque_offset``: the torque channel reads a constant offset per joint: τ_logged = τ + b.

A current monitor's or amplifier's zero, a torque sensor's tare: τ_logged,j = τ_j + b_j (b_j = 0 untouched). Simulator:
b added to the logged torque channel, after every other channel effect (the logger's end). Diagnosis: a constant
column b_j on joint j's row, against both nominal models (a refitted π has no constant: gravity, friction and inertia
all vary with the motion); on an arm whose model carries offsets already (`offsets = true`), against the datasheet
only.

Told from asymmetric Coulomb friction, which is a constant while moving too (the scored residual is compared about each
stop's mean, so the two fit alike): an offset stays at rest, where friction holds no level of its own, so a candidate
whose offset the rest samples do not show is unresolved (`_at_rest`); and an asymmetric level that vanishes in one
direction is not friction (`asymmetric_coulomb`'s plausibility).
"""

from __future__ import annotations

from ident_opt import wording
from ident_opt.effects.base import Effect, arm_values, np, per_joint_draw, signals
from ident_opt.effects.families import ChainFamily, per_joint, per_joint_columns, resolved_joints, selected, step
from ident_opt.effects.keys import Key

#: Largest |b_j| as a share of joint j's largest logged torque (`PLAUSIBLE`).
MOST_SHARE = 0.25
#: An offset stays at rest: there the residual of the model without it must show at least this share of b_j, with
#: its sign, on every joint whose b_j is at least `CHECKED` of the largest (`_at_rest`). Simulated offsets show
#: 0.98–1.02 of b there; the simulator's asymmetric Coulomb friction, whose levels also read as a constant while moving,
#: 0.66–0.71 (the joint dithers at its stops, so its friction averages to the mean level); MERIt's joint 2 shows 2.0.
#: Set between them, knowing all three.
AT_REST_SHARE = 0.85
CHECKED = 0.25
#: Plausibility (`diagnosis.plausibility`, docs/effects.md "Plausibility"): the physical range of the estimate, as data.
PLAUSIBLE = (
    {
        "key": "offset",
        "most_share": MOST_SHARE,
        "of": "torque_logged",
        "unit": "N m",
        "why": "a current monitor's zero is specified to a few per cent of its drive's full scale, a joint logged well "
        "below its rating reads it as a larger share of what it logs (MERIt's third drive, which never moves, reads "
        "−0.07 A at rest on both trials, 9 % of joint 2's largest logged current); an offset beyond a quarter of the "
        "largest torque the joint logged is a channel read wrongly (a unit, a sign, a missing tare), not a zero error",
    },
)


class TorqueOffset(Effect):
    summary = "the torque channel reads a constant offset per joint: tau_logged = tau + b"
    order = 10
    keys = {  # noqa: RUF012
        "offset": Key(
            "pair", (0.3, 0.0), "N m per joint, added to the logged torque", None, magnitude=True, maximum=1e4
        ),
    }

    def untouched(self, key: str, joint: int, joints) -> float:
        return 0.0

    def chain_default(self, key: str, joints) -> object:
        """An n-joint arm: 3 % of joint 1's reference torque on joint 1, the others untouched."""
        return (0.03 * joints.scale.torque[0],) + (0.0,) * (joints.n - 1)

    def is_active(self, p: dict, coulomb: tuple[tuple, tuple]) -> bool:
        return any(b != 0.0 for b in p["offset"])

    # ------------------------------------------------------------------ simulator: b added to the logged channel
    def true_plant(self, plant, p: dict) -> None:
        b = np.asarray(p["offset"], dtype=float)
        plant.channel.append(lambda t, tau: tau + b)

    def chain_plant(self, plant, p: dict) -> None:
        self.true_plant(plant, p)

    def chain_families(self, ctx) -> list:
        """b_j on joint j's row, on the joints where it is resolved; against the rigid fit too unless the arm's π has
        offsets of its own."""
        own = "off" in getattr(ctx.arm, "joint_terms", ())
        return [
            ChainFamily(
                self.name,
                extra=_arm_columns,
                baselines=("datasheet",) if own else ("datasheet", "rigid_fit"),
                estimate=lambda p, se, ctx: ({"offset": per_joint(p, "b", ctx.n)}, {"se": per_joint(se, "b", ctx.n)}),
                screen=lambda p, se, ctx: resolved_joints(p, se, ("b",), ctx.n),
                check=_at_rest,
            )
        ]

    def chain_draw(self, rng, joints, chosen) -> dict:
        """On each chosen joint ±2–5 % of its reference torque."""
        return {
            "offset": arm_values(
                joints.n,
                chosen,
                0.0,
                lambda j: rng.choice([-1.0, 1.0]) * rng.uniform(0.02, 0.05) * joints.scale.torque[j],
            )
        }

    # ------------------------------------------------------------------ diagnosis
    judged = ("offset",)
    plausible = PLAUSIBLE

    def families(self, ctx) -> list:
        return [self.family(extra=_columns, estimate=_estimate, check=_at_rest)]

    def sentence(self, d, base: str, gain: str) -> str:
        return (
            "The logged torque carries a constant offset per joint, at rest and moving alike (a current monitor's "
            f"or a torque sensor's zero): b = {wording.pair(d.estimate['offset'], 'N m')}; {gain}"
        )

    def draw(self, rng, robot) -> dict:
        """±0.5–1 × each joint's datasheet Coulomb level (a zero error of the size friction has), on joint 1, 2 or
        both."""
        fc = robot.rigid_body("physical").fc
        signs = rng.choice([-1.0, 1.0], size=2)
        drawn = iter([signs[0] * rng.uniform(0.5, 1.0), signs[1] * rng.uniform(0.5, 1.0)])
        factors = per_joint_draw(rng, 0.0, lambda: next(drawn))
        return {"offset": tuple(f * level for f, level in zip(factors, fc))}

    def judge(self, estimate: dict, truth: dict) -> list[tuple[bool, float]]:
        # An untouched joint's 0 is judged against the largest true offset, as on an n-joint arm.
        return self.chain_judge(estimate, truth)


def _columns(ds, theta: dict, dt: float, ctx) -> tuple[np.ndarray, list[str]]:
    """A constant b_j on joint j's row."""
    X = np.zeros((ds.n, 2, 2))
    X[:, 0, 0], X[:, 1, 1] = 1.0, 1.0
    return X, ["b1", "b2"]


def _estimate(p: dict, se: dict, ctx) -> tuple[dict, dict]:
    return {"offset": [p["b1"], p["b2"]]}, {"se": [se["b1"], se["b2"]]}


def _arm_columns(ds, theta: dict, ctx, baseline: str) -> tuple[np.ndarray, list[str]]:
    """b_j on joint j's row, for the joints θ selects (an n-joint arm)."""
    return per_joint_columns(np.ones((ds.n, ctx.n)), selected(theta, "torque_offset", ctx.n), "b")


def _at_rest(predict, theta: dict, ctx, params: dict) -> tuple[dict, str | None]:
    """The offset read at rest (training part): b_j + the mean residual of the candidate over joint j's rest samples
    (`signals.resting`), which is the level the rest samples show beyond the model without the offset. Unresolved when
    a joint whose b_j is at least `CHECKED` of the largest shows less than `AT_REST_SHARE` of it there, or the other
    sign: a constant only while moving is friction's (asymmetric Coulomb), not the channel's."""
    tr = ctx.train
    b = np.array([float(params.get(f"b{j + 1}", 0.0)) for j in range(tr.tau.shape[1])])
    rest = signals.resting(tr.dq, step(tr))
    r = tr.tau - predict(tr)
    seen = [float(b[j] + r[rest[:, j], j].mean()) if rest[:, j].sum() >= 10 else None for j in range(len(b))]
    largest = float(np.max(np.abs(b))) if len(b) else 0.0
    weak = [
        j
        for j, s in enumerate(seen)
        if s is not None and abs(b[j]) >= CHECKED * largest > 0 and s * np.sign(b[j]) < AT_REST_SHARE * abs(b[j])
    ]
    found = {"at_rest": seen}
    if not weak:
        return found, None
    joints = ", ".join(f"joint {j + 1} ({seen[j]:.3g} of {b[j]:.3g} N m)" for j in weak)
    return found, (
        f"the rest samples do not show the offset on {joints}: a constant only while moving is asymmetric friction's"
    )


EFFECT = TorqueOffset()
