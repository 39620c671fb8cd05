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

from ident_opt.effects.base import (
    Effect,
    Key,
    ca,
    cands,
    datasheet,
    edge_rule,
    inside,
    linear,
    nlp,
    np,
    report,
    signals,
)
from ident_opt.parameters import Parameter

#: The default excess of the static level over the datasheet's mean Coulomb level [N m], per joint.
DEFAULT_EXCESS = (0.3, 0.2)


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
#: A rest this long [s] is a stop (or a start), not the slow instant of a velocity reversal.
STOP_S = 0.25


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
        "static": Key("pair", None, "N m, static (breakaway) level fs per joint (default: datasheet fc + [0.3,0.2])"),
        "velocity": Key("pair", (0.05, 0.05), "rad/s, Stribeck velocity vs, per joint", 0.0, True),
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
    resolution = edge_rule(
        "Stribeck friction with no joint's excess resolved, or whose velocity vs lies",
        VS_RANGE,
        "rad/s",
        "an excess that does not fall off within the range is a Coulomb step, a candidate of its own",
    )

    def resolved(self, estimate: dict, dt: float) -> bool:
        vs = [v for s, v in zip(estimate["static"], estimate["velocity"]) if s > 0]
        return bool(vs) and all(inside(v, *VS_RANGE) for v in vs)

    def families(self, robot) -> list:
        names = tuple(p.name for p in self.parameters)
        return [
            self.family(
                extra=_columns,
                nonnegative=(*names, "fs1_stop", "fs2_stop"),
                axes=lambda rate: [
                    linear.Axis("vs1", *VS_RANGE, 11, True),
                    linear.Axis("vs2", *VS_RANGE, 11, True),
                ],
                estimate=_estimate,
                refine=lambda ctx, o, X, names, beta, theta: polish(
                    ctx.rest, ctx.train.dq, ctx.train.tau, o, X, names, beta, theta, trusted(ctx.train)
                ),
            )
        ]

    def sentence(self, d, base: str, gain: str) -> str:
        e, ev, pair = d.estimate, d.evidence[d.baseline], report.pair
        return (
            f"Friction rises at low speed beyond the Coulomb level (low-speed excess of the residual "
            f"{pair(ev['low_speed_excess'], 'N m')}): a static level fs = {pair(e['static'], 'N m')} "
            f"falling off over vs = {pair(e['velocity'], 'rad/s')} explains it; {gain}"
        )

    def draw(self, rng, robot) -> dict:
        u, fc = rng.uniform, datasheet.rigid_body(robot, "physical").fc
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
    return {"static": static, "velocity": velocity}, {
        "se_static": [se["fs1"], se["fs2"]],
        "excess": [p["fs1"], p["fs2"]],
    }


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
        every = max(1, int(moving.sum()) // cands.POLISH_ROWS)

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
