"""One rule for the plausibility of every cause's estimate (`docs/effects.md`, "Plausibility"), applied inside the
rounds where a candidate is picked (`rounds._pick`): a candidate that fails it is never named — it is treated as not
clearing the margin, with a `shortfall` saying why, and the loop goes on to the next candidate; what it would have
explained becomes evidence for a `mismatch` (`verdict`).

A candidate is plausible when all of these hold:

1. **range**: every estimate lies in its cause's physical range, declared as data beside the cause
   (`Effect.plausible`, each cause's `PLAUSIBLE`; read by `ranges`): a bound on a value (`least`, `most`: a number or
   one of the arm's own bounds, `Facts`; held with `SE_MARGIN` standard errors where the declaration names them,
   `se`), on its magnitude (`most_abs`, waived by `unless: "distinct"` when the held-out motion is distinct from the
   training one: the same value then gains on a trajectory it was not fitted on), on its magnitude as a share of one
   of the arm's bounds (`most_share` of `of`: a torque offset against the joint's largest logged torque), on a
   vector's length (`most_norm`) or, for an elastic joint, on the static sag of its spring under the joint's RMS torque
   (`most_sag`). On an arm with n joints a per-joint candidate is first fitted again without the joints whose values
   fail (`failing_joints`, `chain.families.fit`);
2. **search_edge** (false when it holds): no searched value lies within `EDGE` (a ratio) of a bound of its search
   (`search` in the same declarations): an estimate there is the search stopped by its bound, not the data's;
3. **no_joint_worse**: no joint's held-out MSE grows beyond its noise: by at least the naming margin's share of it
   (`scoring.MARGIN`, 5 %) and the engine's share of its torque variance — what a gain must clear to count — and by
   more than `SCATTER` standard errors of the paired difference of the two models' squared residuals on that joint
   (their means over blocks of `BLOCK_S`, the residuals being correlated over tens of samples: `paired_scatter`);
4. **forward_simulation**: the forward simulation (0.5 s windows driven by the measured torque, `evidence.
   forward_error`) does not get worse: Σ_j ln(e_after,j / e_before,j) over the joints stays below two standard errors
   of its scatter, 2 √(n / (2 W)) for W windows (each joint's RMS over W windows scatters by about 1/√(2W) in log);
5. and the candidate is **identifiable** from the motion: it gains (removes the margin) on some joint the training
   motion determines (`identifiability`: not a scaled copy of another joint's path). A candidate that gains only on
   undetermined joints is rejected as `not_identifiable` rather than implausible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ident_opt.diagnosis import scoring
from ident_opt.effects import CATALOGUE

#: A searched value within this ratio of a bound of its search sits at that edge (`search_edge`): five times the
#: naming rule's 2 % (`effects.base.SEARCH_EDGE`), "well inside" the range.
EDGE = 1.1
#: A joint is worse only when its MSE grows by more than this many standard errors of the paired difference.
SCATTER = 2.0
#: The blocks [s] the paired difference's standard error is read over (`paired_scatter`): the forward simulation's
#: windows, several times the residuals' correlation time after the low-pass.
BLOCK_S = 0.5
#: A bound holds with this many standard errors of the value, where the fit gives them (`se` in a declaration): μ4 =
#: 0.97 ± 0.06 on the TX40 is a gear of 51 % efficiency by its value, and of 48 % one standard error up.
SE_MARGIN = 2.0
#: Without `[robot] rated_payload` in the problem, the arm's is taken as this share of its moving links' mass (the
#: problem format's default: the nominal arm's mass): generous on every arm here (rated payload over arm mass: KUKA
#: LWR4+ 7/16 kg, Panda 3/18 kg, TX40 2/27 kg, UR10e 12.5/33.5 kg); a problem that knows its arm's says so.
RATED_SHARE = 1.0
#: A payload's centre of mass is near the flange when within this share of the chain's length of the last link's frame.
FLANGE_SHARE = 0.25


@dataclass
class Facts:
    """What the rule reads of the arm and the data: the joints' names, each joint's RMS and largest logged torque on the
    training part [N m], the rated payload [kg] and the flange radius [m] (None: no bound) with how they were read,
    whether the held-out motion is distinct from the training one, the joints the training motion leaves undetermined
    (0-based), the held-out torque's variance per joint [N² m²], the engine's variance floor and the forward
    simulation's number of windows."""

    joints: tuple[str, ...]
    torque_rms: np.ndarray
    torque_max: np.ndarray
    rated_payload: float | None
    flange: float | None
    distinct: bool
    undetermined: tuple[int, ...]
    var: np.ndarray
    floor: float
    windows: int
    how: dict = field(default_factory=dict)

    def bound(self, name, j: int | None = None) -> float | None:
        """A bound of a declaration: a number, or one of the arm's (`rated_payload`, `flange`, `torque_logged` of
        joint j)."""
        if isinstance(name, int | float):
            return float(name)
        if name == "rated_payload":
            return self.rated_payload
        if name == "flange":
            return self.flange
        if name == "torque_logged":
            return None if j is None else float(self.torque_max[j])
        raise ValueError(f"unknown bound {name!r}")

    def describe(self) -> dict:
        """The facts the rule used, for the JSON."""
        return {
            "rated_payload_kg": self.rated_payload,
            "flange_radius_m": self.flange,
            "held_out_distinct": self.distinct,
            **self.how,
        }


def facts(engine, ident, var: np.ndarray, robot) -> Facts:
    """The `Facts` of a diagnosis: its engine (its training part, `moving_mass` and `reach`), what the data can tell
    (`identifiability.Identifiability`), the held-out torque's variance and the robot (its `rated_payload` [kg] when
    the problem gives one)."""
    tau = engine.parts.train.tau
    rated = getattr(robot, "rated_payload", None)
    how = {}
    if rated:
        how["rated_payload"] = "the problem's rated payload"
    else:
        mass = engine.moving_mass
        rated = RATED_SHARE * mass if mass else None
        how["rated_payload"] = (
            f"the moving links' mass ({mass:.3g} kg): the problem gives no rated payload ([robot] rated_payload)"
            if mass
            else "unknown: the problem gives no rated payload and the model no link masses"
        )
    reach = engine.reach
    flange = FLANGE_SHARE * reach if reach else None
    if flange:
        how["flange_radius"] = f"{FLANGE_SHARE:.0%} of the chain's length ({reach:.3g} m)"
    test = engine.parts.test
    duration = float(test.t[-1] - test.t[0]) if test.n > 1 else 0.0
    return Facts(
        joints=tuple(robot.joint_names),
        torque_rms=np.sqrt(np.mean(tau**2, axis=0)),
        torque_max=np.max(np.abs(tau), axis=0),
        rated_payload=rated,
        flange=flange,
        distinct=ident.held_out_distinct,
        undetermined=tuple(ident.undetermined_joints) if not ident.full_rank else (),
        var=np.asarray(var, dtype=float),
        floor=engine.margin_variance,
        windows=max(1, int(duration // 0.5)),
        how=how,
    )


def _value(estimate: dict, detail: dict, key: str):
    if key in estimate:
        return estimate[key]
    return detail.get(key)


def _finite(v) -> bool:
    return v is not None and isinstance(v, int | float) and math.isfinite(v)


def _joint(facts: Facts, estimate: dict, j: int | None) -> str:
    """How a failure names the joint it is on: the joint's name, or the elastic joint's."""
    if j is None and isinstance(estimate.get("joint"), int) and 1 <= estimate["joint"] <= len(facts.joints):
        j = estimate["joint"] - 1
    return f" on {facts.joints[j]}" if j is not None and j < len(facts.joints) else ""


def _norm(entry: dict, value, facts: Facts) -> list[str]:
    """A vector's length against its bound (`most_norm`)."""
    bound = facts.bound(entry["most_norm"])
    size = float(np.linalg.norm(np.asarray(value, dtype=float)))
    if bound is None or size <= bound:
        return []
    u = f" {entry.get('unit')}" if entry.get("unit") else ""
    return [f"{entry['key']} {size:.3g}{u} from the last link's frame, beyond {bound:.3g}{u}"]


def _sag(entry: dict, value, estimate: dict, facts: Facts) -> list[str]:
    """An elastic joint's static sag under its RMS torque against its bound (`most_sag`)."""
    j = estimate.get("joint")
    if not (_finite(value) and isinstance(j, int) and 1 <= j <= len(facts.torque_rms)):
        return []
    torque = float(facts.torque_rms[j - 1])
    sag = torque / value if value > 0 else math.inf
    if sag <= entry["most_sag"]:
        return []
    return [
        f"{entry['key']} {value:.3g} {entry.get('unit', '')}{_joint(facts, estimate, None)} would sag {sag:.3g} rad "
        f"under the joint's RMS torque ({torque:.3g} N m), beyond {entry['most_sag']:g} rad"
    ]


def _bounds(entry: dict, v: float, j: int | None, where: str, facts: Facts, se: float = 0.0) -> list[str]:
    """One value against its magnitude bound (`most_abs`, waived by `unless: "distinct"` on a distinct held-out
    motion) and its bounds (`least`, `most`), these with `SE_MARGIN` standard errors `se` of the value where the fit
    gives them (`se` in the declaration: the detail key that holds them)."""
    key, u = entry["key"], f" {entry.get('unit')}" if entry.get("unit") else ""
    out = []
    if "most_abs" in entry and abs(v) > entry["most_abs"]:
        if not (entry.get("unless") == "distinct" and facts.distinct):
            why = " (the held-out motion repeats the training one)" if entry.get("unless") == "distinct" else ""
            out.append(f"{key} {v:.3g}{u}{where} beyond ±{entry['most_abs']:g}{u}{why}")
    if "most_share" in entry:
        of = facts.bound(entry["of"], j)
        if of is not None and abs(v) > entry["most_share"] * of:
            out.append(f"{key} {v:.3g}{u}{where} beyond ±{entry['most_share']:.0%} of {entry['of']} ({of:.3g}{u})")
    margin = SE_MARGIN * se if _finite(se) and se > 0 else 0.0
    sure = f" within {SE_MARGIN:g} standard errors ({v:.3g} ± {se:.2g})" if margin else ""
    for side, word in (("least", "below"), ("most", "beyond")):
        bound = facts.bound(entry[side], j) if side in entry else None
        if bound is not None and ((side == "least" and v - margin < bound) or (side == "most" and v + margin > bound)):
            out.append(f"{key} {v:.3g}{u}{where} {word} {bound:.3g}{u}{sure}")
    return out


def _se(entry: dict, detail: dict, j: int | None) -> float:
    """The standard error of a declared value (joint j's of a per-joint list), from its fit's detail (`se`), or 0."""
    found = (detail or {}).get(entry.get("se", ""), None)
    if isinstance(found, list | tuple):
        found = found[j] if j is not None and j < len(found) else None
    return float(found) if _finite(found) else 0.0


def failing_joints(cause: str, estimate: dict, detail: dict, facts: Facts) -> dict[int, list[str]]:
    """The joints (0-based) whose per-joint values fail their range (`_bounds`), each with why: a per-joint cause's
    candidate is fitted again without them (`chain.families.fit`), so one joint's implausible value does not refuse the
    joints where the cause is read well — and is never named."""
    out: dict[int, list[str]] = {}
    for entry in CATALOGUE[cause].plausible:
        value = _value(estimate, detail or {}, entry["key"])
        if not isinstance(value, list | tuple) or "most_norm" in entry or "most_sag" in entry:
            continue
        for j, v in enumerate(value):
            if _finite(v):
                why = _bounds(entry, v, j, _joint(facts, estimate, j), facts, _se(entry, detail, j))
                if why:
                    out.setdefault(j, []).extend(why)
    return out


def _edge(entry: dict, v: float, where: str) -> list[str]:
    """A searched value against its search's bounds (`search`; within `EDGE` of one is at its edge). 0 is an
    untouched joint's."""
    if "search" not in entry or v == 0:
        return []
    low, high = entry["search"]
    if not ((low > 0 and v <= low * EDGE) or v >= high / EDGE):
        return []
    u = f" {entry.get('unit')}" if entry.get("unit") else ""
    return [
        f"{entry['key']} {v:.3g}{u}{where} at an edge of its search ({low:g} to {high:g}{u}; within {EDGE - 1:.0%} of "
        "a bound)"
    ]


def ranges(cause: str, estimate: dict, detail: dict, facts: Facts) -> tuple[list[str], list[str]]:
    """(range failures, search-edge failures), in words, of a cause's estimate (and its fit's detail, where a
    declared key lives there: an elastic joint's damping ratio and stiffness) against its declarations
    (`Effect.plausible`). A per-joint list is checked joint by joint."""
    out_range, out_edge = [], []
    for entry in CATALOGUE[cause].plausible:
        value = _value(estimate, detail or {}, entry["key"])
        if value is None:
            continue
        if "most_norm" in entry:
            out_range += _norm(entry, value, facts)
            continue
        if "most_sag" in entry:
            out_range += _sag(entry, value, estimate, facts)
            continue
        per_joint = isinstance(value, list | tuple)
        for j, v in enumerate(value if per_joint else [value]):
            if _finite(v):
                jj = j if per_joint else None
                where = _joint(facts, estimate, jj)
                out_range += _bounds(entry, v, jj, where, facts, _se(entry, detail, jj))
                out_edge += _edge(entry, v, where)
    return out_range, out_edge


def gains_on(before: np.ndarray, after: np.ndarray, var: np.ndarray, floor: float) -> list[int]:
    """The joints (0-based) where a model removes the naming margin of the held-out MSE (`scoring.MARGIN` of it and
    `floor` of the torque variance)."""
    drop = np.asarray(before) - np.asarray(after)
    ok = (drop >= scoring.MARGIN * np.asarray(before)) & (drop >= floor * np.asarray(var)) & (drop > 0)
    return [int(j) for j in np.flatnonzero(ok)]


def paired_scatter(r_before: np.ndarray, r_after: np.ndarray, dt: float) -> np.ndarray:
    """(n,) the standard error [N² m²] of the held-out MSE difference of two models from their residuals (N, n) on the
    same samples (as scored): the mean of d = r_after² − r_before² over blocks of `BLOCK_S`, its standard error the
    blocks' scatter over √(blocks)."""
    d = r_after**2 - r_before**2
    length = max(1, round(BLOCK_S / dt))
    blocks = len(d) // length
    if blocks < 4:
        return np.full(d.shape[1], np.inf)
    means = d[: blocks * length].reshape(blocks, length, -1).mean(axis=1)
    return means.std(axis=0, ddof=1) / np.sqrt(blocks)


def worse_on(before: np.ndarray, after: np.ndarray, var: np.ndarray, floor: float, scatter=None) -> list[int]:
    """The joints (0-based) whose held-out MSE grows beyond its noise (module doc, 3); `scatter` (n,): the standard
    error of the difference (`paired_scatter`; None: not asked)."""
    rise = np.asarray(after) - np.asarray(before)
    bad = (rise >= scoring.MARGIN * np.asarray(before)) & (rise >= floor * np.asarray(var)) & (rise > 0)
    if scatter is not None:
        bad &= rise > SCATTER * np.asarray(scatter)
    return [int(j) for j in np.flatnonzero(bad)]


def forward_worse(before, after, windows: int) -> tuple[bool, float, float]:
    """(worse, Σ_j ln(e_after,j / e_before,j), the bound it must stay below) of the forward simulation's RMS angle
    errors per joint (module doc, 4); joints without a finite error on both sides are left out."""
    b, a = np.asarray(before, dtype=float), np.asarray(after, dtype=float)
    ok = np.isfinite(a) & np.isfinite(b) & (a > 0) & (b > 0)
    if not ok.any():
        return False, 0.0, 0.0
    total = float(np.sum(np.log(a[ok] / b[ok])))
    bound = 2.0 * math.sqrt(int(ok.sum()) / (2.0 * max(windows, 1)))
    return total > bound, total, bound


def judge(
    cause: str,
    estimate: dict,
    detail: dict,
    before_mse,
    after_mse,
    forward: tuple | None,
    facts: Facts,
    scatter=None,
) -> dict:
    """The rule (module doc) on one fitted candidate: its estimate and detail, the held-out MSE per joint of the same
    kind of fit without it (`before_mse`) and with it, the forward simulation's errors (before, after) or None
    (not run), and the standard error of the MSE difference per joint (`paired_scatter`; None: not asked). Returns
    {"plausible", "identifiable", "checks": {range, search_edge, no_joint_worse, forward_simulation}, "reasons": [...],
    "gains_on", "worse_on", "forward": {...}}."""
    in_range, at_edge = ranges(cause, estimate, detail, facts)
    worse = worse_on(before_mse, after_mse, facts.var, facts.floor, scatter)
    gains = gains_on(before_mse, after_mse, facts.var, facts.floor)
    names = facts.joints
    reasons = [*in_range, *at_edge]
    if worse:
        nmse = [(before_mse[j] / facts.var[j], after_mse[j] / facts.var[j]) for j in worse]
        reasons.append(
            "held-out error worse on "
            + ", ".join(f"{names[j]} ({b:.3g} → {a:.3g} nMSE)" for j, (b, a) in zip(worse, nmse))
        )
    fwd = {}
    forward_ok = True
    if forward is not None:
        bad, total, bound = forward_worse(*forward, facts.windows)
        forward_ok = not bad
        fwd = {"before_rad": list(forward[0]), "after_rad": list(forward[1]), "log_ratio_sum": total, "bound": bound}
        if bad:
            reasons.append(
                f"the forward simulation gets worse (Σ ln(after/before) of its angle errors {total:.2f} > {bound:.2f})"
            )
    undetermined = set(facts.undetermined)
    identifiable = not undetermined or not gains or any(j not in undetermined for j in gains)
    if not identifiable:
        reasons.append(
            "it gains only on "
            + ", ".join(names[j] for j in gains)
            + ", whose paths the training motion does not move independently"
        )
    checks = {
        "range": not in_range,
        "search_edge": bool(at_edge),
        "no_joint_worse": not worse,
        "forward_simulation": forward_ok,
    }
    plausible = checks["range"] and not checks["search_edge"] and checks["no_joint_worse"] and forward_ok
    return {
        "plausible": bool(plausible and identifiable),
        "identifiable": bool(identifiable),
        "checks": checks,
        "reasons": reasons,
        "gains_on": gains,
        "worse_on": worse,
        "forward": fwd,
    }


def shortfall(judgement: dict) -> str:
    """The row's `shortfall` of a candidate the rule rejects."""
    checks = judgement["checks"]
    implausible = not (
        checks["range"] and not checks["search_edge"] and checks["no_joint_worse"] and checks["forward_simulation"]
    )
    word = {
        (True, True): "implausible",
        (True, False): "implausible and not identifiable",
        (False, False): "not identifiable",
        (False, True): "implausible",
    }[(implausible, judgement["identifiable"])]
    return f"{word}: " + "; ".join(judgement["reasons"])
