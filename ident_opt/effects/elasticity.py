"""``elasticity``: a lightly damped mode, an elastic joint (two-mass, motor angle logged) or a flexible link.

In the simulator (values in SI units):

- ``kind=joint``: joint j becomes a two-mass (Spong) model. The motor (inertia B = the joint's armature,
  its friction F_j) drives the link through a spring k and damper d: τ_s = k (θ − q_j) + d (dθ − dq_j),
  B ddθ + F_j(dθ) = τ_j − τ_s, and the link side is the rigid model without that armature and friction,
  driven by τ_s at joint j. k = J_l (2π f)², d = 2 ζ √(k J_l), with J_l the link-side inertia at joint j
  (joint 1: at q2 = 0 with joint 2 held). The logged angle of joint j is the motor's θ.
- ``kind=link``: link j is cut at mid-length into two rigid halves joined by a torsional spring (see
  `simulator/flexible_link.py`); the joints stay rigid and their angles are logged.

Either way the plant gains two states and logs the spring's deflection as ``deflection<j>``.

Diagnosis, once per joint j, the same model on the planar arm (`elastic_drive`) and on an n-joint arm
(`_arm_columns`): the link behind joint j deflects by e, driven by the link-side torque the measured motion
demands at joint j, ë + 2ζω ė + ω² e = −τ_link,j / M_jj (datasheet inertias, `signals.deflection`); the torque
gains s·(M_link[:, j] ë + ∂τ_link/∂q_j e), the mode's inertia and gravity's sag. The mode's f and ζ are searched
by variable projection; on the planar arm IPOPT then polishes them jointly with every β by multiple shooting
(`numerics/damped_mode.py`), against both nominal models.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ident_opt import wording
from ident_opt.effects.base import Effect, damped_mode, edge_rule, inside, least_squares, np, relative_error, signals
from ident_opt.effects.families import ChainFamily, step, view_key
from ident_opt.effects.keys import Key
from ident_opt.errors import InputError

#: Joint-2 angles [rad] the trajectories reach: |q2| ≤ 1.4 rad (the band of the mode over the workspace).
Q2_RANGE = (0.0, 1.4)
#: Where an elastic mode is searched [Hz]: the first modes of flexible-link arms lie at a few Hz; above
#: ~12 Hz a mode is no longer observable in accelerations estimated with the usual 15 Hz low-pass, and a
#: "mode" there only fits filter transients at starts and stops.
ELASTIC_BAND_HZ = (1.5, 12.0)
#: Where an elastic mode's damping ratio is searched.
DAMPING_RANGE = (0.005, 0.3)
#: Largest static deflection [rad] of an elastic joint under its RMS logged torque (`PLAUSIBLE`): the diagnosis's
#: deflection model is linear (sin e ≈ e within 1.5 % up to 0.3 rad, gravity's own stiffness left out), and a spring
#: that sags more under the joint's everyday torque lets the link hang visibly off its pose (17°), which no drive
#: (a gear deflects by arc-minutes) and no link of a position-controlled arm does.
MOST_SAG_RAD = 0.3
#: Plausibility (`diagnosis.plausibility`, docs/effects.md "Plausibility"): the physical range of the estimate, as data.
PLAUSIBLE = (
    {"key": "frequency_hz", "search": ELASTIC_BAND_HZ, "unit": "Hz"},
    {"key": "damping_ratio", "search": DAMPING_RANGE, "unit": ""},
    {
        "key": "stiffness",
        "most_sag": MOST_SAG_RAD,
        "unit": "N m/rad",
        "why": "a spring that would sag more than 0.3 rad (17°) under the joint's RMS torque holds no pose: no drive "
        "(arc-minutes under rated torque) and no link of a position-controlled arm is that soft, and the fitted mode "
        "then carries a sliver of the link's inertia (the TX40's 0.068 N m/rad: 6e-4 kg m²), following a filter or "
        "timing mismatch rather than a resonance",
    },
)
#: Relative tolerance on a hidden mode's frequency.
FREQUENCY_TOL = 0.20
#: Highest mode the simulator accepts [Hz]: a stiffer spring is a rigid joint at any control rate it runs at
#: (and its RK4 steps would grow without bound; `chain_loop.MAX_SUBSTEPS` bounds them too).
MAX_FREQUENCY_HZ = 500.0


@dataclass(frozen=True)
class Mode:
    """A lightly damped mode behind joint `index` (0-based): a spring k [N m/rad] and a damper d [N m s/rad] between
    a driven motor inertia B [kg m²] and a link inertia J_link [kg m²], which set its natural frequency
    `frequency_hz` [Hz] and damping ratio `damping` (`spring_for`); `fastest_rate` [1/s] bounds the mode's rate with
    the joints free (it sizes the RK4 step). The planar arm's `Elastic` and the n-joint plant's
    `simulator.chain_plant.ElasticJoint` are modes."""

    index: int
    k: float
    d: float
    B: float
    J_link: float
    frequency_hz: float
    damping: float
    fastest_rate: float

    @property
    def deflection_column(self) -> str:
        """The logged column of the spring's deflection."""
        return f"deflection{self.index + 1}"


def natural_hz(k: float, J: float) -> float:
    """The natural frequency [Hz] of a spring k [N m/rad] on an inertia J [kg m²]: √(k/J) / 2π."""
    return math.sqrt(k / J) / (2 * math.pi)


def spring_for(J_link: float, frequency_hz: float, damping: float) -> tuple[float, float]:
    """(k [N m/rad], d [N m s/rad]) of a mode of `frequency_hz` [Hz] and damping ratio `damping` on the inertia
    J_link [kg m²]: k = J_link (2π f)², d = 2 ζ √(k J_link)."""
    k = J_link * (2 * math.pi * frequency_hz) ** 2
    return k, 2 * damping * math.sqrt(k * J_link)


class Elasticity(Effect):
    summary = "a lightly damped mode: an elastic joint (two-mass, motor angle logged) or a flexible link"
    order = 4
    keys = {  # noqa: RUF012
        "joint": Key("joint", 2, "the elastic joint: 1 or 2 (1 … n, or its name, on an n-joint arm)"),
        "frequency_hz": Key(
            "float", 3.0, "Hz, the mode's natural frequency with the joints held", 0.0, True, maximum=MAX_FREQUENCY_HZ
        ),
        "damping": Key("float", 0.02, "damping ratio of that mode", maximum=10.0),
        "kind": Key(
            "choice",
            "joint",
            "joint: two-mass elastic joint; link: link `joint` cut in two halves joined by a spring",
            None,
            choices=("joint", "link"),
        ),
    }

    def scaled(self, p: dict, s: float, coulomb: tuple[tuple, tuple]) -> dict:
        # Magnitude = compliance 1/k ∝ 1/f²: scale 0 is a rigid joint.
        p["frequency_hz"] = p["frequency_hz"] / math.sqrt(s) if s > 0 else math.inf
        return p

    def is_active(self, p: dict, coulomb: tuple[tuple, tuple]) -> bool:
        return math.isfinite(p["frequency_hz"])

    # ------------------------------------------------------------------ simulator
    def mechanism(self, plant, p: dict) -> tuple[str, int, float, float]:
        """(kind "joint" or "link", 0-based joint, frequency [Hz], damping ratio): the simulator builds it
        (`simulator.elastic.build`)."""
        return p["kind"], p["joint"] - 1, p["frequency_hz"], p["damping"]

    # ------------------------------------------------------------------ any arm: a two-mass joint
    def chain_mechanism(self, plant, p: dict) -> tuple[int, float, float]:
        if p["kind"] != "joint":
            raise InputError(
                f"effect elasticity: kind={p['kind']} is the planar two-link arm's flexible link; on "
                f"{plant.robot.described_as} an elastic joint is kind=joint"
            )
        return p["joint"] - 1, p["frequency_hz"], p["damping"]

    def chain_truth(self, plant, p: dict) -> dict:
        """`frequency_hz` is the spring's at the centre pose (the `--effect` key); the link inertia behind it moves
        with the other joints, so the trial has its own: `frequency_trial_hz` at the motion's mean link inertia (what
        the diagnosis estimates: its column carries the mean over the samples), `frequency_range_hz` over it."""
        e = plant.elastic
        trial = {}
        if e.trial_inertia is not None:
            mean, least, largest = e.trial_inertia
            trial = {
                "frequency_trial_hz": natural_hz(e.k, mean),
                "frequency_range_hz": [natural_hz(e.k, largest), natural_hz(e.k, least)],
                "link_inertia_trial": [mean, least, largest],
            }
        return {
            "joint": e.index + 1,
            "joint_name": plant.robot.joint_names[e.index],
            "kind": "joint",
            "frequency_hz": e.frequency_hz,
            **trial,
            "damping": e.damping,
            "stiffness": e.k,
            "damper": e.d,
            "motor_inertia": e.B,
            "motor_inertia_added": e.motor_added,
            "link_inertia": e.J_link,
        }

    def chain_families(self, ctx) -> list:
        """An elastic joint on each of the joints whose residual rings most (`chain.search.elastic_joints`): the link
        behind it deflects by e, ë + 2ζω ė + ω² e = −u driven by the measured motion, and adds s M_link[:, j] ë to the
        torque (`_arm_columns`); beside it, against the datasheet, the motor's inertia B ddq_j a datasheet may lack.
        f and ζ searched as on the planar arm, against both nominal models."""
        return [
            ChainFamily(
                self.name,
                extra=_arm_columns(joint),
                axes=lambda rate, theta: [
                    least_squares.Axis("frequency_hz", *ELASTIC_BAND_HZ, 16, True),
                    least_squares.Axis("damping", *DAMPING_RANGE, 6, True),
                ],
                nonnegative=("scale", "motor"),
                estimate=_arm_estimate(joint),
                nests=("armature",),  # its motor column, against the datasheet, is joint j's armature column
            )
            for joint in ctx.elastic_joints(_arm_columns)
        ]

    def chain_draw(self, rng, joints, chosen) -> dict:
        return {"joint": chosen[0] + 1, "frequency_hz": rng.uniform(3.0, 8.0), "damping": rng.uniform(0.01, 0.05)}

    def chain_judge(self, estimate: dict, truth: dict) -> list[tuple[bool, float]]:
        """Against the trial's own frequency where the truth has it (`chain_truth`)."""
        return self.judge(estimate, {**truth, "frequency_hz": truth.get("frequency_trial_hz", truth["frequency_hz"])})

    def truth_entry(self, truth, p: dict) -> dict:
        e = truth.elastic
        return {
            "joint": e.index + 1,
            "kind": e.kind,
            "frequency_range_hz": list(e.frequency_range_hz),
            "frequency_hz": e.frequency_hz,
            "damping": e.damping,
            "stiffness": e.k,
            "damper": e.d,
            "motor_inertia": e.B,
            "link_inertia": e.J_link,
        }

    # ------------------------------------------------------------------ diagnosis
    judged = ("joint", "frequency_hz")
    plausible = PLAUSIBLE
    resolution = edge_rule(
        "an elastic mode whose frequency lies", ELASTIC_BAND_HZ, "Hz", "the residual has no resonance inside the band"
    )

    def resolved(self, estimate: dict, dt: float) -> bool:
        return inside(estimate["frequency_hz"], *ELASTIC_BAND_HZ)

    def families(self, ctx) -> list:
        return [
            self.family(
                extra=_columns(joint),
                axes=lambda rate: [
                    least_squares.Axis("frequency_hz", *ELASTIC_BAND_HZ, 16, True),
                    least_squares.Axis("damping", *DAMPING_RANGE, 6, True),
                ],
                # The spring carries a positive share of the link's inertia: a negative one is no mode (it
                # is what a filter or timing mismatch, e.g. a delay estimated a millisecond long, leaves).
                nonnegative=("scale",),
                estimate=_estimate(joint),
                polish=_polish(joint),
            )
            for joint in (1, 2)
        ]

    def sentence(self, d, base: str, gain: str) -> str:
        e, det, num = d.estimate, d.detail_of(self.name), wording.num
        # k and the link inertia come from the fitted scale s; without them (no such fit) the mode alone is said.
        spring = (
            f"k = {num(det['stiffness'], 'N m/rad')} (link inertia {num(det['inertia'], 'kg m²')}, damping ratio "
            f"{num(det['damping_ratio'])})"
            if all(np.isfinite(det.get(key, np.nan)) for key in ("stiffness", "inertia", "damping_ratio"))
            else f"its mode at {num(e['frequency_hz'], 'Hz')}"
        )
        return (
            f"Joint {e['joint']} shows a lightly damped {num(e['frequency_hz'], 'Hz')} oscillation that the "
            f"rigid model cannot produce; an elastic joint with {spring} driven by the measured motor-side angle "
            "explains it"
            f"{wording.polish_note(d.named and d.named.detail, 'frequency_hz', 'Hz')}; {gain}"
        )

    def spectrum_marker(self, estimate: dict, joint: int) -> float | None:
        return estimate["frequency_hz"] if estimate["joint"] == joint + 1 else None

    def channel_lines(self, d, channels: dict) -> list[str]:
        el = next((c for c in d.candidates if c["cause"] == self.name), None)
        if el is None:
            return []
        f = el["estimate"]["frequency_hz"]
        near = [n for n, info in channels.items() if abs(info["mode_band_max_hz"] - f) <= 0.2 * f]
        status = "the named cause" if d.cause == self.name else f"not named; score {el['score']:.1f}"
        return [
            "",
            f"The elastic-joint candidate ({status}) puts a mode at {wording.num(f, 'Hz')} on joint "
            f"{el['estimate']['joint']}; channels whose 1–10 Hz maximum lies within 20 % of it: "
            + (", ".join(f"`{n}`" for n in near) if near else "none")
            + ".",
        ]

    def draw(self, rng, robot) -> dict:
        u = rng.uniform
        return {"joint": int(rng.integers(1, 3)), "frequency_hz": u(2.0, 8.0), "damping": u(0.01, 0.05)}

    def judge(self, estimate: dict, truth: dict) -> list[tuple[bool, float]]:
        same = estimate["joint"] == truth["joint"]
        rel = relative_error(estimate["frequency_hz"], truth["frequency_hz"])
        return [(same, 0.0 if same else 1.0), (rel <= FREQUENCY_TOL, rel)]


def elastic_drive(joint: int, ds, ctx) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u (N,) [rad/s²], P (N, 2) [kg m²], K (N, 2) [N m/rad]): the drive of elastic joint j's link, its inertia
    pattern and its stiffness pattern, from the datasheet's link side (friction and the rotors' inertia removed).

    The link behind an elastic joint j sits at q_j = θ_j + e. Its spring carries the link-side torque the measured
    motion demands at joint j, τ_link,j (inertial, Coriolis and gravity), so the deflection is driven by
    u = τ_link,j / M_jj,link (the same model as the n-joint engine's, `_arm_columns`): at rest it is gravity's
    static sag, in motion the mode. The torques then differ from the rigid model's at θ by P ë + K e, with
    P = M_link[:, j] (link j's inertia on its own row, the coupling on the other) and K = ∂τ_link/∂q_j (what
    the sag does to gravity's torque on both rows). One free scale s on that physical pattern: the pattern (which
    row rings how much) is what tells an elastic joint 1 from an elastic joint 2, so it is not free."""
    # Remembered for the last few views (`chain.families.view_key`). Few: an offset's search builds a new view at every
    # trial angle.
    key = (joint, *view_key(ds))
    cache = ctx.cache.setdefault("elastic_drive", {})
    if key not in cache:
        if len(cache) >= 4:
            cache.pop(next(iter(cache)))  # the oldest
        model = ctx.nominal
        pi = model.link_side(model.vector(ctx.datasheet), ctx.armature)
        unit, zero = np.zeros_like(ds.ddq), np.zeros_like(ds.ddq)
        unit[:, joint - 1] = 1.0
        P = model.predict(pi, ds.q, zero, unit) - model.predict(pi, ds.q, zero, zero)
        tau_link = model.predict(pi, ds.q, ds.dq, ds.ddq)
        h = 1e-6  # central differences: the planar model is smooth in q, and this is exact to ~1e-9 relative
        dq_j = np.zeros_like(ds.q)
        dq_j[:, joint - 1] = h
        K = (model.predict(pi, ds.q + dq_j, ds.dq, ds.ddq) - model.predict(pi, ds.q - dq_j, ds.dq, ds.ddq)) / (2 * h)
        cache[key] = (tau_link[:, joint - 1] / P[:, joint - 1], P, K)
    return cache[key]


def _arm_columns(joint: int):
    """The elastic joint's columns on an n-joint arm (0-based `joint`): the link behind it sits at q_j = θ_j + e,
    e driven by the link-side torque the measured motion demands at joint j (inertial, Coriolis, gravity: the
    datasheet's), ë + 2ζω ė + ω² e = −τ_link,j / M_jj; the torques then differ from the rigid model's at θ by
    s (M_link[:, j] ë + ∂τ_link/∂q_j e) (an inertia and a pose shift, scaled together by s ≥ 0); and, against the
    datasheet, B ddq_j on row j (the motor's inertia, which the datasheet may lack)."""

    def columns(ds, theta: dict, ctx, baseline: str) -> tuple[np.ndarray, list[str]]:
        P = ctx.inertia_column(ds, joint)
        e, acceleration = signals.deflection(
            ctx.link_torque(ds)[:, joint] / P[:, joint],
            theta.get("frequency_hz", 5.0),
            theta.get("damping", 0.05),
            step(ds),
        )
        X = (P * acceleration[:, None] + ctx.stiffness_column(ds, joint) * e[:, None])[:, :, None]
        if baseline != "datasheet":
            return X, ["scale"]
        motor = np.zeros_like(X)
        motor[:, joint, 0] = ds.ddq[:, joint]
        return np.concatenate([X, motor], axis=2), ["scale", "motor"]

    return columns


def _arm_estimate(joint: int):
    def estimate(p: dict, se: dict, ctx) -> tuple[dict, dict]:
        m_link = float(np.mean(ctx.inertia_column(ctx.train, joint)[:, joint]))
        m_eff = p["scale"] * m_link  # the link inertia the spring carries [kg m²]
        w = 2 * math.pi * p["frequency_hz"]
        return (
            {"joint": joint + 1, "frequency_hz": p["frequency_hz"]},
            {
                "joint_name": ctx.robot.joint_names[joint],
                "damping_ratio": p["damping"],
                "inertia": m_eff,
                "stiffness": m_eff * w * w,
                "damping_coefficient": 2 * p["damping"] * w * m_eff,
                "motor_inertia_beyond_datasheet": p.get("motor", 0.0),
            },
        )

    return estimate


def _columns(joint: int):
    def columns(ds, theta: dict, dt: float, ctx) -> tuple[np.ndarray, list[str]]:
        u, P, K = elastic_drive(joint, ds, ctx)
        e, acceleration = signals.deflection(u, theta["frequency_hz"], theta["damping"], dt)
        return (P * acceleration[:, None] + K * e[:, None])[:, :, None], ["scale"]

    return columns


def _estimate(joint: int):
    def estimate(p: dict, se: dict, ctx) -> tuple[dict, dict]:
        m_link = float(np.mean(elastic_drive(joint, ctx.train, ctx)[1][:, joint - 1]))
        m_eff = p["scale"] * m_link  # the link inertia the spring carries [kg m²]
        w = 2 * math.pi * p["frequency_hz"]
        return (
            {"joint": joint, "frequency_hz": p["frequency_hz"]},
            {
                "damping_ratio": p["damping"],
                "inertia": m_eff,
                "stiffness": m_eff * w * w,
                "damping_coefficient": 2 * p["damping"] * w * m_eff,
            },
        )

    return estimate


def _polish(joint: int):
    def polish(baseline: str, ctx, o, X, beta, theta: dict, bounds: dict) -> tuple[dict | None, dict]:
        # (f, ζ) with every β by IPOPT, multiple shooting; the scale s is the last column of X.
        u, P, K = elastic_drive(joint, ctx.train, ctx)
        tau = ctx.train.tau - o
        return damped_mode.polish(u, P, tau, X[:, :, :-1], ctx.rest, ctx.weights, ctx.dt, theta, beta, bounds, K)

    return polish


EFFECT = Elasticity()
