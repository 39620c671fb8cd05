"""``asymmetric_coulomb``: Coulomb friction that differs by direction (replaces the datasheet mean).

Model extension ``asymmetric_coulomb``: fc1p fc1n fc2p fc2n replace fc1, fc2 (a Coulomb level per velocity
sign). Omitted keys default to the datasheet's own per-direction levels (reflected through the gear ratio);
the effect's magnitude is its departure from the datasheet's symmetric (mean) level. Simulator: that
friction. Diagnosis: the extension's four levels fitted, against both nominal models.
"""

from __future__ import annotations

from ident_opt import wording
from ident_opt.effects.base import Effect, ca, np
from ident_opt.effects.families import RESOLVED, ChainFamily, selected
from ident_opt.effects.keys import Key
from ident_opt.parameters import Parameter

#: Least direction difference |fc+ − fc−|, relative to the joint's mean level, that makes friction asymmetric.
ASYMMETRY = 0.1
#: An n-joint arm's default: levels ±40 % about the mean, which is 2 % of the joint's reference torque where the
#: datasheet gives no Coulomb friction.
ARM_SPLIT, ARM_LEVEL = 0.4, 0.02


def _mean(coulomb: tuple[tuple, tuple]) -> list[float]:
    """The datasheet's symmetric Coulomb level per joint [N m]: the clean trial's friction."""
    return [0.5 * (a + b) for a, b in zip(*coulomb)]


#: Least ratio of a joint's smaller Coulomb level to its larger one (`PLAUSIBLE`).
LEAST_RATIO = 0.2
#: Plausibility (`diagnosis.plausibility`, docs/effects.md "Plausibility"): the physical range of the estimate, as data.
#: "torque_logged" is each joint's largest logged torque on the training part (`plausibility.Facts`); "level_ratio"
#: (in the fit's detail) is each joint's smaller level over its larger one.
PLAUSIBLE = (
    *(
        {
            "key": key,
            "most": "torque_logged",
            "unit": "N m",
            "why": "a joint that moved was driven past its friction level in each direction",
        }
        for key in ("positive", "negative")
    ),
    {
        "key": "level_ratio",
        "least": LEAST_RATIO,
        "unit": "",
        "why": "a gear's or a bearing's friction differs by direction by tens of per cent (the simulated splits reach "
        "1 : 4); a level that vanishes in one direction while the other stays is a constant torque while moving, a "
        "torque channel's offset (MERIt's joint 2: fc+ 0, fc− 0.48 N m, read as an offset of −0.44 N m on exp1 and "
        "−0.29 N m on exp2)",
    },
)


def level_ratio(positive, negative) -> list[float]:
    """Each joint's smaller Coulomb level over its larger one (1 where both are 0: no friction to compare)."""
    return [
        min(abs(p), abs(n)) / max(abs(p), abs(n)) if max(abs(p), abs(n)) > 0 else 1.0
        for p, n in zip(positive, negative)
    ]


class AsymmetricCoulomb(Effect):
    summary = "Coulomb friction that differs by direction (replaces the datasheet mean)"
    order = 2
    keys = {  # noqa: RUF012
        "positive": Key("pair", None, "N m, level for dq > 0 (default: the datasheet's, x gear ratio)", maximum=1e4),
        "negative": Key("pair", None, "N m, level for dq < 0 (default: the datasheet's, x gear ratio)", maximum=1e4),
    }

    def default(self, key: str, coulomb: tuple[tuple, tuple]) -> object:
        return coulomb[0] if key == "positive" else coulomb[1]

    def scaled(self, p: dict, s: float, coulomb: tuple[tuple, tuple]) -> dict:
        mean = _mean(coulomb)
        p["positive"] = tuple(m + s * (v - m) for m, v in zip(mean, p["positive"]))
        p["negative"] = tuple(m + s * (v - m) for m, v in zip(mean, p["negative"]))
        return p

    def untouched(self, key: str, joint: int, joints) -> float:
        return _mean(joints)[joint]

    def chain_default(self, key: str, joints) -> object:
        """An n-joint arm: ±`ARM_SPLIT` about the datasheet's mean level, or about `ARM_LEVEL` × the joint's
        reference torque where the datasheet has none."""
        sign = 1.0 if key == "positive" else -1.0
        levels = [m if m > 0 else ARM_LEVEL * T for m, T in zip(_mean(joints), joints.scale.torque)]
        return tuple(m * (1 + sign * ARM_SPLIT) for m in levels)

    def is_active(self, p: dict, coulomb: tuple[tuple, tuple]) -> bool:
        mean = _mean(coulomb)
        return any(v != m for m, v in zip(mean, p["positive"])) or any(v != m for m, v in zip(mean, p["negative"]))

    # ------------------------------------------------------------------ model: fcjp [dq_j > 0] − fcjn [dq_j < 0]
    parameters = tuple(
        Parameter(f"fc{j}{s}", "N m", f"joint-{j} Coulomb level for {d} velocity", "friction", j)
        for j in (1, 2)
        for s, d in (("p", "positive"), ("n", "negative"))
    )
    replaces = ("fc1", "fc2")
    fallback = {"fc1p": "fc1", "fc1n": "fc1", "fc2p": "fc2", "fc2n": "fc2"}  # noqa: RUF012

    def columns(self, model) -> dict:
        zero = np.zeros_like
        return {
            "fc1p": lambda q, dq, a: ((dq[:, 0] > 0).astype(float), zero(dq[:, 0])),
            "fc1n": lambda q, dq, a: (-(dq[:, 0] < 0).astype(float), zero(dq[:, 0])),
            "fc2p": lambda q, dq, a: (zero(dq[:, 1]), (dq[:, 1] > 0).astype(float)),
            "fc2n": lambda q, dq, a: (zero(dq[:, 1]), -(dq[:, 1] < 0).astype(float)),
        }

    def add_terms(self, model, q, dq, p: dict, M: list, G: list, F: list) -> None:
        for j in range(2):
            k = str(j + 1)
            F[j] = F[j] + p["fc" + k + "p"] * ca.if_else(dq[j] > 0, 1, 0)
            F[j] = F[j] - p["fc" + k + "n"] * ca.if_else(dq[j] < 0, 1, 0)

    # ------------------------------------------------------------------ simulator: the model extension's friction
    def true_plant(self, plant, p: dict) -> None:
        plant.extensions.append(self.name)
        for j, (positive, negative) in enumerate(zip(p["positive"], p["negative"]), start=1):
            plant.pi[f"fc{j}p"], plant.pi[f"fc{j}n"] = positive, negative

    def true_physical(self, physical: dict, p: dict) -> None:
        physical["fc_positive"], physical["fc_negative"] = list(p["positive"]), list(p["negative"])
        physical["fc"] = [0.5 * (a + b) for a, b in zip(p["positive"], p["negative"])]

    def chain_plant(self, plant, p: dict) -> None:
        plant.positive, plant.negative = np.array(p["positive"]), np.array(p["negative"])

    def chain_families(self, ctx) -> list:
        """A Coulomb level per direction on the joints where they differ: against the datasheet, the levels
        fc+ [dq_j > 0] − fc− [dq_j < 0] ≥ 0 (friction opposes motion) replace the datasheet's; against the rigid
        fit, a_j [dq_j ≠ 0] beside the refitted symmetric level (fc± = fc ± a; beside torque offsets a constant
        while moving is theirs, and the rigid fit cannot tell the asymmetry)."""
        return [
            ChainFamily(
                self.name,
                extra=_arm_columns,
                removed=_arm_removed,
                estimate=_arm_estimate,
                screen=_arm_screen,
                screen_inertia_free=True,  # beside a refitted π the asymmetry is a torque offset: datasheet side only
                nonnegative=("fp", "fn"),
            )
        ]

    def chain_draw(self, rng, joints, chosen) -> dict:
        """On each chosen joint a split of ±30..60 % about its mean level (the datasheet's, or 1.5–3 % of its
        reference torque where the datasheet has none); the datasheet's mean level elsewhere."""
        mean = _mean(joints)
        level = {j: mean[j] if mean[j] > 0 else rng.uniform(0.015, 0.03) * joints.scale.torque[j] for j in chosen}
        split = {j: rng.uniform(0.3, 0.6) * rng.choice([-1.0, 1.0]) for j in chosen}
        return {
            key: tuple(level[j] * (1 + sign * split[j]) if j in chosen else mean[j] for j in range(joints.n))
            for key, sign in (("positive", 1.0), ("negative", -1.0))
        }

    # ------------------------------------------------------------------ diagnosis
    judged = ("positive", "negative")
    plausible = PLAUSIBLE
    resolution = (
        f"Coulomb levels that differ by direction by less than {ASYMMETRY:.0%} of their mean on every joint are "
        "not named asymmetric",
        "that is a symmetric Coulomb level: part of π, not a cause",
    )

    def resolved(self, estimate: dict, dt: float) -> bool:
        pairs = zip(estimate["positive"], estimate["negative"])
        return any(abs(p - n) > ASYMMETRY * 0.5 * (abs(p) + abs(n)) for p, n in pairs)

    def families(self, ctx) -> list:
        extended = (*ctx.nominal.extensions, self.name)
        return [
            self.family(
                lambda th: ctx.model(extended),
                tuple(p.name for p in self.parameters),
                estimate=_estimate,
            )
        ]

    def sentence(self, d, base: str, gain: str) -> str:
        e, mm = d.estimate, d.evidence[d.baseline]["moving_mean"]
        num, pair = wording.num, wording.pair
        return (
            f"The residual of the {base} model differs by direction of motion (mean while moving "
            f"positive / negative: "
            + ", ".join(
                f"{wording.joint(d.joints, j)} {num(m['positive'])} / {num(m['negative'])} N m"
                for j, m in enumerate(mm)
            )
            + f"): Coulomb friction is asymmetric, fc+ = {pair(e['positive'], 'N m')}, "
            f"fc− = {pair(e['negative'], 'N m')}; {gain}"
        )

    def draw(self, rng, robot) -> dict:
        body = robot.rigid_body("physical")
        pos, neg = [], []
        for fc in body.fc:  # a per-direction split of the datasheet's mean level by ±30..60 %
            a = rng.uniform(0.3, 0.6) * rng.choice([-1.0, 1.0])
            pos.append(fc * (1 + a))
            neg.append(fc * (1 - a))
        return {"positive": tuple(pos), "negative": tuple(neg)}


def _arm_columns(ds, theta: dict, ctx, baseline: str) -> tuple[np.ndarray, list[str]]:
    """Against the datasheet: [v_j > 0] and −[v_j < 0] (levels fp_j, fn_j); against the rigid fit: [v_j ≠ 0]
    (a_j), on the drives θ selects: v_j is drive j's velocity and its columns reach every joint its motor turns
    (`ArmContext.drive_velocity`, `drive_columns`; the joint's own dq_j on its row alone where the drive turns
    only its joint), as the Coulomb level they replace (`_arm_removed`) does."""
    joints = selected(theta, "asymmetric_coulomb", ctx.n)
    v = ctx.drive_velocity(ds)
    if baseline == "datasheet":
        up, _ = ctx.drive_columns((v > 0).astype(float), joints, "fp")
        down, _ = ctx.drive_columns(-(v < 0).astype(float), joints, "fn")
        names = [f"{k}{j + 1}" for j in joints for k in ("fp", "fn")]
        X = np.stack([up, down], axis=3).reshape(ds.n, ctx.n, 2 * len(joints))
        return X, names
    return ctx.drive_columns((v != 0).astype(float), joints, "a")


def _arm_removed(theta: dict, ctx) -> list[int]:
    """The datasheet's Coulomb parameters of the joints θ selects (their levels per direction replace them)."""
    terms = ctx.coulomb_terms()
    return [i for j in selected(theta, "asymmetric_coulomb", ctx.n) for i in terms[j]]


def _coulomb(p: dict, ctx, j: int) -> float:
    """Joint j's symmetric Coulomb level [N m]: the refitted π's where the fit has it, else the datasheet's."""
    terms, names = ctx.coulomb_terms()[j], ctx.arm.names
    return sum(float(p.get(names[i], ctx.datasheet[i])) for i in terms)


def _arm_estimate(p: dict, se: dict, ctx) -> tuple[dict, dict]:
    """fc+ and fc− per joint: the fitted levels, fc ± a beside a refitted level, the symmetric level elsewhere."""
    positive, negative = [], []
    for j in range(ctx.n):
        k = str(j + 1)
        if "fp" + k in p:
            positive.append(float(p["fp" + k]))
            negative.append(float(p["fn" + k]))
        else:
            fc, a = _coulomb(p, ctx, j), float(p.get("a" + k, 0.0))
            positive.append(fc + a)
            negative.append(fc - a)
    return {"positive": positive, "negative": negative}, {"level_ratio": level_ratio(positive, negative)}


def _arm_screen(p: dict, se: dict, ctx) -> list[int]:
    """The joints whose levels differ by direction by more than `RESOLVED` standard errors."""
    out = []
    for j in range(ctx.n):
        k = str(j + 1)
        if "fp" + k in p:
            diff, err = p["fp" + k] - p["fn" + k], np.hypot(se["fp" + k], se["fn" + k])
        else:
            diff, err = p.get("a" + k, 0.0), se.get("a" + k, np.inf)
        if abs(diff) > RESOLVED * err:
            out.append(j)
    return out


def _estimate(p: dict, se: dict, ctx) -> tuple[dict, dict]:
    positive, negative = [p["fc1p"], p["fc2p"]], [p["fc1n"], p["fc2n"]]
    return (
        {"positive": positive, "negative": negative},
        {
            "se_positive": [se["fc1p"], se["fc2p"]],
            "se_negative": [se["fc1n"], se["fc2n"]],
            "level_ratio": level_ratio(positive, negative),
        },
    )


EFFECT = AsymmetricCoulomb()
