"""``stribeck``: friction that falls from a static (breakaway) level fs to the Coulomb level fc as speed rises.

The friction is fc sgn(dq) + (fs − fc) sgn(dq) exp(−(dq/vs)²). The effect's keys and estimate give the
static level fs itself [N m]; the model extension's parameters fs1 fs2 are the excess fs − fc (linear).
Model extension ``stribeck``: fs1 fs2 (excess), with the Stribeck velocities vs given
(`PlanarArm.stribeck_velocity`). Simulator: that friction, the excess over the true plant's mean Coulomb
level. Diagnosis: the excess ≥ 0 linear, vs1 vs2 [rad/s] searched by variable projection, then polished by
IPOPT (`polish`), against both nominal models; the estimate adds the fitted (or datasheet) Coulomb level.
It shows only where the joints move slowly for a while, so its hidden trials follow the smooth `fourier`
reference.

Near a stop or a start (`STOP_S` of rest, within one filter length 1/f_c of it) the diagnosis gives the excess
a coefficient of its own (fs1_stop, fs2_stop), and the estimate reads fs away from them: there the estimated
velocity and the filtered torque are the zero-phase filters' smoothing of a stick–slip transition (the joint
sticks or breaks away within a sample or two), not the speed the friction acted at. Read there, the excess
comes out 5–15 % low and vs too wide (`docs/effects.md`); smooth reversals keep every sample.
"""

from __future__ import annotations

from ident_opt import wording
from ident_opt.effects.base import (
    MAGNITUDE_TOL,
    Effect,
    ca,
    edge_rule,
    inside,
    least_squares,
    nlp,
    np,
    relative_error,
    signals,
)
from ident_opt.effects.families import POLISH_ROWS, RESOLVED, ChainFamily, per_joint, resolved_joints, selected
from ident_opt.effects.keys import Key
from ident_opt.errors import InputError
from ident_opt.parameters import Parameter

#: The default excess of the static level over the datasheet's mean Coulomb level [N m], per joint.
DEFAULT_EXCESS = (0.3, 0.2)
#: An n-joint arm's default excess, as a share of each joint's reference torque (`ArmScale.torque`).
ARM_EXCESS = 0.01


def _mean(coulomb: tuple[tuple, tuple]) -> list[float]:
    """The datasheet's symmetric Coulomb level per joint [N m]."""
    return [0.5 * (a + b) for a, b in zip(*coulomb)]


def plant_coulomb(pi: dict, j: int) -> float:
    """The mean Coulomb level [N m] of joint j (1-based) in a parameter dict (per-direction levels averaged)."""
    k = str(j)
    if "fc" + k + "p" in pi:
        return 0.5 * (pi["fc" + k + "p"] + pi["fc" + k + "n"])
    return pi["fc" + k]


#: Where the Stribeck velocity vs [rad/s] is searched (the grid) and polished (IPOPT's bounds): one range, so a
#: vs at its edge is the search stopped by its bound (`resolved`). A hump as wide as 0.5 rad/s, the joints' whole
#: speed range in a typical trial, no longer falls off within the motion: it is a reshaped Coulomb level.
VS_RANGE = (0.005, 0.5)
#: Plausibility (`diagnosis.plausibility`, docs/effects.md "Plausibility"): the physical range of the estimate, as data.
#: "torque_logged" is each joint's largest logged torque on the training part (`plausibility.Facts`).
PLAUSIBLE = (
    {"key": "velocity", "search": VS_RANGE, "unit": "rad/s"},
    {
        "key": "static",
        "most": "torque_logged",
        "unit": "N m",
        "why": "a joint that moved was driven past its breakaway level",
    },
)
#: The least Stribeck velocity an n-joint candidate names, in multiples of the lowest speed compared on its joint
#: (`_arm_estimate`).
FALL = 2.0
#: A rest this long [s] is a stop (or a start), not the slow instant of a velocity reversal.
STOP_S = 0.25


def beyond_logged(static: list[float], ctx) -> list[int]:
    """The joints (0-based) whose static level exceeds the largest torque logged on them in the training part: a
    joint that moved was driven past its static friction, so such a level is a hump extrapolated where the data
    have no samples (a column of a few 1e-11 at the speeds compared once gave 9e8 N m), not an estimate."""
    peak = np.max(np.abs(ctx.train.tau), axis=0)
    return [j for j, fs in enumerate(static) if fs > peak[j]]


def shape(dq: np.ndarray, vs: float) -> np.ndarray:
    """sgn(dq) exp(−(dq/vs)²): the Stribeck excess per N m of fs − fc (dq [rad/s], vs [rad/s])."""
    return np.sign(dq) * np.exp(-((dq / vs) ** 2))


def trusted(ds) -> np.ndarray:
    """(N, 2) bool: the samples whose estimated velocity can show the Stribeck excess — all but those within
    one filter length (1/f_c of the data's derivative cut-off, else the diagnosis's torque filter) of a stop or
    a start (module docstring)."""
    dt = float(np.median(np.diff(ds.t)))
    smoothing = 1.0 / (ds.cutoff_hz or signals.TORQUE_FILTER_HZ)
    return ~signals.near_stops(ds.dq, dt, STOP_S, smoothing)


class Stribeck(Effect):
    summary = "friction excess fs sgn(dq) exp(-(dq/vs)^2) above the Coulomb level at low speed"
    order = 3
    keys = {  # noqa: RUF012
        "static": Key(
            "pair", None, "N m, static (breakaway) level fs per joint (default: datasheet fc + [0.3,0.2])", maximum=1e4
        ),
        "velocity": Key("pair", (0.05, 0.05), "rad/s, Stribeck velocity vs, per joint", 0.0, True, maximum=100.0),
    }

    def default(self, key: str, coulomb: tuple[tuple, tuple]) -> object:
        if key == "static":
            return tuple(m + e for m, e in zip(_mean(coulomb), DEFAULT_EXCESS))
        return self.keys[key].default

    def scaled(self, p: dict, s: float, coulomb: tuple[tuple, tuple]) -> dict:
        # The magnitude is the excess over the datasheet's mean Coulomb level.
        p["static"] = tuple(m + s * (v - m) for m, v in zip(_mean(coulomb), p["static"]))
        return p

    def is_active(self, p: dict, coulomb: tuple[tuple, tuple]) -> bool:
        return any(v != m for m, v in zip(_mean(coulomb), p["static"]))

    def untouched(self, key: str, joint: int, joints) -> float:
        return _mean(joints)[joint] if key == "static" else self.keys["velocity"].default[0]

    def chain_default(self, key: str, joints) -> object:
        """An n-joint arm: a static level `ARM_EXCESS` × the joint's reference torque above the datasheet's mean."""
        if key == "static":
            return tuple(m + ARM_EXCESS * T for m, T in zip(_mean(joints), joints.scale.torque))
        return super().chain_default(key, joints)

    # ------------------------------------------------------------------ any arm: the excess on the joint's velocity
    def chain_plant(self, plant, p: dict) -> None:
        """The excess over the plant's own Coulomb level (asymmetric_coulomb's, when hidden too) on the joints the
        effect touches: those whose static level is neither the datasheet's nor the plant's mean (a joint left at
        the datasheet's level beside an asymmetric Coulomb friction has no excess, not a negative one)."""
        static = np.array(p["static"], dtype=float)
        mean = 0.5 * (plant.positive + plant.negative)
        touched = (static != plant.mean_coulomb) & (static != mean)
        plant.excess = np.where(touched, static - mean, 0.0)
        below = [j for j in range(plant.n) if touched[j] and static[j] < mean[j]]
        if below:
            j = below[0]
            raise InputError(
                f"effect stribeck: its static level {static[j]:.4g} N m on {plant.joints.names[j]} is below that "
                f"joint's Coulomb level {mean[j]:.4g} N m (the mean of its per-direction levels): a Stribeck excess "
                f"is a rise above it; give static above {mean[j]:.4g} on that joint"
            )
        plant.velocity = np.array(p["velocity"])

    def chain_truth(self, plant, p: dict) -> dict:
        return {**p, "static_excess": plant.excess.tolist()}

    def chain_families(self, ctx) -> list:
        """fs_j sgn(dq_j) exp(−(dq_j/vs_j)²) on the joints where it is resolved (screened at vs = the middle of its
        range), away from stops and near them with coefficients of their own (`_columns`), vs_j searched per joint;
        against both nominal models."""
        return [
            ChainFamily(
                self.name,
                extra=_arm_columns,
                axes=lambda rate, theta: [
                    least_squares.Axis(f"vs{j + 1}", max(VS_RANGE[0], ctx.stick_speed[j]), VS_RANGE[1], 11, True)
                    for j in selected(theta, self.name, ctx.n)
                ],
                nonnegative=("fs", "fsstop"),
                estimate=_arm_estimate,
                screen=lambda p, se, ctx: resolved_joints(p, se, ("fs",), ctx.n),
            )
        ]

    def chain_draw(self, rng, joints, chosen) -> dict:
        """On each chosen joint an excess of 0.5–1 % of its reference torque over its mean Coulomb level, falling
        off over 3–8 % of its cruise speed."""
        mean = _mean(joints)
        return {
            "static": tuple(
                mean[j] + rng.uniform(0.005, 0.01) * joints.scale.torque[j] if j in chosen else mean[j]
                for j in range(joints.n)
            ),
            "velocity": tuple(
                rng.uniform(0.03, 0.08) * joints.scale.speed[j] if j in chosen else self.keys["velocity"].default[0]
                for j in range(joints.n)
            ),
        }

    def chain_judge(self, estimate: dict, truth: dict) -> list[tuple[bool, float]]:
        """Per joint: where the truth has an excess, fs and vs within `MAGNITUDE_TOL`; elsewhere the estimate must
        report none (0) or a static level within `MAGNITUDE_TOL` of the largest true excess of the mean level."""
        excess = np.asarray(truth["static_excess"], dtype=float)
        largest = float(np.max(np.abs(excess))) or 1.0
        checks = []
        for j, ex in enumerate(excess):
            fs, vs = estimate["static"][j], estimate["velocity"][j]
            if ex != 0:
                for e, t in ((fs, truth["static"][j]), (vs, truth["velocity"][j])):
                    rel = relative_error(e, t)
                    checks.append((rel <= MAGNITUDE_TOL, rel))
            else:
                rel = 0.0 if fs == 0 else abs(fs - (truth["static"][j] - ex)) / largest
                checks.append((rel <= MAGNITUDE_TOL, rel))
        return checks

    # ------------------------------------------------------------------ model: fsj sgn(dq_j) exp(−(dq_j/vs_j)²)
    parameters = tuple(
        Parameter(f"fs{j}", "N m", f"joint-{j} Stribeck excess over the Coulomb level", "friction", j) for j in (1, 2)
    )

    def columns(self, model) -> dict:
        zero, vs = np.zeros_like, model.stribeck_velocity
        return {
            "fs1": lambda q, dq, a: (shape(dq[:, 0], vs[0]), zero(dq[:, 0])),
            "fs2": lambda q, dq, a: (zero(dq[:, 1]), shape(dq[:, 1], vs[1])),
        }

    def add_terms(self, model, q, dq, p: dict, M: list, G: list, F: list) -> None:
        for j in range(2):
            vs = model.stribeck_velocity[j]
            F[j] = F[j] + p["fs" + str(j + 1)] * ca.sign(dq[j]) * ca.exp(-((dq[j] / vs) ** 2))

    # ------------------------------------------------------------------ simulator: the model extension's friction
    def true_plant(self, plant, p: dict) -> None:
        plant.extensions.append(self.name)
        for j in (1, 2):  # the model's fs is the excess over the plant's mean Coulomb level
            plant.pi[f"fs{j}"] = p["static"][j - 1] - plant_coulomb(plant.pi, j)
        plant.options["stribeck_velocity"] = tuple(p["velocity"])

    def truth_entry(self, truth, p: dict) -> dict:
        excess = truth.model.as_dict(truth.pi)
        return {**p, "static_excess": [excess[f"fs{j}"] for j in (1, 2)]}

    # ------------------------------------------------------------------ diagnosis
    reference = "fourier"
    judged = ("static", "velocity")
    plausible = PLAUSIBLE
    resolution = edge_rule(
        "Stribeck friction with no joint's excess resolved, or whose velocity vs lies",
        VS_RANGE,
        "rad/s",
        "an excess that does not fall off within the range is a Coulomb step, a candidate of its own",
    )

    def resolved(self, estimate: dict, dt: float) -> bool:
        vs = [v for s, v in zip(estimate["static"], estimate["velocity"]) if s > 0]
        return bool(vs) and all(inside(v, *VS_RANGE) for v in vs)

    def families(self, ctx) -> list:
        names = tuple(p.name for p in self.parameters)
        return [
            self.family(
                extra=_columns,
                nonnegative=(*names, "fs1_stop", "fs2_stop"),
                axes=lambda rate: [
                    least_squares.Axis("vs1", *VS_RANGE, 11, True),
                    least_squares.Axis("vs2", *VS_RANGE, 11, True),
                ],
                estimate=_estimate,
                refine=lambda ctx, o, X, names, beta, theta: polish(
                    ctx.rest, ctx.train.dq, ctx.train.tau, o, X, names, beta, theta, trusted(ctx.train)
                ),
            )
        ]

    def sentence(self, d, base: str, gain: str) -> str:
        e, ev, pair = d.estimate, d.evidence[d.baseline], wording.pair
        return (
            f"Friction rises at low speed beyond the Coulomb level (low-speed excess of the residual "
            f"{pair(ev['low_speed_excess'], 'N m')}): a static level fs = {pair(e['static'], 'N m')} "
            f"falling off over vs = {pair(e['velocity'], 'rad/s')} explains it; {gain}"
        )

    def draw(self, rng, robot) -> dict:
        u, fc = rng.uniform, robot.rigid_body("physical").fc
        return {"static": (fc[0] + u(0.2, 0.4), fc[1] + u(0.15, 0.3)), "velocity": (u(0.03, 0.1), u(0.03, 0.1))}


def _columns(ds, theta: dict, dt: float, ctx) -> tuple[np.ndarray, list[str]]:
    """The diagnosis's columns (N, 2, 4) at vs1 vs2 of θ: fs1 fs2, the excess shape where it can be seen
    (`trusted`), and fs1_stop fs2_stop, the same shape near stops and starts with a coefficient of its own."""
    cols, keep = np.zeros((ds.n, 2, 4)), trusted(ds)
    for j in range(2):
        f = shape(ds.dq[:, j], theta[f"vs{j + 1}"])
        cols[:, j, j] = f * keep[:, j]
        cols[:, j, 2 + j] = f * ~keep[:, j]
    return cols, ["fs1", "fs2", "fs1_stop", "fs2_stop"]


def _estimate(p: dict, se: dict, ctx) -> tuple[dict, dict]:
    """The static level fs = the fitted (or datasheet) mean Coulomb level + the fitted excess."""
    static, velocity = [], []
    for j in (1, 2):
        k = str(j)
        fs, s = p["fs" + k], se["fs" + k]
        # A joint whose excess is not resolved from zero is "untouched": report 0 for both keys.
        resolved = fs > 3.0 * s
        fc = (
            plant_coulomb({**ctx.datasheet, **p}, j)
            if ("fc" + k in p or "fc" + k + "p" in p)
            else ctx.datasheet["fc" + k]
        )
        static.append(fc + fs if resolved else 0.0)
        velocity.append(p["vs" + k] if resolved else 0.0)
    detail = {"se_static": [se["fs1"], se["fs2"]], "excess": [p["fs1"], p["fs2"]]}
    high = beyond_logged(static, ctx)
    if high:
        detail["unresolved"] = _beyond_reason(high, ctx)
    return {"static": static, "velocity": velocity}, detail


def _beyond_reason(joints: list[int], ctx) -> str:
    """Why a candidate with a static level beyond the logged torque (`beyond_logged`) is not named."""
    names = ", ".join(ctx.robot.joint_names[j] for j in joints)
    return f"its static level on {names} exceeds the largest torque logged there: no joint that moved has such friction"


def _arm_columns(ds, theta: dict, ctx, baseline: str) -> tuple[np.ndarray, list[str]]:
    """fs_j and fsstop_j columns (`_columns`' split near stops) at vs_j of θ (0.05 rad/s before the search) on the
    joints θ selects, through the torque's low-pass (`ArmContext.lowpass`): the hump lasts a few tens of
    milliseconds at a reversal, and the filtered torque holds it smeared; read unfiltered it came out half as high
    and half as wide again on the KUKA."""
    keep = trusted(ds)
    joints = selected(theta, "stribeck", ctx.n)
    X = np.zeros((ds.n, ctx.n, 2 * len(joints)))
    names = []
    for k, j in enumerate(joints):
        f = shape(ds.dq[:, j], theta.get(f"vs{j + 1}", 0.05))
        X[:, j, 2 * k], X[:, j, 2 * k + 1] = f * keep[:, j], f * ~keep[:, j]
        names += [f"fs{j + 1}", f"fsstop{j + 1}"]
    return ctx.lowpass(X, ds), names


def _arm_estimate(p: dict, se: dict, ctx) -> tuple[dict, dict]:
    """fs = the joint's Coulomb level (per-direction levels averaged where found beside) + the excess, vs; 0 and 0
    where the excess is not resolved."""
    static, velocity = [], []
    for j in range(ctx.n):
        k = str(j + 1)
        fs = p.get("fs" + k, 0.0)
        if "fs" + k not in p or fs <= RESOLVED * se.get("fs" + k, np.inf):
            static.append(0.0)
            velocity.append(0.0)
            continue
        if "fp" + k in p:
            fc = 0.5 * (p["fp" + k] + p["fn" + k])
        else:
            fc = sum(float(p.get(ctx.arm.names[i], ctx.datasheet[i])) for i in ctx.coulomb_terms()[j])
        static.append(fc + fs)
        velocity.append(float(p["vs" + k]))
    detail = {"excess": per_joint(p, "fs", ctx.n)}
    # A hump is read from its fall: at vs = FALL x the lowest speed compared on its joint (`ArmContext.stick_speed`)
    # 78 % of the excess is still there at that speed, so the data hold the fall, not only a tail above the samples
    # left out, where a joint breaking away from stiction leaves torque that a narrower hump fits.
    floor = FALL * ctx.stick_speed
    low = [j for j in range(ctx.n) if static[j] > 0 and velocity[j] < floor[j]]
    high = [j for j in beyond_logged(static, ctx) if j not in low]
    if low or high:
        detail["failed_joints"] = sorted(low + high)  # `chain.families.fit` fits the others again without them
        reasons = []
        if low:
            names = ", ".join(ctx.robot.joint_names[j] for j in low)
            reasons.append(
                f"its Stribeck velocity on {names} is below {FALL:g} x the lowest speed compared there "
                f"({signals.STICK_SPEEDS:g} rest speeds): the hump's fall is not in the data"
            )
        if high:
            reasons.append(_beyond_reason(high, ctx))
        detail["unresolved"] = "; ".join(reasons)
    return {"static": static, "velocity": velocity}, detail


def polish(
    rest: np.ndarray,
    dq: np.ndarray,
    tau: np.ndarray,
    offset: np.ndarray,
    X: np.ndarray,
    names: list[str],
    beta: np.ndarray,
    theta: dict,
    seen: np.ndarray,
) -> tuple[np.ndarray, dict, list[str]]:
    """(β, θ, IPOPT statuses) with (fs_j, fs_j_stop, vs_j) polished; inputs as in `candidates.fit` (training
    part), `seen` (N, 2) the samples away from stops and starts (`trusted`).

    vs enters nonlinearly: IPOPT moves (fs_j, fs_j_stop, vs_j) jointly, per joint, with every other coefficient
    held, from the search's answer. Only samples where joint j moves are used: at rest the Stribeck term is
    zero (dq = 0) and the rest stretches' projection does not touch them, so this is exactly the candidate's
    objective restricted to those three; a joint's polish is kept only if it lowers that objective."""
    beta, theta, statuses = beta.copy(), dict(theta), []
    fs, stop, vs = ca.SX.sym("fs"), ca.SX.sym("fs_stop"), ca.SX.sym("vs")
    v, away = ca.SX.sym("dq"), ca.SX.sym("away")  # away: 1 away from stops, 0 near them
    level = fs * away + stop * (1 - away)
    expr = level * ca.sign(v) * ca.exp(-((v / vs) ** 2))  # N m, the excess over the Coulomb level
    f = ca.Function("stribeck", [v, away, fs, stop, vs], [expr])
    for j in range(2):
        k = [names.index(f"fs{j + 1}"), names.index(f"fs{j + 1}_stop")]
        moving = rest[:, j] < 0
        if moving.sum() < 10:
            continue
        others = beta.copy()
        others[k] = 0.0
        target = (tau[:, j] - offset[:, j] - X[:, j, :] @ others)[moving]
        data = [dq[moving, j], seen[moving, j].astype(float)]
        x0 = [beta[k[0]], beta[k[1]], theta[f"vs{j + 1}"]]
        every = max(1, int(moving.sum()) // POLISH_ROWS)

        def cost(p, target=target, data=data):
            return float(np.sum((target - np.array(f(data[0][None, :], data[1][None, :], *p)).ravel()) ** 2))

        fit = nlp.fit_expression(
            expr,
            ca.vertcat(fs, stop, vs),
            [v, away],
            [d[::every] for d in data],
            target[::every],
            x0=x0,
            lb=[0.0, 0.0, VS_RANGE[0]],
            ub=[np.inf, np.inf, VS_RANGE[1]],
            names=[f"fs{j + 1}", f"fs{j + 1}_stop", f"vs{j + 1}"],
            options={"ipopt.max_iter": 100},
        )
        statuses.append(f"joint {j + 1}: {fit.status}")
        if fit.success and cost(fit.values) < cost(x0):
            beta[k[0]], beta[k[1]], theta[f"vs{j + 1}"] = map(float, fit.values)
    return beta, theta, statuses


EFFECT = Stribeck()
