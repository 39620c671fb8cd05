"""Hidden-effect trials: true cause × named cause, the exact set of causes on compound trials, and the
median relative estimation error per cause.

    .venv/bin/python benchmarks/confusion_matrix.py [--seeds 5] [--pair-seeds 1] [--duration 80]
        [--trajectory tud01] [--jobs 2] [--out results/diagnosis/confusion.md]

Compound trials hide two catalogue effects at once (every pair, `--pair-seeds` seeds each; elasticity pairs
use one drawn mode); the diagnosis must name exactly that set (`causes` of the JSON), each within tolerance.

For every catalogue cause and seed, a simulated trial (the built-in simulator, the default problem's robot)
hides that one effect at a random realistic magnitude (`ident_opt.diagnosis.hidden.draw`); `none` trials are
clean. The reference is the point-to-point `tud01` (like the real trials), except for causes that need slow
motion (Stribeck friction), which get the reference their module names (`Effect.reference`, here `fourier`;
`--trajectory auto`); a pair of causes that need different references gets `mixed` (both in turn). `diagnose`
runs on
each (chronological 70/30 split); the table counts what it named, and the error column is the median over
trials of the worst relative error of the estimate (when the cause was named).
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from ident_opt.diagnosis import CAUSES
from ident_opt.effects import CATALOGUE
from ident_opt.report import record
from ident_opt.report.confusion import (
    believability,
    believability_lines,
    chain,
    confusion_matrix,
    exact_set_summary,
    rounded,
    worst,
)

ROOT = Path(__file__).resolve().parents[1]


def pair(job: tuple[tuple[str, str], int, float, str]) -> dict:
    """Simulate one trial hiding two effects and diagnose it: was exactly that set named, within tolerance?"""
    from ident_opt.diagnosis import diagnose_trial, hidden, rigid_choice
    from ident_opt.problem import load_problem
    from ident_opt.simulator import simulate_trial

    causes, seed, duration, trajectory = job
    if trajectory == "auto":
        # Causes that need different motion (Stribeck friction slow reversals, a mode or a delay stops and
        # starts) share the `mixed` reference, which alternates the two.
        refs = {CATALOGUE[c].reference for c in causes}
        trajectory = refs.pop() if len(refs) == 1 else "mixed"
    problem = load_problem(ROOT / "problems" / "tudor_2dof.toml")
    robot = problem.robot
    rng = np.random.default_rng([seed, *(CAUSES.index(c) for c in causes), 99])
    effects = {c: hidden.draw(c, rng, robot) for c in causes}
    trial = simulate_trial(robot, trajectory=trajectory, duration=duration, seed=seed, effects=effects, progress=False)
    t0 = time.perf_counter()
    ds = trial.dataset()  # π by the recommended fit, as the command takes it
    d = diagnose_trial(robot, ds, progress=False, rigid_fit=rigid_choice(problem, ds))
    seconds = time.perf_counter() - t0
    named = [c["cause"] for c in d.causes]
    truth = trial.truth["effects"]
    ok = {
        c["cause"]: hidden.errors(c["cause"], c["estimate"], truth[c["cause"]]) for c in d.causes if c["cause"] in truth
    }
    return {
        "causes": list(causes),
        "seed": seed,
        "named": named,
        "exact": set(named) == set(causes),
        "within": bool(set(named) == set(causes) and all(v[0] for v in ok.values())),
        "errors": {c: v[1] for c, v in ok.items()},
        "estimates": {c["cause"]: c["estimate"] for c in d.causes},
        "truth": {c: {k: v for k, v in truth[c].items() if k in CATALOGUE[c].judged} for c in causes},
        "seconds": seconds,
        "trajectory": trajectory,
        "believability": {**believability(d), "named": named},
    }


def one(job: tuple) -> dict:
    """Simulate one hidden-effect trial and diagnose it. `job`: (cause, seed, duration, trajectory), and
    optionally a condition: {"simulate": extra `simulate_trial` keywords (rate, controller bandwidth, noise
    scale), "magnitude": a factor on the drawn magnitude, "background": background terms to switch on}."""
    from ident_opt.diagnosis import diagnose_trial, hidden, rigid_choice
    from ident_opt.problem import load_problem
    from ident_opt.simulator import simulate_trial

    cause, seed, duration, trajectory, *rest = job
    condition = rest[0] if rest else {}
    if trajectory == "auto":  # as the tests: Stribeck friction shows only on a smooth reference
        trajectory = CATALOGUE[cause].reference if cause in CATALOGUE else "tud01"
    problem = load_problem(ROOT / "problems" / "tudor_2dof.toml")
    robot = problem.robot
    rng = np.random.default_rng([seed, CAUSES.index(cause)])
    effects = {} if cause == "none" else {cause: hidden.draw(cause, rng, robot)}
    if cause != "none" and condition.get("magnitude", 1.0) != 1.0:
        effects[cause] = hidden.scaled(cause, effects[cause], condition["magnitude"], robot)
    effects.update({name: {} for name in condition.get("background", ())})
    trial = simulate_trial(
        robot,
        trajectory=trajectory,
        duration=duration,
        seed=seed,
        effects=effects,
        progress=False,
        **condition.get("simulate", {}),
    )
    t0 = time.perf_counter()
    ds = trial.dataset()  # π by the recommended fit, as the command takes it
    d = diagnose_trial(robot, ds, progress=False, rigid_fit=rigid_choice(problem, ds))
    seconds = time.perf_counter() - t0
    out = {
        "cause": cause,
        "seed": seed,
        "named": d.cause,
        "named_set": [c["cause"] for c in d.causes],
        "estimate": d.estimate,
        "seconds": seconds,
        "gain": [b - a for b, a in zip(d.nmse_before, d.nmse_after)],
        "ok": None,
        "error": None,
        "truth": trial.truth["effects"].get(cause),
        "believability": {**believability(d), "named": [c["cause"] for c in d.causes]},
    }
    if cause != "none" and d.cause == cause:
        out["ok"], out["error"] = hidden.errors(cause, d.estimate, trial.truth["effects"][cause])
        nlp = d.named.detail.get("polish") if d.named is not None else None
        if nlp is not None:  # the same trial's estimate before the IPOPT polish (grid search + refinement)
            before = {k: v for k, v in nlp["before"].items() if k in d.estimate}
            out["error_before_polish"] = hidden.errors(cause, before, trial.truth["effects"][cause])[1]
            out["polish_kept"] = nlp["kept"]
    elif cause == "none":
        out["ok"] = d.cause == "none"
    out["exact"] = set(out["named_set"]) == ({cause} - {"none"})
    return out


def compound_table(results: list[dict], pairs: list[dict]) -> list[str]:
    """The exact-set summary over single, clean and paired trials, and the paired trials one by one."""
    singles = [r for r in results if r["cause"] != "none"]
    clean = [r for r in results if r["cause"] == "none"]
    lines = [
        "## The exact set of causes",
        "",
        "`causes` of the diagnosis (the whole chain) against the hidden set: single-effect trials must name "
        "that one cause and nothing else, paired trials both and nothing else, clean trials nothing.",
        "",
        *exact_set_summary(
            [
                (
                    "single",
                    len(singles),
                    sum(r["exact"] for r in singles),
                    sum(bool(r["ok"]) and r["exact"] for r in singles),
                ),
                ("paired", len(pairs), sum(p["exact"] for p in pairs), sum(p["within"] for p in pairs)),
            ],
            "single + paired",
            ("clean (false alarms)", len(clean), sum(r["exact"] for r in clean)),
        ),
        "",
    ]
    if pairs:
        secs = [p["seconds"] for p in pairs]
        lines += [
            f"Paired trials: diagnose runtime median {np.median(secs):.1f} s, max {np.max(secs):.1f} s.",
            "",
            "| hidden | seed | reference | named (in order) | exact | within tolerance | worst rel. error | estimates "
            "| truth |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for p in pairs:
            cell = worst(p["errors"])
            lines.append(
                f"| {' + '.join(p['causes'])} | {p['seed']} | {p['trajectory']} | {chain(p['named'])} "
                f"| {p['exact']} | {p['within']} | {cell} | `{rounded(p['estimates'])}` | "
                f"`{rounded(p['truth'])}` |"
            )
        lines.append("")
    return lines


def table(results: list[dict], command: str, pairs: list[dict] | None = None) -> str:
    """The Markdown report: confusion matrix, success and median errors, runtimes."""

    def tallies(cause: str, rows: list[dict]) -> tuple[str, str]:  # within tolerance, median relative error
        errs = [r["error"] for r in rows if r["error"] is not None]
        return f"{sum(bool(r['ok']) for r in rows)}/{len(rows)}", f"{np.median(errs):.3f}" if errs else "—"

    lines = [
        "# Diagnosis on hidden-effect trials",
        "",
        f"Regenerate: `{command}`",
        "",
        "Rows: the hidden (true) cause; columns: the cause `diagnose` named. Each trial hides one effect "
        "at a random realistic magnitude (`ident_opt/diagnosis/hidden.py`) in a simulated trial that follows "
        "the point-to-point `tud01` reference (like the real trials), except Stribeck friction, which is "
        "invisible there (joints cross low speeds in a few ms at 100 Hz) and gets the smooth `fourier` "
        "reference; a paired trial whose causes need different motion (Stribeck friction with any other) "
        "follows the `mixed` reference, 10 s blocks of the two in turn (on `fourier` alone a mode or a delay "
        "has next to nothing to show); the simulator's background terms (stiction, drift, ripple) are off.",
        "",
        *confusion_matrix(
            "true \\ named",
            CAUSES,
            [(cause, [r for r in results if r["cause"] == cause]) for cause in CAUSES],
            lambda r, c: r["named"] == c,
            (("within tolerance", "median rel. error"), tallies),
        ),
    ]
    secs = [r["seconds"] for r in results]
    lines += [
        "",
        f"Trials: {len(results)}; diagnose runtime per trial: median {np.median(secs):.1f} s, "
        f"max {np.max(secs):.1f} s.",
        "",
        *compound_table(results, pairs or []),
        "## IPOPT polish",
        "",
        "Elasticity (f, ζ with every linear coefficient, multiple shooting) and joint offsets (δ1, δ2 with π) "
        "are polished by IPOPT from the grid search's answer; the polish is kept when it lowers the training "
        "objective. Worst relative error of the named estimate, same trials, before and after the polish:",
        "",
        "| cause | trials | polish kept | median error before | median error after | max before | max after |",
        "|---|---|---|---|---|---|---|",
    ]
    for cause in CAUSES:
        rows = [r for r in results if r.get("error_before_polish") is not None and r["cause"] == cause]
        if not rows:
            continue
        b, a = [r["error_before_polish"] for r in rows], [r["error"] for r in rows]
        kept = sum(bool(r["polish_kept"]) for r in rows)
        lines.append(
            f"| {cause} | {len(rows)} | {kept} | {np.median(b):.4f} | {np.median(a):.4f} | {np.max(b):.4f} "
            f"| {np.max(a):.4f} |"
        )
    rows = [([] if r["cause"] == "none" else [r["cause"]], r["believability"]) for r in results]
    rows += [(p["causes"], p["believability"]) for p in pairs or []]
    lines += ["", *believability_lines(r for r in rows if r[1] is not None)]
    lines += [
        "## Trials",
        "",
        "`named`: the first cause (the matrix's column); `chain`: every cause named, in order (exact: that one "
        "cause and nothing else).",
        "",
        "| true | seed | named | chain | exact | within tolerance | rel. error | estimate | truth |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        err = f"{r['error']:.3f}" if r["error"] is not None else "—"
        est = {k: (np.round(v, 4).tolist() if not isinstance(v, int) else v) for k, v in r["estimate"].items()}
        judged = {key for effect in CATALOGUE.values() for key in effect.judged}
        truth = {
            k: (np.round(v, 4).tolist() if not isinstance(v, int) else v)
            for k, v in (r["truth"] or {}).items()
            if k in judged
        }
        lines.append(
            f"| {r['cause']} | {r['seed']} | {r['named']} | {chain(r['named_set'])} | {r['exact']} | {r['ok']} "
            f"| {err} | `{est}` | `{truth}` |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from tqdm import tqdm

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument(
        "--first-seed", type=int, default=0, help="seeds start here (trials not looked at while tuning: e.g. 100)"
    )
    parser.add_argument("--duration", type=float, default=80.0)
    parser.add_argument(
        "--trajectory",
        default="auto",
        help="tud01, fourier, mixed, or auto: tud01 except fourier for stribeck (as the tests) and mixed "
        "for a pair that needs both",
    )
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--causes", nargs="*", default=list(CAUSES))
    parser.add_argument("--pair-seeds", type=int, default=1, help="seeds per pair of hidden effects (0: none)")
    parser.add_argument("--out", default=str(ROOT / "results" / "diagnosis" / "confusion.md"))
    args = parser.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    pair_seeds = range(args.first_seed, args.first_seed + args.pair_seeds)
    jobs = [(c, s, args.duration, args.trajectory) for c in args.causes for s in seeds]
    real = [c for c in args.causes if c != "none"]
    pair_jobs = [
        ((a, b), s, args.duration, args.trajectory)
        for i, a in enumerate(real)
        for b in real[i + 1 :]
        for s in pair_seeds
    ]
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(tqdm(pool.map(one, jobs), total=len(jobs), desc="hidden-effect trials", file=sys.stderr))
        pairs = list(tqdm(pool.map(pair, pair_jobs), total=len(pair_jobs), desc="paired trials", file=sys.stderr))
    for p in pairs:
        print(f"{' + '.join(p['causes']):40s} seed {p['seed']}: {p['named']} exact={p['exact']} within={p['within']}")
    for r in results:
        print(
            f"{r['cause']:20s} seed {r['seed']}: named {r['named']:20s} ok={r['ok']} err={r['error']} "
            f"{r['estimate']} truth={r['truth']}"
        )
    command = "python benchmarks/confusion_matrix.py " + " ".join(argv if argv is not None else sys.argv[1:])
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(table(results, command.strip(), pairs))
    seeds_note = f", seeds from {args.first_seed}" if args.first_seed else ""
    record(
        Path(args.out).parent,
        Path(args.out).stem,  # one index entry per report (a run on other seeds beside the default one)
        f"the diagnosis on simulated trials with hidden effects (confusion matrix{seeds_note})",
        [Path(args.out).name],
    )
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
