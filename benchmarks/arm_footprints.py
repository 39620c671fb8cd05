"""How large is each hidden cause of the arm confusion tables against what the diagnosis cannot explain anyway?

    .venv/bin/python benchmarks/arm_footprints.py [--seeds 0 700] [--out results/diagnosis/arm_footprints.md]

For the single-cause trials of `benchmarks/confusion_arms.py` (the same arms, draws, trajectories, rate and length)
whose torque is linear in the cause's size: the cause's own torque on its joint, evaluated on the clean trial's
measured motion with the datasheet model, through the diagnosis's torque low-pass (`signals.TORQUE_FILTER_HZ`),
as an RMS over the trial (its footprint) — against the RMS of the datasheet model's residual on that joint of the
clean trial (sensor noise, quantisation and the controller's ripple after the same low-pass), on the samples the
diagnosis compares (`ArmContext.labels`: a joint's samples slower than twice its rest speed, and a coupled drive's,
left out; `signals.demean_runs`). A footprint well
below that residual is a cause no held-out score can credit. Elasticity, delay and payload are not linear in their
size and are left out.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from confusion_arms import ARMS, draws, places, reference

from ident_opt.diagnosis import hidden
from ident_opt.diagnosis.chain.context import ArmContext, link_side
from ident_opt.diagnosis.split import at_rest
from ident_opt.effects import stribeck
from ident_opt.numerics import signals
from ident_opt.numerics.derivatives import lowpass
from ident_opt.problem import load_problem
from ident_opt.report import record
from ident_opt.simulator import simulate_trial

ROOT = Path(__file__).resolve().parents[1]
LINEAR = ("armature", "asymmetric_coulomb", "stribeck", "joint_offset", "torque_scale", "load_friction")


def footprint(cause: str, keys: dict, j: int, ds, arm, pi: np.ndarray) -> np.ndarray:
    """The torque (N,) [N m] `cause` with `keys` adds on joint j along the measured motion of `ds`."""
    q, dq, ddq = ds.q, ds.dq, ds.ddq
    if cause == "armature":
        return keys["inertia"][j] * ddq[:, j]
    if cause == "asymmetric_coulomb":
        half = 0.5 * (keys["positive"][j] - keys["negative"][j])
        return half * (dq[:, j] != 0)  # +half on both directions about the mean level
    if cause == "stribeck":
        return keys["excess"] * stribeck.shape(dq[:, j], keys["velocity"][j])
    if cause == "joint_offset":
        delta = np.asarray(keys["offset"], dtype=float)
        return (arm.predict(pi, q + delta, dq, ddq) - arm.predict(pi, q, dq, ddq))[:, j]
    if cause == "torque_scale":
        return (keys["scale"][j] - 1.0) * arm.predict(pi, q, dq, ddq)[:, j]
    if cause == "load_friction":
        load = arm.predict(link_side(arm, pi), q, dq, ddq)[:, j]
        return keys["coefficient"][j] * np.abs(load) * np.sign(dq[:, j])
    raise ValueError(cause)


def rows_for(arm_name: str, seed: int) -> list[dict]:
    """Every linear single-cause trial of `arm_name` at `seed`: its footprint and the clean residual."""
    problem = load_problem(ARMS[arm_name])
    robot = problem.robot
    n = robot.n_joints
    view = hidden.chain_joints(robot, problem.limits)
    arm, pi = robot.datasheets()[robot.datasheet]
    clean = {}
    for trajectory in ("tud01", "fourier"):
        ds = simulate_trial(
            robot, trajectory=trajectory, duration=40.0, rate_hz=500.0, seed=seed, limits=problem.limits, progress=False
        ).dataset()
        ds = at_rest(ds)  # a resting joint's velocity read as exactly 0, as the diagnosis reads it
        # the samples the diagnosis compares: slow joints and slow coupled drives left out (`ArmContext.labels`)
        dt = float(np.median(np.diff(ds.t)))
        labels = ArmContext(robot, arm, ds, ds, np.ones(n), np.asarray(pi), dt, None, "ols").labels(ds)
        residual = lowpass(ds.t, ds.tau - arm.predict(pi, ds.q, ds.dq, ds.ddq), signals.TORQUE_FILTER_HZ)
        clean[trajectory] = (ds, signals.demean_runs(residual, labels), labels)
    out = []
    for cause in LINEAR:
        for joints in places(cause, n):
            keys = dict(draws(arm_name, problem, (cause,), joints, seed)[cause])
            j = joints[0]
            if cause == "stribeck":
                keys["excess"] = keys["static"][j] - 0.5 * (view[0][j] + view[1][j])
            ds, residual, labels = clean[reference((cause,))]
            f = np.zeros_like(ds.tau)
            f[:, j] = footprint(cause, keys, j, ds, arm, pi)
            f = signals.demean_runs(lowpass(ds.t, f, signals.TORQUE_FILTER_HZ), labels)[:, j]
            edge = int(0.5 / float(np.median(np.diff(ds.t))))  # the filter's run-in at both ends
            seen = labels[edge:-edge, j] < 0  # the samples compared on joint j (the others are 0 once demeaned)
            rms_f = float(np.sqrt(np.mean(f[edge:-edge][seen] ** 2)))
            rms_r = float(np.sqrt(np.mean(residual[edge:-edge, j][seen] ** 2)))
            out.append(
                {
                    "arm": arm_name,
                    "seed": seed,
                    "cause": cause,
                    "joint": robot.joint_names[j],
                    "footprint": rms_f,
                    "residual": rms_r,
                    "ratio": rms_f / rms_r,
                }
            )
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 700])
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "diagnosis" / "arm_footprints.md")
    args = parser.parse_args(argv)
    rows = [r for seed in args.seeds for arm in ARMS for r in rows_for(arm, seed)]
    lines = [
        "# The hidden causes' footprints in the arm confusion tables",
        "",
        f"Regenerate: `python benchmarks/arm_footprints.py --seeds {' '.join(map(str, args.seeds))}`",
        "",
        __doc__.split("\n\n")[2].replace("\n", " "),
        "",
        "| arm | seed | cause | joint | footprint RMS [N m] | clean residual RMS [N m] | ratio |",
        "|---|---|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['arm']} | {r['seed']} | {r['cause']} | {r['joint']} | {r['footprint']:.4g} | {r['residual']:.4g} | "
        f"{r['ratio']:.3g} |"
        for r in rows
    ]
    text = "\n".join(lines) + "\n"
    args.out.write_text(text)
    record(
        args.out.parent,
        args.out.stem,
        "each linear hidden cause's torque on its joint against the clean trial's residual (the arm tables' seeds "
        f"{' and '.join(map(str, args.seeds))})",
        [args.out.name],
    )
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
