"""Golden outputs: `compare --json` and `diagnose --json` on every shipped real robot, written to one folder, and a
comparison of two such folders to a relative tolerance (timings and paths aside).

A refactor that promises the same results runs `record` before and after, then `diff`:

    .venv/bin/python benchmarks/golden.py record build/golden/before
    .venv/bin/python benchmarks/golden.py record build/golden/after
    .venv/bin/python benchmarks/golden.py diff build/golden/before build/golden/after [--rtol 1e-9]
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "ident_opt"]

# (name, problem, extra diagnose arguments): the commands the results pages name.
ROBOTS = [
    ("merit", "problems/tudor_2dof.toml", ["--data", "data/merit/exp1.csv", "--data", "data/merit/exp2.csv"]),
    ("dfki_c0", "problems/dfki_c0.toml", []),
    ("dfki_a0", "problems/dfki_a0.toml", []),
    ("kuka_lwr4", "problems/kuka_lwr4.toml", []),
    ("franka_panda", "problems/franka_panda.toml", []),
    ("staubli_tx40", "problems/staubli_tx40.toml", []),
]

# (name, problem, effect strings, extra simulate flags): simulated trials whose CSV and truth must not move.
TRIALS = [
    (f"{problem}.{effect.split(':')[0]}{suffix}", f"problems/{problem}.toml", [effect] if effect else [], flags)
    for problem, duration in (("tudor_2dof", "12"), ("kuka_lwr4", "4"))
    for effect, suffix in (
        ("", "clean"),
        ("armature", ""),
        ("asymmetric_coulomb", ""),
        ("stribeck", ""),
        ("elasticity", ""),
        ("elasticity:kind=link" if problem == "tudor_2dof" else "elasticity:joint=3", "_2"),
        ("payload", ""),
        ("delay", ""),
        ("joint_offset", ""),
        ("torque_scale", ""),
        ("load_friction", ""),
    )
    for flags in (["--duration", duration, "--seed", "5"],)
] + [("tudor_sim.background", "problems/tudor_sim.toml", None, ["--duration", "12"])]

# Keys whose values are wall-clock measurements or machine paths, not results.
VOLATILE = {"seconds", "timings_s", "updates_per_second", "written", "files", "csv", "truth_json"}


def _volatile(key: str) -> bool:
    return key in VOLATILE or key.endswith("_seconds")


def _run(job: tuple[str, list[str]]) -> tuple[str, int, str]:
    name, args = job
    proc = subprocess.run(CLI + args, cwd=ROOT, capture_output=True, text=True)
    return name, proc.returncode, proc.stderr[-2000:]


def record(out: Path, only: list[str]) -> int:
    """Run compare and diagnose on every robot (two at a time), JSON into `out`."""
    out.mkdir(parents=True, exist_ok=True)
    jobs = []
    for name, problem, extra in ROBOTS:
        if only and name not in only:
            continue
        jobs.append(
            (
                f"{name}.compare",
                ["compare", "--problem", problem, "--no-progress", "--json", str(out / f"{name}.compare.json")],
            )
        )
        jobs.append(
            (
                f"{name}.diagnose",
                [
                    "diagnose",
                    "--problem",
                    problem,
                    *extra,
                    "--no-progress",
                    "--out",
                    str(out / f"{name}.diagnosis"),
                    "--json",
                    str(out / f"{name}.diagnose.json"),
                ],
            )
        )
    for name, problem, effects, flags in TRIALS:
        if only and name.split(".")[0] not in only:
            continue
        given = [w for e in effects or [] for w in ("--effect", e)]
        jobs.append(
            (
                f"{name}.simulate",
                [
                    "simulate",
                    "--problem",
                    problem,
                    *given,
                    *flags,
                    "--out",
                    str(out / f"{name}.sim.csv"),
                    "--json",
                    str(out / f"{name}.sim.json"),
                ],
            )
        )
    failed = 0
    with ThreadPoolExecutor(2) as pool:
        for name, rc, err in pool.map(_run, jobs):
            print(f"{name}: exit {rc}")
            if rc:
                failed += 1
                print(err)
    return 1 if failed else 0


def _walk(a, b, path: str, rtol: float, out: list[str]) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if _volatile(k):
                continue
            if k not in a or k not in b:
                out.append(f"{path}.{k}: only in {'after' if k not in a else 'before'}")
                continue
            _walk(a[k], b[k], f"{path}.{k}", rtol, out)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append(f"{path}: length {len(a)} -> {len(b)}")
            return
        for i, (x, y) in enumerate(zip(a, b)):
            _walk(x, y, f"{path}[{i}]", rtol, out)
    elif isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        if math.isnan(a) and math.isnan(b):
            return
        if abs(a - b) > rtol * max(abs(a), abs(b), 1e-300) and abs(a - b) > 1e-15:
            out.append(f"{path}: {a!r} -> {b!r}")
    elif a != b:
        out.append(f"{path}: {str(a)[:80]!r} -> {str(b)[:80]!r}")


def diff(before: Path, after: Path, rtol: float) -> int:
    """Every JSON of `before` against its namesake in `after`; print the differences."""
    bad = 0
    for f in sorted(before.glob("*.json")):
        g = after / f.name
        if not g.exists():
            print(f"{f.name}: missing in {after}")
            bad += 1
            continue
        out: list[str] = []
        _walk(json.loads(f.read_text()), json.loads(g.read_text()), "", rtol, out)
        print(f"{f.name}: {'equal' if not out else f'{len(out)} differences'}")
        csv = f.with_name(f.name.replace(".sim.json", ".sim.csv"))
        if csv != f and csv.exists() and csv.read_bytes() != (after / csv.name).read_bytes():
            print(f"{csv.name}: the simulated trial differs")
            bad += 1
        for line in out[:30]:
            print("   ", line)
        bad += bool(out)
    return 1 if bad else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="verb", required=True)
    r = sub.add_parser("record")
    r.add_argument("out", type=Path)
    r.add_argument("--only", action="append", default=[])
    d = sub.add_parser("diff")
    d.add_argument("before", type=Path)
    d.add_argument("after", type=Path)
    d.add_argument("--rtol", type=float, default=1e-9)
    args = ap.parse_args()
    if args.verb == "record":
        return record(args.out.resolve(), args.only)
    return diff(args.before, args.after, args.rtol)


if __name__ == "__main__":
    raise SystemExit(main())
