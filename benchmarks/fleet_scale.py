"""Benchmark (issue 51): a fleet run every day — what adding a day costs next to a run from scratch, a file task's
memory against the file's length, and the pieces' filters against the whole trial's.

    .venv/bin/python benchmarks/fleet_scale.py [--problem P] [--robots 30] [--days 30] [--seconds 30] [--rate 200]
                                               [--workers 2] [--repeats 2] [--samples 1000000] [--skip-memory]
                                               [--out results/fleet_scale.md]

1. **A day added** (the command in its own process, as a user runs it): a simulated fleet of the arm of `--problem`
   (default the planar problems/tudor_2dof.toml; one log a day of `--seconds` ± 30 % at `--rate` Hz) of `--robots` ×
   (`--days` + 1) days. Its first `--days` days are run with a store (from
   scratch, the store and the output folder written), then the last day is added and run again with that store and
   folder; the same full fleet is run from scratch with a fresh store and folder. Reported: the wall seconds of each
   command (local cluster of `--workers` processes, its start and the reports included) and the fleet's own clock,
   the files read, and whether the day-added run's JSON equals the from-scratch one's (all but the `fleet` numbers,
   floats bit for bit) and finds the same changes.
2. **Memory**: one file task (`tasks.file_stats`, the robust fit's statistics) on a log of 10⁴ and of `--samples`
   rows, each in a fresh process: tracemalloc's peak (Python's and NumPy's allocations) and the growth of the
   process's peak resident memory over what it held before the task; also the 10⁶-row log read whole by the loader
   (the pieces switched off), for contrast. Arrow's buffers (Parquet) are outside tracemalloc: the resident memory
   counts them.
3. **Filters**: velocity, acceleration and low-passed angle of a 30,000-sample trial computed in pieces
   (`fleet.chunks`) against the whole trial's (`numerics.derivatives`), as the largest difference relative to the
   signal's largest value; beside it the same whole-trial estimate moved by a one-ulp change of the angles (the
   estimate's own rounding).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pyarrow as pa

from ident_opt.fitting.recommend import Choice
from ident_opt.fleet import chunks, streamed, tasks
from ident_opt.fleet.incremental import SMALL_RUN
from ident_opt.fleet.layout import FleetFile
from ident_opt.fleet.simulated import FleetSpec, long_trial, simulate_fleet
from ident_opt.numerics.derivatives import estimate_derivatives, lowpass

ROOT = Path(__file__).resolve().parents[1]
PLANAR = ROOT / "problems" / "tudor_2dof.toml"
RATE_HZ = 200.0


# ---------------------------------------------------------------------------------------------- 1. a day added
def _timed(problem: Path, logs: Path, db: Path, out: Path, workers: int) -> tuple[float, dict]:
    """The command, as a user runs it every day, in its own process (Python's start, the imports, the cluster's
    start and the reports included): its wall seconds and its JSON (whose `fleet.seconds` is the fleet's own clock:
    the reading, the cluster's work, the statistics and the tests)."""
    argv = [sys.executable, "-m", "ident_opt", "fleet", "--problem", str(problem), "--logs", str(logs)]
    argv += ["--out", str(out), "--store", str(db), "--json", str(out) + ".json", "--workers", str(workers)]
    argv += ["--no-progress"]
    start = time.perf_counter()
    subprocess.run(argv, check=True, capture_output=True)
    return time.perf_counter() - start, json.loads(Path(str(out) + ".json").read_text())


def _answer(data: dict, logs: Path) -> str:
    rest = {k: v for k, v in data.items() if k not in ("fleet", "logs")}
    return json.dumps(rest, sort_keys=True).replace(str(logs), "LOGS")


def _restore(saved: Path, to: Path) -> None:
    """`to` made a copy of `saved` (a file or a folder)."""
    if to.is_dir():
        shutil.rmtree(to)
    (shutil.copytree if saved.is_dir() else shutil.copyfile)(saved, to)


def day_added(problem: Path, spec: FleetSpec, workers: int, folder: Path, repeats: int) -> dict:
    """Part 1 (module doc); the day-added and the from-scratch runs each the best of `repeats` (the store and the
    output folder as they were before the day was added, put back before each; the run from scratch into a fresh
    store and a fresh folder)."""
    full, daily = folder / "full", folder / "daily"
    simulate_fleet(problem, full, spec)
    robots, days = spec.robots, spec.days - 1
    shutil.copytree(full, daily)
    last = [sorted(robot.glob("day=*"))[-1] for robot in sorted(full.glob("robot=*"))]
    for day in last:
        shutil.rmtree(daily / day.relative_to(full))
    first, first_data = _timed(problem, daily, folder / "daily.db", folder / "daily_out", workers)
    _restore(folder / "daily.db", folder / "before.db")
    _restore(folder / "daily_out", folder / "before_out")
    for day in last:
        shutil.copytree(day, daily / day.relative_to(full))
    added_runs, scratch_runs = [], []
    for _ in range(repeats):
        _restore(folder / "before.db", folder / "daily.db")
        _restore(folder / "before_out", folder / "daily_out")
        added_runs.append(_timed(problem, daily, folder / "daily.db", folder / "daily_out", workers))
        (folder / "fresh.db").unlink(missing_ok=True)
        shutil.rmtree(folder / "fresh_out", ignore_errors=True)
        scratch_runs.append(_timed(problem, full, folder / "fresh.db", folder / "fresh_out", workers))
    added, incremental = min(added_runs, key=lambda r: r[0])
    scratch_s, scratch = min(scratch_runs, key=lambda r: r[0])
    own = [min(r[1]["fleet"]["seconds"] for r in runs) for runs in (added_runs, scratch_runs)]
    return {
        "problem": problem.relative_to(ROOT).as_posix() if problem.is_relative_to(ROOT) else str(problem),
        "robots": robots,
        "days": days + 1,
        "file": f"{spec.seconds:g} s ± 30 % at {spec.rate_hz:g} Hz",
        "repeats": repeats,
        "files": scratch["fleet"]["files"],
        "samples": scratch["fleet"]["samples"],
        "first_days_s": first,
        "first_days_own_s": first_data["fleet"]["seconds"],
        "day_added_s": added,
        "day_added_all_s": [r[0] for r in added_runs],
        "day_added_own_s": own[0],
        "from_scratch_s": scratch_s,
        "from_scratch_all_s": [r[0] for r in scratch_runs],
        "from_scratch_own_s": own[1],
        "ratio": added / scratch_s,
        "ratio_own": own[0] / own[1],
        "figures": [len(list((folder / name / "figures").glob("fleet_*.png"))) for name in ("daily_out", "fresh_out")],
        "files_new": incremental["fleet"]["files_new"],
        "files_cached": incremental["fleet"]["files_cached"],
        "same_json": all(_answer(r[1], daily) == _answer(scratch, full) for r in added_runs),
        "same_changes": all(r[1]["changes"] == scratch["changes"] for r in added_runs),
        "changes": [f"{c['robot']} {c['cause']} j{c['joint']} {c['first_day']}" for c in scratch["changes"]],
    }


# ---------------------------------------------------------------------------------------------- 2. memory
def _rss_kb(field: str = "VmRSS") -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    return 0


def measure_memory(path: Path, whole: bool) -> dict:
    """One task on `path` in this (fresh) process: tracemalloc's peak and the resident memory's growth [MB]."""
    if whole:
        streamed.STREAM_MIN_ROWS = 1 << 62  # the pieces switched off: the loader reads every file whole
    job = tasks.Job(str(PLANAR))
    choice = tasks.RobotChoice("R01", Choice("robust", "the benchmark's", 1.0))
    warm = path.with_name("warm.csv")
    tasks.file_stats(job, FleetFile("R01", "2026-03-01", str(warm), warm.name), choice)  # imports, caches
    before = _rss_kb()
    tracemalloc.start()
    start = time.perf_counter()
    result = tasks.file_stats(job, FleetFile("R01", "2026-03-01", str(path), path.name), choice)
    seconds = time.perf_counter() - start
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    grown = max(_rss_kb("VmHWM") - before, 0)
    arrow = pa.default_memory_pool().max_memory() / 1e6  # Arrow's own allocations (Parquet), over the process
    pieces = any("pieces" in note for note in result.notes)
    return {"samples": result.samples, "traced_mb": peak / 1e6, "rss_growth_mb": grown / 1e3, "arrow_mb": arrow,
            "seconds": seconds, "pieces": pieces, "reason": result.reason}  # fmt: skip


def memory(samples: list[int], folder: Path) -> list[dict]:
    """Part 2 (module doc): each measurement in a fresh process."""
    long_trial(PLANAR, 2_000, RATE_HZ, seed=1).to_csv(folder / "warm.csv", index=False)
    rows = []
    for n, kind, whole in [*((n, k, False) for n in samples for k in ("csv", "parquet")), (samples[-1], "csv", True)]:
        path = folder / f"n{n}.{kind}"
        if not path.exists():
            frame = long_trial(PLANAR, n, RATE_HZ, seed=2)
            if kind == "csv":
                frame.to_csv(path, index=False)
            else:
                frame.to_parquet(path, index=False, row_group_size=65_536)
        argv = [sys.executable, __file__, "--measure", str(path)] + (["--whole"] if whole else [])
        done = subprocess.run(argv, capture_output=True, text=True, check=True)
        rows.append({"rows": n, "format": kind, "whole": whole, **json.loads(done.stdout.splitlines()[-1])})
        print(f"  memory: {rows[-1]}", file=sys.stderr)
    return rows


# ---------------------------------------------------------------------------------------------- 3. filters
def filters() -> list[dict]:
    """Part 3 (module doc)."""
    rng = np.random.default_rng(0)
    out = []
    for fs, cutoff in ((100.0, 15.0), (200.0, 15.0), (200.0, 7.5), (1000.0, 15.0)):
        t = np.arange(30_000) / fs
        q = np.column_stack([np.sin(2 * np.pi * 0.3 * t) + 0.5 * np.sin(2 * np.pi * 1.7 * t + 1), np.cos(t)])
        q += 1e-4 * rng.standard_normal(q.shape)
        whole = (*estimate_derivatives(t, q, cutoff)[:2], lowpass(t, q, cutoff))
        source = ({"t": t[i : i + 1000], "q": q[i : i + 1000]} for i in range(0, len(t), 1000))
        parts = [
            (*chunks.derivatives(w, "q", fs, cutoff, len(t)), chunks.lowpassed(w, "q", fs, cutoff, len(t)))
            for w in chunks.windows(source, streamed.CHUNK_ROWS, chunks.margin(fs, cutoff))
        ]
        pieces = [np.concatenate(p) for p in zip(*parts)]
        ulp = (*estimate_derivatives(t, q * (1 + 2**-52), cutoff)[:2], lowpass(t, q * (1 + 2**-52), cutoff))
        rel = [float(np.abs(p - w).max() / np.abs(w).max()) for p, w in zip(pieces, whole)]
        own = [float(np.abs(u - w).max() / np.abs(w).max()) for u, w in zip(ulp, whole)]
        out.append({"fs": fs, "cutoff": cutoff, "margin": chunks.margin(fs, cutoff), "pieces": rel, "one_ulp": own})
    return out


# ---------------------------------------------------------------------------------------------- the report
def _threads(day: dict) -> str:
    """How the day-added run's workers ran (`incremental.SMALL_RUN`)."""
    if day["files_new"] <= SMALL_RUN:
        return f"the day-added run, with a store and at most {SMALL_RUN} files to read, ran its workers as threads"
    return f"the day-added run too: {day['files_new']} files to read, more than `incremental.SMALL_RUN` = {SMALL_RUN}"


def _runs(seconds: list[float]) -> str:
    """The best of the runs, in bold, then every run [s]."""
    return f"**{min(seconds):.1f}** ({', '.join(f'{s:.1f}' for s in seconds)})"


def _memory_lines(mem: list[dict]) -> list[str]:
    """Part 2's section (none when it was skipped)."""
    if not mem:
        return []
    lines = [
        "## A file task's memory against the file's length",
        "",
        "One `tasks.file_stats` (the robust fit's statistics) per fresh process, after a warm-up task on a short CSV "
        "log. traced: tracemalloc's peak (Python and NumPy); Arrow's: the peak of Arrow's memory pool (Parquet's "
        "buffers, outside tracemalloc); resident: growth of the process's peak resident memory over what it held "
        "before the task (allocators keep freed memory: an upper bound).",
        "",
        "| rows | format | read | traced peak [MB] | Arrow's peak [MB] | resident growth [MB] | seconds |",
        "|---:|---|---|---:|---:|---:|---:|",
    ]
    for m in mem:
        how = "whole (loader)" if not m["pieces"] else "in pieces"
        lines.append(
            f"| {m['rows']:,} | {m['format']} | {how} | {m['traced_mb']:.1f} | {m['arrow_mb']:.1f} | "
            f"{m['rss_growth_mb']:.1f} | {m['seconds']:.2f} |"
        )
    small = {m["format"]: m for m in mem if m["rows"] == min(r["rows"] for r in mem)}
    big = {m["format"]: m for m in mem if m["rows"] == max(r["rows"] for r in mem) and m["pieces"]}
    ratios = ", ".join(f"{k} {big[k]['traced_mb'] / small[k]['traced_mb']:.2f}×" for k in big if k in small)
    both = ", ".join(
        f"{k} {(big[k]['traced_mb'] + big[k]['arrow_mb']) / (small[k]['traced_mb'] + small[k]['arrow_mb']):.2f}×"
        for k in big
        if k in small
    )
    lines += [
        "",
        f"Traced peak, the longest log's over the 10⁴-row log's: {ratios} (target ≤ 1.5×); with Arrow's pool "
        f"added: {both}. Parquet is read a row group at a time (here 65,536 rows): Arrow's share is bounded by the "
        "row group, not by the file (compare the two longest logs).",
        "",
    ]
    return lines


def report(day: dict, mem: list[dict], filt: list[dict], command: str) -> str:
    """results/fleet_scale.md."""
    lines = [
        "# Fleet at scale: a run every day (issue 51)",
        "",
        f"Made by `{command}` (`benchmarks/fleet_scale.py`, whose text says what each part measures).",
        "",
        "## A day added, against a run from scratch",
        "",
        f"A simulated fleet of {day['robots']} robots × {day['days']} days ({day['files']} files, "
        f"{day['samples']:,} samples; {day['problem']}, one {day['file']} log a day); a local "
        "cluster of 2 workers on a shared 2-core machine, its start included in every run (worker processes; "
        f"{_threads(day)}). The timed pair ran "
        f"{day['repeats']} times, interleaved; the best of each is compared (the machine is shared).",
        "",
        "Each run is the command as a user runs it every day (`ident-opt fleet --store … --out … --json …`) in its "
        "own process: the wall clock counts Python's start, the imports, the cluster's start and every report "
        "(`--figures new`: a robot's figure drawn when the folder does not show its change yet, the fleet overview "
        "every run); the fleet's own clock (the JSON's `fleet.seconds`) counts the reading, the cluster's work, "
        "the statistics and the change tests.",
        "",
        "| run | the command's wall clock [s] | the fleet's own clock [s] | files read | from the store |",
        "|---|---:|---:|---:|---:|",
        f"| first {day['days'] - 1} days, empty store | {day['first_days_s']:.1f} | {day['first_days_own_s']:.1f} | "
        f"{day['files'] - day['files_new']} | 0 |",
        f"| the last day added, same store and folder | {_runs(day['day_added_all_s'])} | "
        f"{day['day_added_own_s']:.1f} | {day['files_new']} | {day['files_cached']} |",
        f"| all {day['days']} days from scratch, fresh store and folder | {_runs(day['from_scratch_all_s'])} | "
        f"{day['from_scratch_own_s']:.1f} | {day['files']} | 0 |",
        "",
        f"Adding a day costs **{100 * day['ratio']:.1f} %** of the run from scratch by the command's wall clock and "
        f"**{100 * day['ratio_own']:.1f} %** by the fleet's own (target: ≤ 5 %; 1/{day['days']} of the files is "
        f"new). Robots' figures in the folder after the day added / from scratch: {day['figures'][0]} / "
        f"{day['figures'][1]} (the overview included). Same JSON as from scratch (all but the `fleet` numbers, "
        f"floats bit for bit): **{day['same_json']}**; same changes: **{day['same_changes']}** "
        f"({len(day['changes'])}: {', '.join(day['changes'])}).",
        "",
    ]
    lines += _memory_lines(mem)
    lines += [
        "## The pieces' filters against the whole trial's",
        "",
        "30,000 samples, pieces of 8,192 outputs from blocks of 1,000 rows; largest difference over the whole trial "
        "(ends included) relative to the signal's largest value; beside it, the whole-trial estimate's own change "
        "under a one-ulp change of the angles.",
        "",
        "| rate [Hz] | cut-off [Hz] | margin [samples] | velocity | acceleration | low-passed | one ulp: velocity | "
        "acceleration |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for f in filt:
        p, u = f["pieces"], f["one_ulp"]
        lines.append(
            f"| {f['fs']:g} | {f['cutoff']:g} | {f['margin']} | {p[0]:.1e} | {p[1]:.1e} | {p[2]:.1e} | {u[0]:.1e} | "
            f"{u[1]:.1e} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python benchmarks/fleet_scale.py", description=__doc__.split("\n")[0])
    parser.add_argument("--problem", default=str(PLANAR), help="the fleet's arm (part 1; default the planar arm)")
    parser.add_argument("--skip-memory", action="store_true", help="part 1 and 3 only (part 2 measured elsewhere)")
    parser.add_argument("--robots", type=int, default=30)
    parser.add_argument("--seconds", type=float, default=30.0, help="each simulated log's length [s] (30)")
    parser.add_argument("--rate", type=float, default=200.0, help="each simulated log's rate [Hz] (200)")
    parser.add_argument("--days", type=int, default=30, help="days before the one added")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=51)
    parser.add_argument("--repeats", type=int, default=2, help="runs of the timed pair (the best kept)")
    parser.add_argument("--samples", type=int, default=1_000_000, help="the long log's rows")
    parser.add_argument("--out", default=str(ROOT / "results" / "fleet_scale.md"))
    parser.add_argument("--measure", help=argparse.SUPPRESS)  # one memory measurement, in its own process
    parser.add_argument("--whole", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.measure:
        print(json.dumps(measure_memory(Path(args.measure), args.whole)))
        return 0
    with tempfile.TemporaryDirectory(prefix="fleet-scale-") as tmp:
        filt = filters()
        mem = [] if args.skip_memory else memory(sorted({10_000, 100_000, args.samples}), Path(tmp))
        spec = FleetSpec(
            robots=args.robots, days=args.days + 1, seed=args.seed, seconds=args.seconds, rate_hz=args.rate
        )
        day = day_added(Path(args.problem).resolve(), spec, args.workers, Path(tmp), args.repeats)
    command = "python benchmarks/fleet_scale.py " + " ".join(sys.argv[1:] if argv is None else argv)
    text = report(day, mem, filt, command.strip())
    Path(args.out).write_text(text, encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
