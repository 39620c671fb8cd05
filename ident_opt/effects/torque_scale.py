"""``torque_scale``: the logged torque is off by a factor per joint, the true joint torque is s × the logged one.

A wrong torque constant, gear ratio or current-to-torque factor: τ_logged,j = τ_j / s_j (s_j = 1 for an
untouched joint). Simulator: the logged torque channel divided by s. Diagnosis: against the datasheet,
τ_logged,j = c_j (Y π_datasheet)_j with c_j = 1/s_j linear, s per joint.

Not against the rigid fit: a refitted π absorbs any factor common to both joints, so there only the ratio
s2/s1 shows (through the parameters both rows share). Such a version (row 2 divided by a searched ratio,
reporting s = [1, r]) was tried: on a hidden s = [0.905, 1] it beat the datasheet version on the common
footing by fitting the rigid fit's better joint-2 residual, ranked below armature and got the trial misnamed.
"""

from __future__ import annotations

from functools import partial

from ident_opt import wording
from ident_opt.effects.base import Effect, arm_values, np, per_joint_draw, relative_error
from ident_opt.effects.families import ChainFamily, resolved_joints
from ident_opt.effects.keys import Key

#: A hidden factor is found when the estimate is within this of it, per joint. It is also the resolution floor: a
#: factor within it of 1 is not named (`TorqueScale.resolved`), since the diagnosis claims no better accuracy.
SCALE_TOL = 0.02
#: Plausibility (`diagnosis.plausibility`, docs/effects.md "Plausibility"): the physical range of the estimate, as data.
PLAUSIBLE = (
    {
        "key": "scale",
        "least": 0.8,
        "most": 1.25,
        "unit": "",
        "why": "a motor's torque constant is within about ±10 % of its datasheet (tolerance, and magnets losing about "
        "0.1 %/K warm), a current sensor's or amplifier's gain within a few per cent, a gear ratio exact; and a torque "
        "logged as current × torque constant × gear ratio reads the motor's side: the joint gets the gear's "
        "efficiency of it while driving (a harmonic drive's 80–90 %), a factor s of 0.8–0.9. Together: 0.8 to 1.25. "
        "A factor beyond (1.5 to 2 on DFKI A.0's joint 1) is a wrong channel, unit or ratio: a description to check, "
        "not a drive's property",
    },
)


class TorqueScale(Effect):
    summary = "the logged torque is off by a factor per joint: the true joint torque is s x the logged one"
    order = 8
    keys = {  # noqa: RUF012
        "scale": Key(
            "pair", (1.1, 1.0), "s per joint (1: untouched); this effect's own scale", 0.0, True, maximum=100.0
        ),
    }

    # ------------------------------------------------------------------ syntax: `scale` is the factor itself
    def key(self, key: str, where: str) -> Key:
        return self.keys[key] if key in self.keys else super().key(key, where)

    def complete(self, params: dict, where: str, coulomb: tuple[tuple, tuple]) -> dict:
        return self.checked(params, where, coulomb)

    def untouched(self, key: str, joint: int, joints) -> float:
        return 1.0

    def chain_default(self, key: str, joints) -> object:
        return (1.1,) + (1.0,) * (joints.n - 1)

    def is_active(self, p: dict, coulomb: tuple[tuple, tuple]) -> bool:
        return any(s != 1.0 for s in p["scale"])

    def scaled(self, p: dict, s: float, coulomb: tuple[tuple, tuple]) -> dict:
        # The magnitude is the factor's deviation from 1 (s = 0: the untouched channel).
        p["scale"] = tuple(1.0 + s * (v - 1.0) for v in p["scale"])
        return p

    # ------------------------------------------------------------------ simulator: the logged channel / s
    def true_plant(self, plant, p: dict) -> None:
        plant.channel.append(partial(_logged, p["scale"]))

    def chain_plant(self, plant, p: dict) -> None:
        self.true_plant(plant, p)

    def chain_families(self, ctx) -> list:
        """Against the datasheet: joint j's logged torque is c_j (Y π_datasheet)_j, c_j = 1/s_j, on the joints where
        c_j is resolved from 1 (the others as the datasheet predicts them)."""

        def units(p: dict) -> tuple[np.ndarray, tuple[str, ...]]:
            s = np.array([1.0 / p[f"c{j + 1}"] if f"c{j + 1}" in p else 1.0 for j in range(ctx.n)])
            return s, tuple(f"c{j + 1}" for j in range(ctx.n))

        return [
            ChainFamily(
                self.name,
                rows=True,
                baselines=("datasheet",),
                estimate=_arm_estimate,
                screen=lambda p, se, ctx: resolved_joints(p, se, ("c",), ctx.n, untouched=1.0),
                units=units,
            )
        ]

    def chain_draw(self, rng, joints, chosen) -> dict:
        def factor(j: int) -> float:  # uniform over [0.8, 0.95] ∪ [1.05, 1.25]
            x = rng.uniform(0.0, 0.35)
            return 0.8 + x if x < 0.15 else 1.05 + (x - 0.15)

        return {"scale": arm_values(joints.n, chosen, 1.0, factor)}

    def chain_judge(self, estimate: dict, truth: dict) -> list[tuple[bool, float]]:
        return self.judge(estimate, truth)

    # ------------------------------------------------------------------ diagnosis
    judged = ("scale",)
    plausible = PLAUSIBLE
    resolution = (
        f"torque scales within {SCALE_TOL:g} of 1 on every joint are not named",
        "the diagnosis claims a scale only to that tolerance: closer to 1, a factor cannot be told from a correct "
        "torque constant, and on simulated trials such factors were another cause's mismatch, beside a payload",
    )

    def resolved(self, estimate: dict, dt: float) -> bool:
        return any(abs(s - 1.0) > SCALE_TOL for s in estimate["scale"])

    def families(self, ctx) -> list:
        return [self.family(transform=_per_joint, baselines=("datasheet",), estimate=_absolute, units=_units)]

    def sentence(self, d, base: str, gain: str) -> str:
        return (
            f"The logged torque is off by a factor per joint: the true joint torque is "
            f"s = {wording.pair(d.estimate['scale'])} × the logged one; {gain}"
        )

    def draw(self, rng, robot) -> dict:
        def factor() -> float:  # uniform over [0.8, 0.95] ∪ [1.05, 1.25]
            x = rng.uniform(0.0, 0.35)
            return 0.8 + x if x < 0.15 else 1.05 + (x - 0.15)

        return {"scale": per_joint_draw(rng, 1.0, factor)}

    def judge(self, estimate: dict, truth: dict) -> list[tuple[bool, float]]:
        return [(abs(e - t) <= SCALE_TOL, relative_error(e, t)) for e, t in zip(estimate["scale"], truth["scale"])]


def _arm_estimate(p: dict, se: dict, ctx) -> tuple[dict, dict]:
    """s_j = 1/c_j on the joints fitted (1 elsewhere); the joints whose s_j lies within `SCALE_TOL` of 1 fail the
    resolution floor (`detail["failed_joints"]`: `chain.families.fit` fits the others again without them)."""
    scale = [1.0 / p[f"c{j + 1}"] if f"c{j + 1}" in p else 1.0 for j in range(ctx.n)]
    low = [j for j in range(ctx.n) if f"c{j + 1}" in p and abs(scale[j] - 1.0) <= SCALE_TOL]
    return {"scale": scale}, ({"failed_joints": low} if low else {})


def _logged(scale: tuple[float, float], t: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """The torque (N, n) [N m] as logged: the true τ / s per joint."""
    return tau / np.asarray(scale)


def _per_joint(offset: np.ndarray, X: np.ndarray, names: list[str], theta: dict, step: float) -> tuple:
    """Against the datasheet: its prediction o (N, 2) becomes the column of c_j on joint j's row."""
    X = np.concatenate([X, np.zeros((len(offset), 2, 2))], axis=2)
    X[:, 0, -2], X[:, 1, -1] = offset[:, 0], offset[:, 1]
    return np.zeros_like(offset), X, [*names, "c1", "c2"]


def _absolute(p: dict, se: dict, ctx) -> tuple[dict, dict]:
    """s_j = 1/c_j, its standard error se(c_j)/c_j²."""
    c = np.array([p["c1"], p["c2"]])
    with np.errstate(divide="ignore"):
        return {"scale": (1.0 / c).tolist()}, {"se": (np.array([se["c1"], se["c2"]]) / c**2).tolist()}


def _units(p: dict) -> tuple[np.ndarray, tuple[str, ...]]:
    """s_j = 1/c_j: the factor that turns a coefficient fitted on joint j's logged row into joint-torque
    units (an armature or a Coulomb level found beside the scale is otherwise reported as J/s, fc/s)."""
    with np.errstate(divide="ignore"):
        return 1.0 / np.array([p["c1"], p["c2"]]), ("c1", "c2")


EFFECT = TorqueScale()
