"""Contacts and collisions (`ident-opt detect`, `docs/contacts.md`): how well the external-torque observer with
thresholds calibrated on collision-free data finds simulated pushes, and how often it cries wolf on real logs.

    python benchmarks/contacts.py [--arms planar tx40 kuka] [--duration 60] [--real] [--out results]

Simulated (per arm: the planar two-link arm of problems/tudor_sim.toml with its calibrated realism terms, the 6-joint
Stäubli TX40 and the 7-joint KUKA LWR4+ as their nominal models with torque noise): two contact-free trials (seeds 1,
2) train the recommended fit and calibrate the thresholds; a third (seed 3) counts false alarms per minute; then per
pushed joint and push size (a share of that joint's 95th-percentile |τ| on the contact-free trial) one trial with a
0.5 s push every 6 s (`contact:...,every=6`), whatever the arm does then (moving or resting). A push is detected
when an alarm starts within it or 0.3 s after it ends; its delay is the alarm's start minus the push's. Alarms that
start outside every push (and its settling) are false alarms.

Real (`--real`): for every shipped problem, `detect` with all of its trials as calibration trials (each scored with
thresholds calibrated on the others; a single trial's halves stand for two), the fit on its training trials.

Writes OUT/contacts.md and OUT/contacts.json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import ident_opt as iopt
from ident_opt.contact.detect import detect
from ident_opt.simulator.trial import simulate_trial

ROOT = Path(__file__).resolve().parents[1]
ARMS = {
    "planar": ("tudor_sim.toml", (1, 2)),
    "tx40": ("staubli_tx40.toml", (2, 3)),
    "kuka": ("kuka_lwr4.toml", (2, 4)),
}
SHARES = (0.05, 0.1, 0.2, 0.4, 0.7, 1.0, 1.5)
PERIOD, LENGTH, FIRST, GRACE = 6.0, 0.5, 3.0, 0.3
REAL = ("tudor_2dof.toml", "kuka_lwr4.toml", "franka_panda.toml", "staubli_tx40.toml", "dfki_c0.toml", "dfki_a0.toml")


def _trial(problem, effects, seed, duration):
    sim = simulate_trial(
        problem.robot, trajectory="tud01", duration=duration, seed=seed, effects=effects, progress=False
    )
    return sim.dataset()


def score(trial, windows, settling: float) -> dict:
    """Per push: detected, delay [s], the joint's motion then; the false alarms outside every push."""
    found, pushes = trial.alarms, []
    for a, b in windows:
        hit = [x for x in found if a - 1e-9 <= x.start <= b + GRACE]
        k = int(np.searchsorted(trial.t, a))
        pushes.append({"start": a, "detected": bool(hit), "delay": hit[0].start - a if hit else None, "k": k})
    false = [x for x in found if not any(a - 1e-9 <= x.start <= b + settling for a, b in windows)]
    return {"pushes": pushes, "false_alarms": len(false)}


def _push(joint: int, size: float) -> str:
    return f"contact:joint={joint},torque={size:.6g},start={FIRST},duration={LENGTH},every={PERIOD}"


def _row(base, trial, watched, joint: int, size: float, share: float, windows) -> dict:
    """One pushed trial's scores (`score`), with how many pushes found the joint moving."""
    scored = score(watched, windows, base.thresholds.settling)
    moving = [abs(trial.dq[p["k"], joint - 1]) > base.thresholds.rest_speed[joint - 1] for p in scored["pushes"]]
    delays = [p["delay"] for p in scored["pushes"] if p["detected"]]
    return {
        "joint": joint,
        "share": share,
        "torque": float(size),
        "pushes": len(windows),
        "detected": int(sum(p["detected"] for p in scored["pushes"])),
        "detected_moving": int(sum(bool(p["detected"] and m) for p, m in zip(scored["pushes"], moving))),
        "moving": int(sum(moving)),
        "delay_median": float(np.median(delays)) if delays else None,
        "delay_max": float(np.max(delays)) if delays else None,
        "false_alarms": scored["false_alarms"],
    }


def arm_study(name: str, duration: float) -> dict:
    path, joints = ARMS[name]
    problem = iopt.load_problem(ROOT / "problems" / path)
    effects = list(problem.simulate.effects) if problem.simulate is not None else []
    started = time.perf_counter()
    training = [_trial(problem, effects, s, duration) for s in (1, 2)]
    free = _trial(problem, effects, 3, duration)
    reference = np.quantile(np.abs(free.tau), 0.95, axis=0)
    windows = [(float(s), float(s) + LENGTH) for s in np.arange(FIRST, duration - 1.0, PERIOD)]
    cases = [(joint, share) for joint in joints for share in SHARES]
    pushed = [
        _trial(problem, [*effects, _push(joint, share * reference[joint - 1])], 4 + joint, duration)
        for joint, share in cases
    ]
    base = detect(problem, training, training, [free, *pushed])  # one fit, one calibration, every trial watched
    rows = [
        _row(base, trial, watched, joint, share * reference[joint - 1], share, windows)
        for (joint, share), trial, watched in zip(cases, pushed, base.trials[1:])
    ]
    minutes = (free.t[-1] - free.t[0]) / 60
    return {
        "arm": name,
        "problem": f"problems/{path}",
        "joints": problem.robot.n_joints,
        "estimator": base.estimator,
        "thresholds": base.thresholds.as_json(),
        "persistence": base.thresholds.persistence,
        "free_false_alarms_per_minute": len(base.trials[0].alarms) / minutes,
        "calibration": base.calibration,
        "reference_torque": reference.tolist(),
        "rows": rows,
        "seconds": time.perf_counter() - started,
    }


def real_study(path: str) -> dict:
    problem = iopt.load_problem(ROOT / "problems" / path)
    training, testing = iopt.load_trials(problem)
    found = detect(problem, training, [*training, *testing], [])
    return {
        "problem": f"problems/{path}",
        "estimator": found.estimator,
        "calibration": found.calibration,
        "thresholds": found.thresholds.as_json(),
        "persistence": found.thresholds.persistence,
    }


def markdown(arms: list[dict], real: list[dict], command: str) -> str:
    lines = ["# Contacts and collisions: the external-torque observer measured", "", f"Made by `{command}`.", ""]
    lines += [
        "Simulated: per arm two contact-free 60 s trials (seeds 1, 2) train the recommended fit and calibrate the "
        "thresholds (margin 1.5); a third (seed 3) counts false alarms. Each pushed trial has a 0.5 s push every 6 s "
        "from 3 s (`contact:joint=J,torque=T,start=3,duration=0.5,every=6`), of a size given as a share of the "
        "joint's 95th-percentile |τ| on the contact-free trial, whatever the arm does then ('of them moving': the "
        "pushes that found the joint faster than its rest speed). A push counts as detected when an alarm starts "
        "within it or 0.3 s after it; the delay is from the push's start (its 0.05 s ramp included). A false alarm "
        "starts outside every push and its settling. The planar arm carries its calibrated realism terms (a flexible "
        "link, stiction, a slow drift of 0.7 N m std on joint 1: an external torque the observer sees too); the "
        "TX40 and the KUKA are their nominal models with torque noise.",
        "",
        "Real logs: each trial of a robot scored at thresholds calibrated on the other trials of the same robot (the "
        "fit on the problem's training trials); a robot with one recording is split in two halves in time, each "
        "scored with the other's thresholds (short halves make large per-minute rates from one or two alarms).",
        "",
    ]
    for a in arms:
        lines += [f"## {a['arm']} ({a['joints']} joints, {a['problem']}; fit: {a['estimator']})", ""]
        lines.append(
            f"False alarms on a contact-free trial: {a['free_false_alarms_per_minute']:.2f} per minute; calibration "
            "trials held out: "
            + ", ".join(f"{c['false_alarms_per_minute']:.2f}" for c in a["calibration"])
            + " per minute."
        )
        th = ", ".join(f"j{t['joint']} {t['moving']:.3g}/{t['resting']:.3g}" for t in a["thresholds"])
        lines += [f"Thresholds moving/resting [N m]: {th}; persistence {a['persistence']} samples.", ""]
        lines.append(
            "| joint | push [N m] | share of p95 abs tau | detected | of them moving | delay median / max [s] "
            "| false alarms |"
        )
        lines.append("|---|---|---|---|---|---|---|")
        for r in a["rows"]:
            delay = "–" if r["delay_median"] is None else f"{r['delay_median']:.3f} / {r['delay_max']:.3f}"
            lines.append(
                f"| {r['joint']} | {r['torque']:.3g} | {r['share']:.0%} | {r['detected']}/{r['pushes']} | "
                f"{r['detected_moving']}/{r['moving']} | {delay} | {r['false_alarms']} |"
            )
        for joint in sorted({r["joint"] for r in a["rows"]}):
            own = [r for r in a["rows"] if r["joint"] == joint]
            anyone = [r["torque"] for r in own if r["detected"]]
            every = [r["torque"] for r in own if r["detected"] == r["pushes"]]
            lines.append(
                f"\nJoint {joint}: smallest push detected at all {min(anyone) if anyone else float('nan'):.3g} N m; "
                f"every push detected from {min(every) if every else float('nan'):.3g} N m."
            )
        lines.append("")
    if real:
        lines += ["## Real logs (no contact): false alarms per minute, each trial at thresholds from the others", ""]
        lines += ["| problem | fit | trial | duration [s] | false alarms | per minute |", "|---|---|---|---|---|---|"]
        for r in real:
            for c in r["calibration"]:
                lines.append(
                    f"| {r['problem']} | {r['estimator']} | {c['source']} | {c['duration_s']:.1f} | "
                    f"{c['false_alarms']} | {c['false_alarms_per_minute']:.2f} |"
                )
        lines += ["", "Pooled per robot (all its trials' false alarms over their total duration):", ""]
        for r in real:
            count = sum(c["false_alarms"] for c in r["calibration"])
            minutes = sum(c["duration_s"] for c in r["calibration"]) / 60
            lines.append(f"- {r['problem']}: {count} in {minutes:.2f} min, {count / minutes:.2f} per minute")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arms", nargs="*", default=list(ARMS), choices=list(ARMS))
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--real", action="store_true", help="also the shipped real logs")
    parser.add_argument("--out", default=str(ROOT / "results"))
    args = parser.parse_args()
    arms = []
    for name in args.arms:
        arms.append(arm_study(name, args.duration))
        print(f"{name}: done in {arms[-1]['seconds']:.0f} s", flush=True)
    real = [real_study(p) for p in REAL] if args.real else []
    command = "python benchmarks/contacts.py " + " ".join(
        [f"--arms {' '.join(args.arms)}", f"--duration {args.duration:g}", *(["--real"] if args.real else [])]
    )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "contacts.md").write_text(markdown(arms, real, command))
    (out / "contacts.json").write_text(json.dumps({"arms": arms, "real": real}, indent=1, default=float) + "\n")
    print(markdown(arms, real, command))


if __name__ == "__main__":
    main()
