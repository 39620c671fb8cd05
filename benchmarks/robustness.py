"""The diagnosis on trials unlike the ones it was tuned on: other rates, controllers, noise, effect sizes,
lengths and the simulator's background terms, one condition at a time.

    .venv/bin/python benchmarks/robustness.py [--seeds 1] [--first-seed 300] [--jobs 2]
        [--out results/diagnosis/robustness.md]

Every catalogue cause is hidden alone (and a clean trial added) under each condition, on seeds never looked at
while tuning; the trials are those of `confusion_matrix.py` (its `one`) with one setting changed from the
default (100 Hz log, 6 Hz controller bandwidth, the real robot's torque noise, the drawn magnitude, 80 s, no
background terms). Reported per condition: the exact set of causes named (one cause and nothing else; `none`
on the clean trial), within tolerance, and each miss.
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from confusion_matrix import ROOT, chain, one

from ident_opt.diagnosis import CAUSES
from ident_opt.effects import BACKGROUND
from ident_opt.report import record

#: name -> (what changes, trial length [s], condition for `confusion_matrix.one`).
CONDITIONS = {
    "default": ("as the confusion matrix", 80.0, {}),
    "rate 200 Hz": ("logged at 200 Hz", 80.0, {"simulate": {"rate_hz": 200.0}}),
    "rate 1 kHz": ("logged at 1 kHz (40 s)", 40.0, {"simulate": {"rate_hz": 1000.0}}),
    "soft controller": ("closed-loop bandwidth 3 Hz (default 6)", 80.0, {"simulate": {"bandwidth_hz": 3.0}}),
    "stiff controller": ("closed-loop bandwidth 15 Hz", 80.0, {"simulate": {"bandwidth_hz": 15.0}}),
    "noise x3": ("three times the real robot's torque noise", 80.0, {"simulate": {"noise_scale": 3.0}}),
    "effects x0.5": ("half the drawn magnitude", 80.0, {"magnitude": 0.5}),
    "effects x2": ("twice the drawn magnitude", 80.0, {"magnitude": 2.0}),
    "short trial": ("30 s instead of 80", 30.0, {}),
    **{
        f"background: {name}": (f"the simulator's {name} term on, at its defaults", 80.0, {"background": (name,)})
        for name in BACKGROUND
    },
    "background terms": (
        "the simulator's stiction, drift and ripple on together (defaults calibrated on MERIt)",
        80.0,
        {"background": tuple(BACKGROUND)},
    ),
}


def table(results: dict[str, list[dict]], command: str, seconds: float) -> str:
    """The Markdown report: one row per condition, then every miss."""
    lines = [
        "# The diagnosis on trials it was not tuned on",
        "",
        f"Regenerate: `{command}` ({seconds / 60:.0f} min here).",
        "",
        "Each condition changes one setting of the confusion matrix's single-effect trials (100 Hz log, 6 Hz "
        "controller bandwidth, the real robot's torque noise, the drawn magnitude, 80 s, no background terms; "
        "`tud01` reference, `fourier` for Stribeck friction). Every catalogue cause hidden alone, plus a clean "
        "trial that must come out `none`. Exact: that one cause named and nothing else.",
        "",
        "| condition | what changes | trials | exact set | within tolerance | clean trials `none` |",
        "|---|---|---|---|---|---|",
    ]
    for name, rows in results.items():
        effect = [r for r in rows if r["cause"] != "none"]
        clean = [r for r in rows if r["cause"] == "none"]
        exact = sum(r["exact"] for r in effect)
        within = sum(bool(r["exact"] and r["ok"]) for r in effect)
        lines.append(
            f"| {name} | {CONDITIONS[name][0]} | {len(rows)} | {exact}/{len(effect)} | {within}/{len(effect)} "
            f"| {sum(r['exact'] for r in clean)}/{len(clean)} |"
        )
    total = [r for rows in results.values() for r in rows if r["cause"] != "none"]
    lines += [
        "",
        f"All conditions: exact set {sum(r['exact'] for r in total)}/{len(total)}, within tolerance "
        f"{sum(bool(r['exact'] and r['ok']) for r in total)}/{len(total)}.",
        "",
        "## Misses",
        "",
        "| condition | hidden | seed | named (in order) | worst rel. error |",
        "|---|---|---|---|---|",
    ]
    for name, rows in results.items():
        for r in rows:
            if r["exact"] and (r["ok"] or r["cause"] == "none"):
                continue
            err = f"{r['error']:.3f}" if r["error"] is not None else "—"
            lines.append(f"| {name} | {r['cause']} | {r['seed']} | {chain(r['named_set'])} | {err} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from tqdm import tqdm

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--first-seed", type=int, default=300, help="seeds start here (not used while tuning)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--conditions", nargs="*", default=list(CONDITIONS), choices=list(CONDITIONS))
    parser.add_argument("--out", default=str(ROOT / "results" / "diagnosis" / "robustness.md"))
    args = parser.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    jobs = [
        (name, (cause, seed, CONDITIONS[name][1], "auto", CONDITIONS[name][2]))
        for name in args.conditions
        for cause in CAUSES
        for seed in seeds
    ]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        done = list(tqdm(pool.map(one, [j for _, j in jobs]), total=len(jobs), desc="trials", file=sys.stderr))
    results: dict[str, list[dict]] = {name: [] for name in args.conditions}
    for (name, _), r in zip(jobs, done):
        results[name].append(r)
        print(f"{name:18s} {r['cause']:20s} seed {r['seed']}: {r['named_set']} ok={r['ok']}")
    command = "python benchmarks/robustness.py " + " ".join(argv if argv is not None else sys.argv[1:])
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(table(results, command.strip(), time.perf_counter() - t0))
    record(
        out.parent,
        out.stem,
        "the diagnosis on trials it was not tuned on (rates, controllers, noise, sizes)",
        [out.name],
    )
    print(f"wrote {out}; diagnose runtime median {np.median([r['seconds'] for r in done]):.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
