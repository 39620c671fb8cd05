"""Benchmark: `ident-opt fleet` on simulated fleets — what it finds, how fast, in how much memory.

    .venv/bin/python benchmarks/bench_fleet.py [--robots 30] [--days 20] [--seconds 30] [--seed 31] [--quick]

1. **Changes** (issue 31): a planar two-link fleet (problems/tudor_2dof.toml) and a 6-joint one
   (problems/staubli_tx40.toml), each `--robots` × `--days` with hidden wear, payload and drive changes
   (`ident_opt.fleet.simulated`): every hidden change must be found on its robot with its cause, joint and first
   day (± 3 days), and no other robot may be named.
2. **Throughput**, side by side in one run on the planar fleet: a local cluster of 1 worker process, of 2, and an
   existing cluster started as separate processes (`dask scheduler`, `dask worker --nworkers 2`), in interleaved
   rounds (the best of each kept: the machine is shared): wall time of the whole run, samples per second through
   the cluster, worker-seconds per file.
3. **Memory**: one file's task (`tasks.file_stats`) at 1×, 4× and 16× the file length: what it returns (pickled
   bytes: the statistics) and its peak (tracemalloc: Python and NumPy allocations while the loader holds the trial);
   the client's peak (tracemalloc) over whole runs of the same robots and days with files 1× and 4× as long.
4. **On paper**: 1,000 robots × 365 days from the measured per-file and per-robot-day cost.
"""

from __future__ import annotations

import argparse
import datetime
import os
import pickle
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

from distributed import Client

from ident_opt.fleet import layout, tasks
from ident_opt.fleet.run import run_fleet
from ident_opt.fleet.simulated import FleetSpec, read_truth, simulate_fleet

ROOT = Path(__file__).resolve().parents[1]
PLANAR = ROOT / "problems" / "tudor_2dof.toml"
CHAIN = ROOT / "problems" / "staubli_tx40.toml"
#: A found change's first day may differ from the hidden one by this many days.
DAYS_OFF = 3


def judge(result, root: Path) -> tuple[int, int, int, list[str]]:
    """(hidden, found right, false alarms, problems) of a run against the fleet's truth."""
    hidden = {h.robot: h for h in read_truth(root)}
    found = {c.robot: c for c in result.changes}
    problems, right = [], 0
    for robot, h in hidden.items():
        c = found.get(robot)
        if c is None:
            problems.append(f"{robot}: {h.cause} (joint {h.joint}) from {h.first_day} missed")
            continue
        off = abs((datetime.date.fromisoformat(c.first_day) - datetime.date.fromisoformat(h.first_day)).days)
        if (c.cause, c.joint) == (h.cause, h.joint) and off <= DAYS_OFF:
            right += 1
        else:
            problems.append(f"{robot}: {h.cause} j{h.joint} {h.first_day} found as {c.cause} j{c.joint} {c.first_day}")
    false = [r for r in found if r not in hidden]
    problems += [f"{r}: false alarm ({found[r].cause})" for r in false]
    return len(hidden), right, len(false), problems


def changes_section(args, folder: Path) -> None:
    print("\n## 1. Changes found (hidden: wear, payload, drive)\n")
    print(
        f"{'arm':<14}{'robots×days':>12}{'hidden':>8}{'right':>7}{'false':>7}{'seconds':>9}{'CPU-ms/file':>12}"
        "  fit  problems"
    )
    for name, problem, seconds in (("planar 2-joint", PLANAR, args.seconds), ("TX40 6-joint", CHAIN, 20.0)):
        if args.quick and problem == CHAIN:
            continue
        root = folder / f"changes_{problem.stem}"
        spec = FleetSpec(robots=args.robots, days=args.days, seconds=seconds, rate_hz=100.0, seed=args.seed)
        simulate_fleet(problem, root, spec)
        result = run_fleet(problem, str(root), workers=2, progress=False)
        hidden, right, false, problems = judge(result, root)
        size, seconds = f"{args.robots}×{args.days}", result.fleet["seconds"]
        cpu = 1000 * result.fleet["cpu_seconds_per_file"]
        print(
            f"{name:<14}{size:>12}{hidden:>8}{right:>7}{false:>7}{seconds:>9.1f}{cpu:>12.0f}  {result.estimator}  "
            f"{problems or 'none'}"
        )


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _external(workers: int) -> tuple[str, list[subprocess.Popen]]:
    """A scheduler and `workers` single-threaded workers, each its own process (the `dask` CLI)."""
    address = f"tcp://127.0.0.1:{_free_port()}"
    dask = str(Path(sys.executable).parent / "dask")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    port = address.rsplit(":", 1)[1]
    commands = [
        [dask, "scheduler", "--host", "127.0.0.1", "--port", port, "--no-dashboard"],
        [dask, "worker", address, "--nworkers", str(workers), "--nthreads", "1", "--no-dashboard"],
    ]
    started = [subprocess.Popen(c, env=env, stderr=subprocess.DEVNULL) for c in commands]
    with Client(address, timeout="60s") as client:  # every worker up before the timed run
        client.wait_for_workers(workers, timeout=120)
    return address, started


def throughput_section(args, folder: Path) -> dict:
    print(f"\n## 2. Throughput (planar fleet, the same files; best of {args.repeats} interleaved rounds)\n")
    root = folder / "throughput"
    spec = FleetSpec(robots=args.robots, days=args.days, seconds=args.seconds, rate_hz=200.0, seed=args.seed + 1)
    simulate_fleet(PLANAR, root, spec)
    runs = (("local, 1 worker", False, 1), ("local, 2 workers", False, 2), ("dask CLI, 2 workers", True, 2))
    best: dict[str, dict] = {}
    print(f"load average before: {os.getloadavg()[0]:.1f} (2 cores shared: other work slows every number here)")
    for _ in range(args.repeats):
        for label, external, workers in runs:
            scheduler, started = _external(workers) if external else (None, [])
            try:
                local = None if external else workers
                result = run_fleet(
                    PLANAR, str(root), scheduler=scheduler, workers=local, progress=False, connect_timeout=60
                )
            finally:
                for process in reversed(started):
                    process.terminate()
                    process.wait(timeout=30)
            if label not in best or result.fleet["engine_seconds"] < best[label]["engine_seconds"]:
                best[label] = result.fleet
    print(f"load average after: {os.getloadavg()[0]:.1f}")
    print(f"({best['local, 1 worker']['samples'] / best['local, 1 worker']['files']:,.0f} samples per file, "
          f"{best['local, 1 worker']['files']} files)")  # fmt: skip
    for label, f in best.items():
        per_file = f["engine_seconds"] * f["workers"] / f["files"]
        print(
            f"{label:<20} wall {f['seconds']:6.1f} s  cluster {f['engine_seconds']:6.1f} s  "
            f"{f['samples_per_second']:10,.0f} samples/s  {per_file * 1000:6.1f} worker-ms/file  "
            f"{f['cpu_seconds_per_file'] * 1000:6.1f} CPU-ms/file"
        )
    one, two = best["local, 1 worker"], best["local, 2 workers"]
    print(f"\n2 workers / 1 worker: {two['samples_per_second'] / one['samples_per_second']:.2f}× samples/s")
    print("(CPU-ms per file: the tasks' own CPU time, what a file costs whatever else the machine runs)")
    return {"per_file": min(f["cpu_seconds_per_file"] for f in best.values()), "fleet": one}


def memory_section(args, folder: Path) -> None:
    print("\n## 3. Memory\n")
    job = tasks.Job(str(PLANAR.resolve()))
    tasks.setup(job.problem)
    print("one file's task (tasks.file_stats, with the robot's recommended fit's statistics):")
    for factor in (1, 4, 16):
        root = folder / f"length_{factor}"
        spec = FleetSpec(robots=1, days=1, seconds=args.seconds * factor, rate_hz=200.0, changed=0.0, seed=3)
        simulate_fleet(PLANAR, root, spec)
        file = layout.discover(str(root)).files[0]
        choice = tasks.choose(job, file.robot, [file])  # the fit the file's statistics are for; warms the caches
        tasks.file_stats(job, file, choice)
        tracemalloc.start()
        result = tasks.file_stats(job, file, choice)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        print(
            f"  {result.samples:>9,} samples ({choice.recommendation.estimator}): returns "
            f"{len(pickle.dumps(result)):>6,} bytes; "
            f"peak {peak / 1e6:7.1f} MB ({peak / result.samples:5.0f} bytes/sample)"
        )
    print("the client's peak over a whole run (tracemalloc; 8 robots × 12 days, 2 workers):")
    for factor in (1, 4):
        root = folder / f"client_{factor}"
        spec = FleetSpec(robots=8, days=12, seconds=args.seconds * factor, rate_hz=200.0, seed=5)
        simulate_fleet(PLANAR, root, spec)
        tracemalloc.start()
        result = run_fleet(PLANAR, str(root), workers=2, progress=False)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        print(f"  {result.fleet['samples']:>11,} samples: client peak {peak / 1e6:6.1f} MB")


def paper_section(measured: dict) -> None:
    print("\n## 4. 1,000 robots × 365 days, on paper\n")
    per_file, f = measured["per_file"], measured["fleet"]
    samples = f["samples"] / f["files"]
    files = 1000 * 365
    print(f"measured: {per_file * 1000:.1f} CPU-ms per file of {samples:,.0f} samples (read, derivatives,")
    print("statistics, the robot-day's fit, the changes' evidence), one file per robot-day, each worker a core;")
    print("plus Dask's own overhead (about 1 ms per task, 3 tasks per file)")
    for workers in (2, 64, 512):
        hours = files * (per_file + 0.003) / workers / 3600
        print(f"  {workers:>4} workers: {hours:8.2f} h")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--robots", type=int, default=30)
    parser.add_argument("--days", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=30.0, help="length of a day's log [s]")
    parser.add_argument("--repeats", type=int, default=2, help="rounds of the throughput runs (best kept)")
    parser.add_argument("--seed", type=int, default=31)
    parser.add_argument("--quick", action="store_true", help="the planar arm only")
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="bench-fleet-"))
    print(f"# bench_fleet: {args.robots} robots × {args.days} days, {os.cpu_count()} cores, seed {args.seed}")
    start = time.perf_counter()
    try:
        changes_section(args, folder)
        measured = throughput_section(args, folder)
        memory_section(args, folder)
        paper_section(measured)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    print(f"\n(benchmark wall time {time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
