"""The diagnosis on plants and loggers it was not tuned on: confusion tables, tuned and unseen seeds apart.

    PYTHONPATH=. .venv/bin/python benchmarks/unseen_plants.py --set tuning [--jobs 2] [--out-dir results/diagnosis]
    PYTHONPATH=. .venv/bin/python benchmarks/unseen_plants.py --set unseen|fresh

The test matrix (issue 30), written before any rule was changed. Every trial is 80 s at 100 Hz from the built-in
closed loop (the tudor_2dof robot), with one or two hidden causes, and is handed to `diagnose` the way another
logger would (`simulator.unseen.PIPELINES`, one per trial in turn): derivatives from a cubic Savitzky–Golay filter
of 11, 15 or 21 samples, or no derivatives (the loader estimates them at its "auto" cut-off), or currents and no
derivatives. `diagnose` reads the torque filter from the trial as the CLI does with the default
`derivative_cutoff_hz = "auto"`. The plants:

- `catalogue`: every catalogue cause alone (and a clean trial) in the project's own plant, each under another
  logger; two pairs the issue names (a payload with a delay; a catalogue elastic joint with an offset);
- `beam`: a flexible link with distributed mass and three modes (`simulator.unseen.Beam`, assumed modes, first
  mode 2.5–7 Hz, damping 0.5–1.5 % on every mode), alone and beside asymmetric Coulomb friction;
- `nonlinear joint`: an elastic joint whose spring hardens (tangent 1.5–3 × k at the largest gravity deflection)
  or has a play (0.1–0.3 × that deflection), judged against the frequency of the mean tangent stiffness.

Seed sets, fixed before the first run: `tuning` = 0, 1 (looked at while changing rules); `unseen` = 700, 701
(run once, at the end; looked at since); `fresh` = 702, 703 (added once the unseen set had been looked at; run once,
after the elastic column gained gravity's sag). Magnitudes are drawn from `hidden.draw` on a stream of this
benchmark's own.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import replace
from functools import partial
from pathlib import Path

import numpy as np

from ident_opt.report.confusion import chain, confusion_matrix, rounded, share, worst

ROOT = Path(__file__).resolve().parents[1]
SEEDS = {"tuning": (0, 1), "unseen": (700, 701), "fresh": (702, 703)}

#: (label, plant, hidden catalogue causes, special mechanism or None)
CASES = (
    ("none", "catalogue", (), None),
    ("armature", "catalogue", ("armature",), None),
    ("asymmetric_coulomb", "catalogue", ("asymmetric_coulomb",), None),
    ("stribeck", "catalogue", ("stribeck",), None),
    ("elasticity", "catalogue", ("elasticity",), None),
    ("payload", "catalogue", ("payload",), None),
    ("delay", "catalogue", ("delay",), None),
    ("joint_offset", "catalogue", ("joint_offset",), None),
    ("torque_scale", "catalogue", ("torque_scale",), None),
    ("load_friction", "catalogue", ("load_friction",), None),
    ("payload + delay", "catalogue", ("payload", "delay"), None),
    ("elasticity + joint_offset", "catalogue", ("elasticity", "joint_offset"), None),
    ("beam", "beam", ("elasticity",), "beam"),
    ("beam + asymmetric_coulomb", "beam", ("elasticity", "asymmetric_coulomb"), "beam"),
    ("hardening joint", "nonlinear joint", ("elasticity",), "hardening"),
    ("backlash joint", "nonlinear joint", ("elasticity",), "backlash"),
)


def hidden_effects(causes, special, rng, robot) -> tuple[dict, object]:
    """The hidden effects' keys and the mechanism (a function of the truth) for one case."""
    from ident_opt.diagnosis import hidden

    effects = {c: hidden.draw(c, rng, robot) for c in causes}
    if special is None:
        return effects, None
    joint = int(rng.integers(1, 3))
    if special == "beam":
        f, zeta = rng.uniform(2.5, 7.0), rng.uniform(0.005, 0.015)
        effects["elasticity"] = {"joint": joint, "frequency_hz": f, "damping": zeta, "kind": "link"}
        return effects, partial(_beam, j=joint - 1, f=f, zeta=zeta)
    f, zeta = rng.uniform(2.0, 8.0), rng.uniform(0.01, 0.05)
    size = rng.uniform(0.5, 2.0) if special == "hardening" else rng.uniform(0.1, 0.3)
    effects["elasticity"] = {"joint": joint, "frequency_hz": f, "damping": zeta, "kind": "joint"}
    return effects, partial(_nonlinear, shape=special, size=size)


def _beam(truth, j, f, zeta):
    from ident_opt.simulator import unseen

    return unseen.beam(truth, j, f, zeta, 3)


def _nonlinear(truth, shape, size):
    from ident_opt.simulator import unseen

    return unseen.nonlinear_joint(truth, shape, size)


def trial(job: tuple[int, int]) -> dict:
    """Simulate case `job[0]` on seed `job[1]`, hand it over through its logger, diagnose it, judge it."""
    from ident_opt.diagnosis import diagnose_trial, hidden, rigid_choice
    from ident_opt.effects import CATALOGUE
    from ident_opt.problem import load_problem
    from ident_opt.simulator import simulate_trial, unseen

    index, seed = job
    label, plant, causes, special = CASES[index]
    problem = load_problem(ROOT / "problems" / "tudor_2dof.toml")
    problem = replace(problem, data=replace(problem.data, derivative_cutoff_hz="auto"))  # as a logger's file
    robot = problem.robot
    rng = np.random.default_rng([seed, index, 30])
    effects, mechanism = hidden_effects(causes, special, rng, robot)
    refs = {CATALOGUE[c].reference for c in causes} or {"tud01"}
    trajectory = refs.pop() if len(refs) == 1 else "mixed"
    pipeline = unseen.PIPELINES[(index + seed) % len(unseen.PIPELINES)]
    t0 = time.perf_counter()
    sim = simulate_trial(
        robot, trajectory=trajectory, duration=80.0, seed=seed, effects=effects, progress=False, mechanism=mechanism
    )
    seconds_sim = time.perf_counter() - t0
    truth = sim.truth["effects"]
    if special in ("hardening", "backlash"):
        el = truth["elasticity"]  # judged at the spring's mean tangent stiffness over the trial
        el["frequency_small_signal_hz"] = el["frequency_hz"]
        el["frequency_hz"] = _effective(sim, robot, effects, mechanism)
    ds = unseen.derived(sim, pipeline, robot)
    t0 = time.perf_counter()
    fit = rigid_choice(problem, ds)  # π by the recommended fit, as the command
    d = diagnose_trial(robot, ds, progress=False, torque_filter_hz="auto", rigid_fit=fit)
    seconds = time.perf_counter() - t0
    named = [c["cause"] for c in d.causes]
    judged = {
        c["cause"]: hidden.errors(c["cause"], c["estimate"], truth[c["cause"]]) for c in d.causes if c["cause"] in truth
    }
    exact = set(named) == set(causes)
    return {
        "case": label,
        "plant": plant,
        "seed": seed,
        "pipeline": pipeline,
        "trajectory": trajectory,
        "hidden": list(causes),
        "named": named,
        "exact": exact,
        "within": bool(exact and all(ok for ok, _ in judged.values())),
        "errors": {c: err for c, (_, err) in judged.items()},
        "estimates": {c["cause"]: c["estimate"] for c in d.causes},
        "truth": {c: truth[c] for c in causes},
        "nmse_before": d.nmse_before,
        "nmse_after": d.nmse_after,
        "candidates": [{k: c.get(k) for k in ("cause", "score", "estimate", "shortfall")} for c in d.candidates],
        "seconds_simulate": seconds_sim,
        "seconds_diagnose": seconds,
    }


def _effective(sim, robot, effects, mechanism) -> float:
    """The effective frequency [Hz] of a non-linear joint's mode over the trial's logged deflections."""
    from ident_opt.effects import is_active, normalise
    from ident_opt.simulator import unseen
    from ident_opt.simulator.truth import build_truth, coulomb_levels

    coulomb = coulomb_levels(robot)
    wanted = normalise(effects, coulomb)
    truth = build_truth(robot, {n: p for n, p in wanted.items() if is_active(n, p, coulomb)})
    mech = mechanism(truth)
    return unseen.effective_frequency_hz(mech, sim.frame[mech.deflection_column].to_numpy())


def tables(results: list[dict], command: str) -> str:
    """Markdown: per plant the exact-set counts and a case × named table; then every trial."""
    lines = ["# The diagnosis on plants and loggers it was not tuned on", "", f"Regenerate: `{command}`", ""]
    lines += [
        "| plant | trials | exact set named | exact set, every estimate within tolerance | false alarms on clean |",
        "|---|---|---|---|---|",
    ]
    for plant in dict.fromkeys(r["plant"] for r in results):
        rows = [r for r in results if r["plant"] == plant]
        real = [r for r in rows if r["hidden"]]
        clean = [r for r in rows if not r["hidden"]]
        lines.append(
            f"| {plant} | {len(real)} | {sum(r['exact'] for r in real)} | {sum(r['within'] for r in real)} | "
            f"{sum(not r['exact'] for r in clean)} of {len(clean)} |"
        )
    real = [r for r in results if r["hidden"]]
    n_exact, n_within = sum(r["exact"] for r in real), sum(r["within"] for r in real)
    lines += [
        f"| all | {len(real)} | {share(n_exact, len(real))} | {share(n_within, len(real))} | |",
        "",
        *confusion(results),
        "| hidden | seed | logger | reference | named (in order) | exact | within | worst rel. error | estimates "
        "| truth |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        cell = worst(r["errors"])
        truth = {c: _judged(c, v) for c, v in r["truth"].items()}
        lines.append(
            f"| {r['case']} | {r['seed']} | {r['pipeline']} | {r['trajectory']} | {chain(r['named'])} | "
            f"{r['exact']} | {r['within']} | {cell} | `{rounded(r['estimates'])}` | `{rounded(truth)}` |"
        )
    secs = [r["seconds_diagnose"] for r in results]
    lines += ["", f"diagnose runtime per trial: median {np.median(secs):.1f} s, max {np.max(secs):.1f} s.", ""]
    return "\n".join(lines)


def confusion(results: list[dict]) -> list[str]:
    """Hidden case × cause named (anywhere in the chain; `none` for an empty chain): trial counts."""
    from ident_opt.diagnosis import CAUSES

    lines = confusion_matrix(
        "hidden \\ named",
        CAUSES,
        [(label, [r for r in results if r["case"] == label]) for label in dict.fromkeys(r["case"] for r in results)],
        lambda r, c: (c in r["named"]) or (c == "none" and not r["named"]),
        (("trials",), lambda label, rows: (str(len(rows)),)),
    )
    return [*lines, ""]


def _judged(cause: str, truth: dict) -> dict:
    from ident_opt.effects import CATALOGUE

    return {k: v for k, v in truth.items() if k in CATALOGUE[cause].judged}


def saved_trials(paths: list[str | Path], seed_set: str) -> list[dict]:
    """The trial records of `seed_set` in trial logs (JSON lines), each case and seed once (the last record wins), in
    matrix order."""
    latest = {}
    for path in paths:
        for line in Path(path).read_text().splitlines():
            r = json.loads(line)
            if r["seed"] in SEEDS[seed_set]:
                latest[(r["case"], r["seed"])] = r
    labels = [c[0] for c in CASES]
    return sorted(latest.values(), key=lambda r: (r["seed"], labels.index(r["case"])))


def _tables_only(args, command: str) -> int:
    """Write `unseen_plants_<set>.md` from trial logs (`--tables`): each case and seed once, in matrix order."""
    text = tables(saved_trials(args.tables, args.set), command)
    (Path(args.out_dir) / f"unseen_plants_{args.set}.md").write_text(text)
    print(text.split("\n\n| hidden")[0])
    return 0


def main(argv: list[str] | None = None) -> int:
    from tqdm import tqdm

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--set", choices=tuple(SEEDS), required=True, help="tuning, unseen or fresh seeds")
    parser.add_argument("--cases", nargs="*", help="labels of the cases to run (default: all)")
    parser.add_argument("--seeds", type=int, nargs="*", help="a subset of the set's seeds (default: all of them)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out-dir", default=str(ROOT / "results" / "diagnosis"))
    parser.add_argument(
        "--tables",
        nargs="*",
        metavar="JSONL",
        help="only write the tables of the set from these trial logs (the last record of a case and seed wins)",
    )
    args = parser.parse_args(argv)
    command = "python benchmarks/unseen_plants.py " + " ".join(argv if argv is not None else sys.argv[1:])
    if args.tables:
        return _tables_only(args, command)
    wanted = [i for i, c in enumerate(CASES) if not args.cases or c[0] in args.cases]
    seeds = [s for s in SEEDS[args.set] if not args.seeds or s in args.seeds]
    # The unseen plants first (the slowest to simulate, and the ones the matrix is about); order does not change
    # what a trial is (its logger and magnitudes follow from its case and seed alone).
    jobs = sorted(((i, s) for s in seeds for i in wanted), key=lambda j: (CASES[j[0]][1] == "catalogue", j[1], j[0]))
    out = Path(args.out_dir)
    stem = f"unseen_plants_{args.set}" + ("" if not args.cases and not args.seeds else "_partial")
    results = []
    with ProcessPoolExecutor(args.jobs) as pool, open(out / f"{stem}.jsonl", "w") as log:
        futures = [pool.submit(trial, job) for job in jobs]
        for future in tqdm(as_completed(futures), total=len(jobs), desc=f"{args.set} trials", file=sys.stderr):
            r = future.result()
            results.append(r)
            log.write(json.dumps(r, default=float) + "\n")
            log.flush()
            print(
                f"{r['case']:28s} seed {r['seed']:4d} {r['pipeline']:15s} named {r['named']} exact={r['exact']} "
                f"within={r['within']} errors={rounded(r['errors'])}",
                flush=True,
            )
    order = {job: k for k, job in enumerate(jobs)}
    results.sort(key=lambda r: order[(next(i for i, c in enumerate(CASES) if c[0] == r["case"]), r["seed"])])
    (out / f"{stem}.md").write_text(tables(results, command))
    print(tables(results, command).split("\n\n| hidden")[0])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
