"""``joint_offset``: encoder zero offsets, the true angle is the logged q + offset.

Model extension ``joint_offset`` (alias ``offset``): b1s b2s, the sin gravity columns an encoder zero
offset adds by rotating G. Simulator: the encoders read the true angle − δ. Diagnosis: the nominal model
evaluated at q + δ (gravity and inertia both see the true angle), δ1 δ2 [rad] searched, then polished by
IPOPT jointly with π (`offsets`), against both nominal models.
"""

from __future__ import annotations

import math
import time

from ident_opt import wording
from ident_opt.effects.base import Effect, arm_values, ca, damped_mode, least_squares, nlp, np, relative_error, signals
from ident_opt.effects.families import POLISH_ROWS, ChainFamily, per_joint
from ident_opt.effects.keys import Key
from ident_opt.parameters import Parameter

#: A hidden offset is found when the estimate is within this [rad] or this relative error.
OFFSET_TOL = (0.01, 0.20)
#: Most linear fits that centre the offset search (`gravity_rotation`).
CENTRE_ITERATIONS = 6
#: Plausibility (`diagnosis.plausibility`, docs/effects.md "Plausibility"): the physical range of the estimate, as data.
PLAUSIBLE = (
    {
        "key": "offset",
        "most_abs": 0.05,
        "unit": "rad",
        "unless": "distinct",
        "why": "an encoder's zero is set at assembly against a mark, to within a few tenths of a degree to a few "
        "degrees (0.05 rad is 2.9°); a larger offset is a real mistake only when the same offset gains on a motion "
        "distinct from the one it was fitted on (on the motion it was fitted on, a wrong zero imitates any pose-"
        "dependent error: a frame, a mass)",
    },
)


class JointOffset(Effect):
    summary = "encoder zero offsets: the true angle is the logged q + offset"
    order = 7
    keys = {"offset": Key("pair", (0.02, -0.03), "rad, per joint", None, magnitude=True, maximum=4 * math.pi)}  # noqa: RUF012

    # ------------------------------------------------------------------ model: G rotated by δ
    parameters = (
        Parameter("b1s", "N m", "sin q1 gravity column: an encoder zero offset rotates G", "gravity"),
        Parameter("b2s", "N m", "sin(q1 + q2) gravity column", "gravity"),
    )
    aliases = ("offset",)

    def check_model(self, model) -> None:
        if model.gravity == "paper":
            raise ValueError("the offset extension needs the physical gravity vector")

    def columns(self, model) -> dict:
        zero, s = np.zeros_like, np.sin
        return {
            "b1s": lambda q, dq, a: (s(q[:, 0]), zero(q[:, 0])),
            "b2s": lambda q, dq, a: (s(q[:, 0] + q[:, 1]), s(q[:, 0] + q[:, 1])),
        }

    def add_terms(self, model, q, dq, p: dict, M: list, G: list, F: list) -> None:
        s1, s12 = ca.sin(q[0]), ca.sin(q[0] + q[1])
        G[0] = G[0] + (p["b1s"] * s1 + p["b2s"] * s12)
        G[1] = G[1] + p["b2s"] * s12

    # ------------------------------------------------------------------ simulator: the encoders' zero
    def true_plant(self, plant, p: dict) -> None:
        plant.offset = [a + b for a, b in zip(plant.offset, p["offset"])]

    def chain_default(self, key: str, joints) -> object:
        """An n-joint arm: the planar default's two values in turn, 0.02 and −0.03 rad."""
        return tuple(self.keys[key].default[j % 2] for j in range(joints.n))

    def chain_plant(self, plant, p: dict) -> None:
        plant.offset = plant.offset + np.asarray(p["offset"])

    def chain_families(self, ctx) -> list:
        """The nominal model at q + δ, δ by Gauss–Newton on the torque's angle Jacobian (`chain.search.offset_search`)
        on every joint, then on the joints where it is resolved; against both nominal models."""
        return [
            ChainFamily(
                self.name,
                angles=lambda theta: np.array([theta.get(f"delta{j + 1}", 0.0) for j in range(ctx.n)]),
                search=lambda family, baseline, ctx: ctx.offset_search(family, baseline),
                estimate=lambda p, se, ctx: ({"offset": per_joint(p, "delta", ctx.n)}, {}),
            )
        ]

    def chain_draw(self, rng, joints, chosen) -> dict:
        return {
            "offset": arm_values(joints.n, chosen, 0.0, lambda j: rng.uniform(0.02, 0.06) * rng.choice([-1.0, 1.0]))
        }

    def chain_judge(self, estimate: dict, truth: dict) -> list[tuple[bool, float]]:
        return self.judge(estimate, truth)

    # ------------------------------------------------------------------ diagnosis
    judged = ("offset",)
    plausible = PLAUSIBLE

    def families(self, ctx) -> list:
        return [
            self.family(
                angles=lambda th: np.array([th["delta1"], th["delta2"]]),
                axes=lambda rate: [
                    least_squares.Axis("delta1", -0.1, 0.1, 21),
                    least_squares.Axis("delta2", -0.1, 0.1, 21),
                ],
                center=gravity_rotation,
                estimate=lambda p, se, ctx: ({"offset": [p["delta1"], p["delta2"]]}, {}),
                polish=_polish,
            )
        ]

    def sentence(self, d, base: str, gain: str) -> str:
        pair, ev = wording.pair, d.evidence[d.baseline]
        return (
            f"Gravity looks rotated (pose-correlated share of the residual {pair(ev['pose_r2'])}): encoder "
            f"zero offsets δ = {pair(d.estimate['offset'], 'rad')} explain it"
            f"{wording.polish_note(d.named and d.named.detail, 'offset', 'rad')}; {gain}"
        )

    def draw(self, rng, robot) -> dict:
        return {"offset": tuple(rng.uniform(0.02, 0.06) * rng.choice([-1.0, 1.0]) for _ in range(2))}

    def judge(self, estimate: dict, truth: dict) -> list[tuple[bool, float]]:
        checks = []
        for e, t in zip(estimate["offset"], truth["offset"]):
            rel = relative_error(e, t)
            checks.append((abs(e - t) <= OFFSET_TOL[0] or rel <= OFFSET_TOL[1], rel))
        return checks


def gravity_rotation(ctx, baseline: str) -> dict:
    """Where the offset search is centred [rad], any size: the rotation of gravity read from linear fits.

    G1 = b1 cos(q1 + δ1) + b2 cos(q1 + q2 + δ1 + δ2) = b1 cos δ1 cos q1 − b1 sin δ1 sin q1 + …, so the rigid
    model with the offset extension's sin columns (b1s, b2s) fitted by least squares gives
    δ1 = atan2(−b1s, b1) and δ1 + δ2 = atan2(−b2s, b2), however large the offset (a quarter turn included).
    The inertia terms see q2 + δ2 too, so the fit is repeated at the shifted angles until the correction is
    below 1 mrad (at most `CENTRE_ITERATIONS`). Per-direction Coulomb levels are fitted alongside: an
    asymmetric friction would otherwise leak into the gravity columns. The search then refines ±0.1 rad
    around the centre and IPOPT polishes within ±2π."""
    tr = ctx.train
    model = ctx.model((*ctx.nominal.extensions, "asymmetric_coulomb", "joint_offset"))
    tau = signals.demean_runs(tr.tau, ctx.rest)
    delta = np.zeros(2)
    for _ in range(CENTRE_ITERATIONS):
        Y = signals.demean_runs(model.regressor(tr.q + delta, tr.dq, tr.ddq), ctx.rest)
        p = dict(zip(model.names, least_squares.solve(np.zeros_like(tau), Y, tau, ctx.weights, False).beta))
        d1 = math.atan2(-p["b1s"], p["b1"])
        d12 = math.atan2(-p["b2s"], p["b2"])
        step = np.array([d1, math.remainder(d12 - d1, 2 * math.pi)])
        delta = delta + step
        if np.max(np.abs(step)) < 1e-3:
            break
    return {"delta1": float(delta[0]), "delta2": float(delta[1])}


def _polish(baseline: str, ctx, o, X, beta, theta: dict, bounds: dict) -> tuple[dict | None, dict]:
    """(δ1, δ2) jointly by IPOPT, with π when it is refitted (`offsets`), within a half turn."""
    tr, model = ctx.train, ctx.nominal
    held = model.vector(ctx.datasheet) if baseline == "datasheet" else None
    wide = (-2 * math.pi, 2 * math.pi)
    return offsets(model, tr.q, tr.dq, tr.ddq, tr.tau, ctx.rest, ctx.weights, held, beta, theta, wide)


def offsets(
    model,
    q: np.ndarray,
    dq: np.ndarray,
    ddq: np.ndarray,
    tau: np.ndarray,
    labels: np.ndarray,
    weights: np.ndarray,
    pi_fixed: np.ndarray | None,
    beta: np.ndarray,
    theta: dict,
    bounds: tuple[float, float],
) -> tuple[dict | None, dict]:
    """IPOPT on the encoder offsets (δ1, δ2) jointly with π (rigid_fit; `pi_fixed` None) or with the
    datasheet π held (`pi_fixed`): the candidate's objective, Σ_j w_j |demean_runs(τ_j − τ̂_j(q + δ))|².

    The search moves δ1 and δ2 one at a time (grid sweeps, then a Brent refinement per coordinate); gravity
    couples them (b2 cos(q1 + q2 + δ1 + δ2) sees their sum), so a joint step can still lower the cost. The
    model is smooth in δ (sines and cosines), so IPOPT (exact Hessian) is cheap here. Returns (θ or None,
    info); the caller re-solves π exactly at the new δ and keeps it only if the training objective drops."""
    t0 = time.perf_counter()
    every = max(1, -(-len(q) // POLISH_ROWS))
    q, dq, ddq, tau, labels = (a[::every] for a in (q, dq, ddq, tau, labels))
    if every > 1:
        labels = signals.rest_runs(np.where(labels >= 0, 0.0, 1.0))
    n, k = len(q), len(beta)
    delta = ca.MX.sym("delta", 2)
    # π on unit-norm columns (as `least_squares.solve`): they differ by orders of magnitude (inertias vs gravity).
    scale = np.ones(0)
    if pi_fixed is None:
        Y = model.regressor(q + np.array([theta["delta1"], theta["delta2"]]), dq, ddq)
        scale = 1.0 / np.maximum(np.sqrt(np.einsum("njk,j->k", Y**2, weights)), 1e-300)
    bs = ca.MX.sym("b", k if pi_fixed is None else 0)
    pi = bs * ca.DM(scale) if pi_fixed is None else ca.DM(pi_fixed)
    f = model.function("tau").map(n)
    pred = f(ca.DM(q.T) + ca.repmat(delta, 1, n), ca.DM(dq.T), ca.DM(ddq.T), ca.repmat(pi, 1, n))  # 2 × n
    objective = 0
    for j in range(2):
        r = damped_mode.demean_mx(ca.DM(tau[:, j]) - pred[j, :].T, labels[:, j])
        objective = objective + float(weights[j]) * ca.sumsqr(r)
    z = ca.vertcat(delta, bs)
    x0 = np.concatenate([[theta["delta1"], theta["delta2"]], beta / scale if pi_fixed is None else []])
    lb = np.concatenate([[bounds[0]] * 2, np.full(len(x0) - 2, -np.inf)])
    ub = np.concatenate([[bounds[1]] * 2, np.full(len(x0) - 2, np.inf)])
    # Exact Hessian: π enters linearly, so the problem is a quadratic in π coupled to δ — quasi-Newton
    # crawls along that ill-conditioned quadratic; Newton steps take it in one.
    options = {**nlp.IPOPT_QUIET, "ipopt.max_iter": 50}
    solver = ca.nlpsol("offsets", "ipopt", {"x": z, "f": objective / n}, options)
    sol = solver(x0=x0, lbx=lb, ubx=ub)
    st = solver.stats()
    zs = np.array(sol["x"]).ravel()
    info = {
        "method": f"IPOPT, (δ1, δ2) jointly with {'π' if pi_fixed is None else 'the datasheet π held'}",
        "status": st["return_status"],
        "iterations": int(st["iter_count"]),
        "seconds": time.perf_counter() - t0,
    }
    if not np.all(np.isfinite(zs[:2])):
        return None, info
    return {"delta1": float(zs[0]), "delta2": float(zs[1])}, info


EFFECT = JointOffset()
