"""The verdict beside the causes (`docs/effects.md`, "Verdicts"): `causes` when a cause is named, `none` when nothing
beyond noise remains, `mismatch` when a residual clearly beyond noise remains that no plausible cause explains (the
model or the description is wrong there), `not_identifiable` when the trials cannot tell (too few independent
motions for the joints involved, or no held-out motion distinct from training). `mismatch` and `not_identifiable`
entries may accompany named causes (for other joints).

- **Beyond noise** (`beyond_noise`): a joint's held-out residual as scored (the torque low-passed like the
  derivatives, each rest stretch's level removed: what stiction holds is no model's) whose nMSE is at least
  `RESIDUAL_FLOOR` and at least `NOISE_FACTOR` × white noise at the residual's own level in the band's upper part (its
  median spectral density between half and nine tenths of the band's edge — the low-pass's cut-off, else the Nyquist
  rate — times the band, `noise_nmse`), or a joint at least `RESIDUAL_FLOOR` where a candidate the plausibility rule
  rejected in the last round removed the naming margin of the final model's held-out MSE (structure a cause would
  explain, `conclude`).
- **Mismatch** entries group such joints by the candidates the plausibility rule rejected that gained on them
  (`explained_by_rejected`), with the residual's signature (`signature`) and what to check (`check`).
- **Not identifiable** entries say what the data lack and the `ident-opt excite` command that records it.
"""

from __future__ import annotations

import numpy as np

from ident_opt.diagnosis.identifiability import REPEAT_RAD, Identifiability
from ident_opt.numerics import signals

#: A residual is beyond noise when its power is at least this many times white noise's at its own level in the band's
#: upper part: at least half of it is structure (a white residual reads about 1, the low-pass's roll-off included).
NOISE_FACTOR = 2.0
#: ... and at least this share of the joint's torque variance: below, what is left is what the filters and the stops
#: leave on a correct model (simulated clean planar trials on the `mixed` reference: up to 0.043 on joint 2) and what
#: the real arms' best identifications leave (the Panda's joints 2e-4–0.016, the TX40's joints 1–4 0.003–0.008).
RESIDUAL_FLOOR = 0.05
#: A residual is pose-dependent when the pose functions explain this share of its variance (`evidence.pose_r2`).
POSE_SHARE = 0.5
#: A spectrum peak this prominent [dB] is a signature.
PEAK_DB = 10.0
#: Reversal steps this large against the residual's RMS are a signature.
STEP_SHARE = 1.0
#: A slow residual: this share of its power below `evidence.LOW_BAND_HZ`.
SLOW_SHARE = 0.8

#: What each rejected cause points at when it explained a residual but was not plausible.
CHECK_FOR = {
    "joint_offset": "the encoder zero and the URDF joint frame of {joints}",
    "torque_scale": "the torque channel of {joints} (current-to-torque constant, gear ratio, sign)",
    "elasticity": "a compliance or an oscillation near {joints} (a second sensor: strain gauges, an accelerometer)",
    "load_friction": "the friction model of {joints}'s gear",
    "payload": "a missing body on the last link (a tool, a flange, cables) and the URDF's inertials",
    "armature": "the rotor inertia of {joints}'s drive",
    "delay": "the logs' time stamps (torque and encoders on one clock)",
    "asymmetric_coulomb": "the friction model and the torque channel's offset of {joints}",
    "stribeck": "the friction model of {joints} at low speed",
}


def noise_nmse(residual: np.ndarray, tau: np.ndarray, dt: float, filter_hz: float | None) -> np.ndarray:
    """(n,) the power of white noise at the residual's (N, n) own level in the band's upper part, over the band, as a
    share of the torque's (N, n) variance (module doc)."""
    edge = min(filter_hz, 0.45 / dt) if filter_hz else 0.45 / dt
    out = np.zeros(residual.shape[1])
    for j in range(residual.shape[1]):
        f, p = signals.spectrum(residual[:, j], dt)
        band = (f >= 0.5 * edge) & (f <= 0.9 * edge)
        out[j] = float(np.median(p[band])) * edge if band.any() else 0.0
    return out / np.maximum(np.var(tau, axis=0), np.finfo(float).tiny)


def residual_nmse(residual: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """(n,) the residual's variance as a share of the torque's."""
    return np.var(residual, axis=0) / np.maximum(np.var(tau, axis=0), np.finfo(float).tiny)


def beyond_noise(residual: np.ndarray, noise: np.ndarray, structured: frozenset = frozenset()) -> list[int]:
    """The joints (0-based) whose held-out residual (nMSE, `residual_nmse`) lies beyond noise (module doc): at least
    `RESIDUAL_FLOOR`, and `NOISE_FACTOR` × the white noise's (`noise`) or `structured` (a rejected cause explains part
    of it)."""
    return [
        j
        for j, v in enumerate(residual)
        if np.isfinite(v) and v >= RESIDUAL_FLOOR and (v >= NOISE_FACTOR * float(noise[j]) or j in structured)
    ]


def signature(ev: dict, j: int, band_hz: float | None = None) -> str:
    """The residual's signature on joint j (0-based) from the extended model's held-out evidence (`evidence.
    residual_evidence`): pose-dependent, steps at reversals, a spectrum peak (below `band_hz`, the scored band's
    edge), slow, lagging; "broadband" else."""
    parts = []
    pose = ev["pose_r2"][j]
    if pose is not None and pose >= POSE_SHARE:
        parts.append(f"pose-dependent ({pose:.0%} of its variance follows the joint angles, gravity-like)")
    steps = ev["reversal_steps"][j]
    rms = ev["rms"][j] or 0.0
    up, down = steps.get("negative_to_positive"), steps.get("positive_to_negative")
    big = [s for s in (up, down) if s is not None and np.isfinite(s) and rms > 0 and abs(s) >= STEP_SHARE * rms]
    if big:
        shown = ", ".join(f"{s:+.3g}" for s in (up, down) if s is not None and np.isfinite(s))
        parts.append(f"steps at velocity reversals ({shown} N m, friction-like)")
    peaks = [
        p
        for p in ev["peaks"][j]
        if p.get("prominence_db", 0) >= PEAK_DB and (band_hz is None or p["frequency_hz"] < band_hz)
    ]
    if peaks:
        p = peaks[0]
        parts.append(f"a spectrum peak at {p['frequency_hz']:.3g} Hz")
    low = ev["low_band_fraction"][j]
    if low is not None and low >= SLOW_SHARE:
        parts.append(f"slow ({low:.0%} of its power below 0.6 Hz: a drift or a slow load)")
    lag = ev["lag_s"][j]
    if lag is not None and np.isfinite(lag) and abs(lag) >= 0.002:
        word = "lags" if lag > 0 else "leads"
        parts.append(f"the measured torque {word} the prediction by {1e3 * abs(lag):.3g} ms")
    return "; ".join(parts) if parts else "broadband (no pose, reversal, peak or lag signature)"


def _check(joints: list[str], rejected: list[str], sig: str) -> str:
    """What to check for a mismatch on `joints` given the causes rejected there and the residual's signature."""
    where = ", ".join(joints)
    out = [CHECK_FOR[c].format(joints=where) for c in rejected if c in CHECK_FOR]
    if "pose-dependent" in sig and not any("frame" in o for o in out):
        out.append(
            f"the description's frames and inertials (the URDF's or the datasheet's) of {where} and the links beyond "
            "(a missing body: a tool, cables)"
        )
    if "reversals" in sig and "joint_offset" not in rejected:
        out.append(f"the friction model and the torque channel's offset of {where}")
    if "spectrum peak" in sig and "elasticity" not in rejected:
        out.append(f"a mode or a controller oscillation on {where}")
    if not out:
        out.append(f"the torque channel of {where} and the description's frames and inertials of its links")
    return "; ".join(dict.fromkeys(out))


def excite(problem: str | None, out: str, extra: str = "") -> str:
    """The `ident-opt excite` command that records a trial (`problem`: its file, else a placeholder)."""
    return f"ident-opt excite --problem {problem or '<problem.toml>'} --out {out} --duration 60{extra}"


def _implausible(c: dict) -> bool:
    """Whether a rejected candidate failed a plausibility check (not only identifiability)."""
    checks = c.get("checks", {})
    return (
        not checks.get("range", True)
        or checks.get("search_edge", False)
        or not checks.get("no_joint_worse", True)
        or not checks.get("forward_simulation", True)
    )


def conclude(
    named: list[dict],
    rejected: list[dict],
    ident: Identifiability,
    nmse_after: list[float],
    noise: tuple[np.ndarray, np.ndarray],
    ev_after: dict,
    joints: tuple[str, ...],
    problem: str | None = None,
    band_hz: float | None = None,
    final_round: int | None = None,
) -> tuple[str, list[dict], list[dict], list[int]]:
    """(verdict, mismatch entries, not_identifiable entries, the joints beyond noise (0-based)) from the named
    causes, the candidates the rule rejected (each with `cause`, `gains_on`, `checks`, `identifiable`), what the data
    can tell, the extended model's held-out nMSE per joint (as the entries report it), (its residual's nMSE, the white
    noise's) per joint (`residual_nmse`, `noise_nmse`) and its held-out evidence (`final_round`: the round the loop
    stopped in, whose rejected candidates gained against the final model). A joint beyond noise goes to a
    `mismatch` entry when a candidate failing a plausibility check gained on it, or when the motion determines it
    (nothing plausible explains it); a joint the motion leaves undetermined otherwise goes to the `not_identifiable`
    entry of the missing motions."""
    last = max((c.get("round", 0) for c in rejected), default=0)
    structured = {j for c in rejected if _implausible(c) and c.get("round") == last for j in c.get("gains_on", ())}
    left = beyond_noise(*noise, frozenset(structured if last == final_round else ()))
    undetermined = set(ident.undetermined_joints) if not ident.full_rank else set()
    not_identifiable = _not_identifiable(rejected, ident, left, undetermined, ev_after, joints, problem, band_hz)
    mismatch = _mismatch(rejected, left, undetermined, nmse_after, ev_after, joints, band_hz)
    if named:
        verdict = "causes"
    elif left:
        blind = any(j in undetermined for j in left) or not ident.held_out_distinct
        verdict = "not_identifiable" if blind else "mismatch"
    else:
        verdict = "none"
    return verdict, mismatch, not_identifiable, left


def _not_identifiable(
    rejected: list[dict],
    ident: Identifiability,
    left: list[int],
    undetermined: set[int],
    ev_after: dict,
    joints: tuple[str, ...],
    problem: str | None,
    band_hz: float | None,
) -> list[dict]:
    """The `not_identifiable` entries (`conclude`): the joints the motion leaves undetermined (with the residual
    beyond noise on them) and a held-out part that repeats the training motion, each with the command recording what
    is missing."""
    not_identifiable = []
    if undetermined:
        unclear = sorted({c["cause"] for c in rejected if not c.get("identifiable", True)})
        blind = [j for j in left if j in undetermined]
        entry = {
            "what": f"the training motion holds {ident.independent_motions} independent motions for "
            f"{ident.n_joints} joints ({'; '.join(ident.undetermined()[: max(1, len(ident.copies))])}): a cause on "
            "those joints cannot be told from the same cause on the joints they copy, nor from the rigid parameters "
            "the motion leaves free",
            "joints": [joints[j] for j in sorted(undetermined)],
            "rejected": unclear,
            "record": excite(problem, "excite_d.csv", " --criterion d")
            + " (a D-optimal excitation moves every joint on its own; log it and diagnose again)",
        }
        if blind:
            entry["residual_beyond_noise"] = [joints[j] for j in blind]
            entry["signature"] = "; ".join(f"{joints[j]}: {signature(ev_after, j, band_hz)}" for j in blind)
        not_identifiable.append(entry)
    if not ident.held_out_distinct:
        not_identifiable.append(
            {
                "what": f"the held-out part ({ident.scored_on}) repeats the training motion (median distance "
                f"{ident.held_out_distance_rad:.3g} rad, within {REPEAT_RAD:g}) and no other trial is distinct: "
                "its gains are measured on the training motion and are unverified",
                "joints": list(joints),
                "rejected": [],
                "record": excite(problem, "distinct.csv", " --seed 1")
                + " (a motion of its own; log it and give it as --test-data)",
            }
        )
    return not_identifiable


def _mismatch(
    rejected: list[dict],
    left: list[int],
    undetermined: set[int],
    nmse_after: list[float],
    ev_after: dict,
    joints: tuple[str, ...],
    band_hz: float | None,
) -> list[dict]:
    """The `mismatch` entries (`conclude`): the joints beyond noise grouped by the implausible candidates that gained on
    them, with the residual's signature and what to check; undetermined joints no candidate explains are left to
    `not_identifiable`."""
    implausible = [c for c in rejected if _implausible(c)]
    by_causes: dict[tuple, list[int]] = {}
    for j in left:
        causes = tuple(sorted({c["cause"] for c in implausible if j in c.get("gains_on", ())}))
        if j in undetermined and not causes:
            continue  # what the data cannot tell is said under not_identifiable
        by_causes.setdefault(causes, []).append(j)
    mismatch = []
    for causes, js in by_causes.items():
        names = [joints[j] for j in js]
        sig = "; ".join(f"{joints[j]}: {signature(ev_after, j, band_hz)}" for j in js)
        mismatch.append(
            {
                "joints": [j + 1 for j in js],
                "joint_names": names,
                "nmse_after": [nmse_after[j] for j in js],
                "signature": sig,
                "explained_by_rejected": list(causes),
                "check": _check(names, list(causes), sig),
            }
        )
    return mismatch
