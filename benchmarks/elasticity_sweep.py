"""What the diagnosis can and cannot see of an elastic mode: a sweep over its frequency, joint and kind.

    .venv/bin/python benchmarks/elasticity_sweep.py [--seed 1] [--jobs 2] [--out results/diagnosis/elasticity_sweep.md]

For each kind (`joint`: a two-mass elastic joint, motor angle logged; `link`: a flexible link cut at
mid-length, joint angles logged), each joint and each mode frequency from 2 to 15 Hz, the built-in simulator
hides that one mode (damping ratio 0.02) in an 80 s `tud01` trial at 100 Hz, and `diagnose` runs on it
(chronological 70/30 split). The table says what it named, the joint and frequency it found, and whether that
is within the tolerance of the tests (right joint, frequency within 20 %).
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from confusion_matrix import chain
from tqdm import tqdm

from ident_opt.effects.elasticity import ELASTIC_BAND_HZ, FREQUENCY_TOL
from ident_opt.report import record

ROOT = Path(__file__).resolve().parents[1]
FREQUENCIES_HZ = (2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 15.0)


def one(job: tuple[str, int, float, int]) -> dict:
    """Simulate one hidden mode and diagnose it."""
    from ident_opt.diagnosis import diagnose_trial, rigid_choice
    from ident_opt.problem import load_problem
    from ident_opt.simulator import simulate_trial

    kind, joint, f, seed = job
    problem = load_problem(ROOT / "problems" / "tudor_2dof.toml")
    robot = problem.robot
    effect = f"elasticity:joint={joint},frequency_hz={f},damping=0.02,kind={kind}"
    trial = simulate_trial(robot, trajectory="tud01", duration=80.0, seed=seed, effects=[effect], progress=False)
    ds = trial.dataset()  # π by the recommended fit, as the command takes it
    d = diagnose_trial(robot, ds, progress=False, rigid_fit=rigid_choice(problem, ds))
    found = next((c["estimate"] for c in d.causes if c["cause"] == "elasticity"), None)
    ok = found is not None and found["joint"] == joint and abs(found["frequency_hz"] / f - 1) <= FREQUENCY_TOL
    return {"kind": kind, "joint": joint, "f": f, "named": [c["cause"] for c in d.causes], "found": found, "ok": ok}


def markdown(rows: list[dict], command: str) -> str:
    """The sweep as a table, with a count per kind."""
    lines = [
        "# Elastic modes the diagnosis can and cannot see",
        "",
        f"Regenerate: `{command}`",
        "",
        f"One hidden mode per trial (damping ratio 0.02), 80 s `tud01` at 100 Hz; searched band "
        f"{ELASTIC_BAND_HZ[0]:g}–{ELASTIC_BAND_HZ[1]:g} Hz; found = right joint, frequency within "
        f"{FREQUENCY_TOL:.0%}.",
        "",
        "| kind | joint | true f [Hz] | named | found joint | found f [Hz] | found |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        e = r["found"] or {}
        named = chain(r["named"])
        f_found = f"{e['frequency_hz']:.2f}" if e else "—"
        lines.append(
            f"| {r['kind']} | {r['joint']} | {r['f']:g} | {named} | {e.get('joint', '—')} | {f_found} | "
            f"{'yes' if r['ok'] else 'no'} |"
        )
    lines.append("")
    for kind in ("joint", "link"):
        sub = [r for r in rows if r["kind"] == kind]
        inside = [r for r in sub if ELASTIC_BAND_HZ[0] <= r["f"] <= ELASTIC_BAND_HZ[1]]
        lines.append(
            f"- `{kind}`: found {sum(r['ok'] for r in sub)}/{len(sub)}; inside the searched band "
            f"{sum(r['ok'] for r in inside)}/{len(inside)}."
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", default=str(ROOT / "results" / "diagnosis" / "elasticity_sweep.md"))
    args = parser.parse_args()
    jobs = [(k, j, f, args.seed) for k in ("joint", "link") for j in (1, 2) for f in FREQUENCIES_HZ]
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(tqdm(pool.map(one, jobs), total=len(jobs), desc="elastic modes"))
    command = "python benchmarks/elasticity_sweep.py" + (f" --seed {args.seed}" if args.seed != 1 else "")
    out = Path(args.out)
    out.write_text(markdown(rows, command))
    record(out.parent, "elasticity_sweep", "elastic modes the diagnosis can and cannot see", [out.name])
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
