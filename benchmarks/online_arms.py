"""Online identification on the real n-joint arms (`make online-arms`, results/online_arms.md):

    python benchmarks/online_arms.py [--problem P ...] [--out DIR]

For each problem (default: KUKA LWR4+, Franka Panda, Stäubli TX40 with their recordings), on its first trial split
in time as `ident-opt online` splits it:

1. the replay (`online_replay.replay`): PBR's base parameters against a from-scratch re-solve at checked steps (and
   against `scipy.optimize.lsq_linear` on the stacked rows), the Python update's speed, the 95 % interval coverage of
   PBR + GMR, and how far PBR's exact sign-bounded parameters are from the consistent fit re-solved at its cadence;
2. the generated `pi_update` (`online_codegen.verify`): C against the Python path, C's time per update;
3. the stream on t, q and currents only: the trial's online part (KUKA: its held-out recording) streamed as
   t, q1 … qn, i1 … in (currents = τ / (k_t N), with k_t = `TORQUE_CONSTANT` and N = `GEAR_RATIO` written into a copy of
   the problem for every joint), derivatives estimated causally, through the compiled kernel; the final parameters
   against the batch bounded least squares (`FactorBoundedLS`) on the training rows plus the streamed rows with the
   loader's zero-phase derivatives (speeds below `derivatives.REST` as rest in both), in standard errors.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from ident_opt.adaptation.replay import _standard_errors, replay
from ident_opt.adaptation.start import serving_identifier
from ident_opt.adaptation.stream import StreamOptions, serve
from ident_opt.data.dataset import chronological_split
from ident_opt.data.loader import load_dataset
from ident_opt.fitting.bounded import FactorBoundedLS
from ident_opt.fitting.recommend import choose
from ident_opt.numerics.derivatives import REST
from ident_opt.problem import load_problem
from ident_opt.report import record
from ident_opt.shipping.pi_update import verify

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = ("kuka_lwr4", "franka_panda", "staubli_tx40")
#: The drives written into the problem's copy for the current stream [N m/A, —]: i = τ / (k_t N).
TORQUE_CONSTANT, GEAR_RATIO = 0.1, 100.0
#: A cadence of the consistent re-solve that gives a few re-solves on these short replays.
EVERY = 250


def _with_drives(problem_path: Path, folder: Path) -> Path:
    """A copy of the problem with `TORQUE_CONSTANT`, `GEAR_RATIO` for every joint (paths made absolute)."""
    problem = load_problem(problem_path)
    text = problem_path.read_text(encoding="utf-8").replace('"../', f'"{problem_path.parent.parent}/')
    drive = f"torque_constant = {TORQUE_CONSTANT}\ngear_ratio = {GEAR_RATIO}\n"
    tables = ""
    for name in problem.robot.joint_names:
        header = f"[robot.{name}]\n"
        if header in text:  # the joint has a table of its own already (the TX40's joint 6): the drive goes into it
            text = text.replace(header, header + drive, 1)
        else:
            tables += f"\n{header}{drive}"
    head, sep, tail = text.partition("\n[data]")
    path = folder / problem_path.name
    path.write_text(head + tables + sep + tail, encoding="utf-8")
    return path


def stream_figures(problem_path: Path, folder: Path) -> dict:
    """Figure 3 (module doc)."""
    problem = load_problem(_with_drives(problem_path, folder))
    trials = [load_dataset(p, problem.data, problem.robot) for p in problem.data.trials]
    first = trials[0]
    tr, te = chronological_split(first.n, problem.split.train_fraction)
    train = first.subset(tr)
    held = problem.data.testing[0] if problem.data.testing else problem.data.trials[0]
    raw = pd.read_csv(held)
    if not problem.data.testing:  # one recording: stream its online part
        raw = raw.iloc[te].reset_index(drop=True)
    n = problem.robot.n_joints
    k = TORQUE_CONSTANT * GEAR_RATIO
    frame = pd.DataFrame({"t": raw["t"]})
    for j in range(1, n + 1):
        frame[f"q{j}"] = raw[f"q{j}"]
    for j in range(1, n + 1):
        frame[f"i{j}"] = raw[f"tau{j}"] / k
    t0 = time.perf_counter()
    start, ident = serving_identifier("pbr", problem, train)
    ready = time.perf_counter()
    options = StreamOptions.for_problem(problem, train)
    out, err = io.StringIO(), io.StringIO()
    text = frame.to_csv(index=False, float_format="%.17g")
    served = time.perf_counter()
    final = serve(ident, start.names, io.StringIO(text), out, err, snapshot_every=0, options=options)["final"]
    seconds = time.perf_counter() - served
    # The batch reference: the loader's zero-phase derivatives on the same t, q, τ.
    path = folder / "streamed.csv"
    pd.DataFrame(
        {
            **{c: frame[c] for c in frame if c.startswith(("t", "q"))},
            **{f"tau{j}": raw[f"tau{j}"] for j in range(1, n + 1)},
        }
    ).to_csv(path, index=False, float_format="%.17g")
    # Read as the stream reads its samples: its own rest rule (REST, below), not the loader's (`rest_velocity`).
    spec = dataclasses.replace(problem.data, derivative_cutoff_hz=options.cutoff_hz, rest_velocity="as_read")
    streamed = load_dataset(path, spec, problem.robot)
    dq = np.where(np.abs(streamed.dq) < REST, 0.0, streamed.dq)
    D = np.concatenate([start.design(train.q, train.dq, train.ddq), start.design(streamed.q, dq, streamed.ddq)])
    tau = np.concatenate([train.tau, streamed.tau])
    batch = FactorBoundedLS(start.estimator.bounds, D, tau).solve().pi
    online = np.array([final["parameters"][name] for name in start.names])
    se = _standard_errors(D, tau, batch)
    z = np.abs(online - batch) / se
    return {
        "streamed": str(Path(held).name),
        "samples": len(frame),
        "updates": final["updates"],
        "outliers": final["outliers"],
        "skipped": final["skipped"],
        "derivatives": final["derivatives"],
        "start_seconds": ready - t0,
        "stream_seconds": seconds,
        "samples_per_second": len(frame) / seconds,
        "compiled": ident._kernel is not None,
        "median_z": float(np.median(z)),
        "max_z": float(z.max()),
        "share_within_1_se": float(np.mean(z <= 1.0)),
        "parameters": len(start.names),
    }


def arm_figures(name: str, folder: Path) -> dict:
    """Figures 1–3 for one shipped problem."""
    path = ROOT / "problems" / f"{name}.toml"
    problem = load_problem(path)
    trial = load_dataset(problem.data.trials[0], problem.data, problem.robot)
    tr, te = chronological_split(trial.n, problem.split.train_fraction)
    choice = choose(problem, [trial.subset(tr)], model=problem.robot.model(()))  # as `ident-opt online` starts cpbr
    r = replay(
        problem,
        trial.subset(tr),
        trial.subset(te),
        checks=5,
        components=None,
        progress=False,
        every=EVERY,
        keys=("pbr", "cpbr"),
        choice=choice,
    )
    rate = r.n / r.solve_seconds["pbr"]
    with tempfile.TemporaryDirectory(prefix="ident_opt_arms_") as tmp:
        c = verify(problem, trial, Path(tmp), repeats=5)
        stream = stream_figures(path, Path(tmp))
    for key in ("final_python", "final_c_example", "files"):
        c.pop(key, None)
    return {
        "problem": problem.name,
        "joints": problem.robot.n_joints,
        "base_parameters": len(r.starts["pbr"].names),
        "cpbr_estimator": choice.estimator,
        "cpbr_estimator_why": choice.why,
        "offline_samples": int(r.train.n),
        "online_samples": int(r.n),
        "batch_check": r.batch_check,
        "python_updates_per_second": rate,
        "coverage_pbr_gmr": r.coverage("online")["pbr+gmr"],
        "nmse": {
            k: r.metrics(w)["nmse"][m]
            for k, w, m in (
                ("pbr_online", "online", "pbr"),
                ("pbr_frozen", "frozen", "pbr"),
                ("pbr_gmr_online", "online", "pbr+gmr"),
                ("cpbr_online", "online", "cpbr"),
            )
        },
        "consistency": r.consistency,
        "pi_update": c,
        "stream": stream,
    }


def markdown(rows: list[dict]) -> str:
    """online_arms.md."""
    lines = [
        "# Online identification on the n-joint arms (`make online-arms`)",
        "",
        (__doc__ or "").split("\n\n", 2)[2].strip(),
        "",
        "| arm | joints | base parameters | offline / online samples | batch check (max relative) | vs lsq_linear | "
        "Python updates/s | C µs per update (regressor) | its CPU µs | C vs Python (size or SE) | coverage PBR+GMR |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        c, b = r["pi_update"], r["batch_check"]
        lines.append(
            f"| {r['problem']} | {r['joints']} | {r['base_parameters']} | {r['offline_samples']} / "
            f"{r['online_samples']} | {b['max_relative_difference']:.1e} | {b['pbr_vs_lsq_linear']:.1e} | "
            f"{r['python_updates_per_second']:.0f} | {c['c_ns_per_update'] / 1e3:.2f} "
            f"({c['c_ns_regressor'] / 1e3:.2f}) | {c['c_cpu_ns_per_update'] / 1e3:.2f} | "
            f"{c['max_difference_vs_size_or_se']:.1e} | "
            f"{' / '.join(f'{v:.2f}' for v in r['coverage_pbr_gmr'])} |"
        )
    lines += [
        "",
        "C vs Python: the largest difference of a parameter after any step, against its size or, nearer 0, its "
        "standard error (relative to the size alone, and of the torques):",
        "",
    ]
    for r in rows:
        c = r["pi_update"]
        lines.append(
            f"- {r['problem']}: {c['max_relative_difference']:.1e} relative, torques "
            f"{c['max_torque_relative_difference']:.1e}; {c['failures']} failures."
        )
    lines += ["", f"## Consistency online (pbr against the consistent fit re-solved every {EVERY} samples)", ""]
    for r in rows:
        c = r["consistency"]
        if not c:
            continue
        last = c["at_re_solves"][-1] if c["at_re_solves"] else None
        lines.append(
            f"- {r['problem']} (cpbr: the {r['cpbr_estimator']} fit, recommended because {r['cpbr_estimator_why']}): "
            f"{len(c['sign_bounds'])} sign bounds held exactly (least slack "
            f"{c['sign_bound_least_slack']:.3g}); {c['re_solves']} re-solves in {c['re_solve_seconds']:.1f} s, least "
            f"pseudo-inertia eigenvalue {c['least_lmi_eigenvalue']:.3g} kg·m²"
            + (
                f"; at the last re-solve ({last['samples_seen']} samples) pbr's torques differ from the consistent "
                f"fit's by {' / '.join(f'{v:.3g}' for v in last['torque_rms_difference'])} N·m RMS "
                f"({' / '.join(f'{v:.2f}' for v in last['relative_to_residual'])} of its residual RMS), parameters "
                f"median {last['parameter_difference_in_se']['median']:.2g} SE; cpbr as held until then differs "
                f"from the re-solve by {' / '.join(f'{v:.3g}' for v in last['held_torque_rms_difference'])} N·m RMS "
                f"({' / '.join(f'{v:.2f}' for v in last['held_relative_to_residual'])} of the residual RMS)"
                if last
                else ""
            )
            + "."
        )
    lines += ["", "## The stream on t, q and currents only", ""]
    lines += [
        "| arm | streamed | samples | updates | delay [samples] | lost | samples/s | start [s] | |Δ|/SE median, max | "
        "within 1 SE |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        s = r["stream"]
        lines.append(
            f"| {r['problem']} | {s['streamed']} | {s['samples']} | {s['updates']} | "
            f"{s['derivatives']['delay_samples']} | {s['derivatives']['lost']} | {s['samples_per_second']:.0f} | "
            f"{s['start_seconds']:.1f} | {s['median_z']:.2f}, {s['max_z']:.2f} | {s['share_within_1_se']:.0%} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--problem", action="append", help="a shipped problem's name (default: the three arms)")
    ap.add_argument("--out", default=str(ROOT / "results"))
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="ident_opt_arms_") as tmp:
        rows = [arm_figures(name, Path(tmp)) for name in (args.problem or PROBLEMS)]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "online_arms.json").write_text(json.dumps(rows, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    text = markdown(rows)
    (out / "online_arms.md").write_text(text, encoding="utf-8")
    record(
        out,
        "online_arms",
        "online identification on the n-joint arms: batch re-solves, the generated update, the t/q/i stream",
        ("online_arms.md", "online_arms.json"),
    )
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
