"""`ident-opt fleet` on hostile input, fourth round (issue 52): a --scheduler port that does not speak Dask, a robot
none of whose files is readable and one file the loader chokes on, a file name that is not UTF-8, a robot id too
long for its figure's file name, fleets behind zip:// URLs, Ctrl-C and SIGTERM to the process group, a one-day
robot's figure, `run_fleet`'s numbers checked at the door, and the simulated-fleet generator's options. A tiny
simulated fleet (2 robots × 3 days) run on threads keeps each case to seconds; the signals' case runs the command
in its own process group."""

from __future__ import annotations

import http.server
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import psutil
import pytest

import ident_opt
from ident_opt.arguments import range_of
from ident_opt.cli import main
from ident_opt.errors import InputError
from ident_opt.fleet import interrupts, layout, simulated, tasks
from ident_opt.fleet.run import run_fleet
from ident_opt.fleet.simulated import FleetSpec, simulate_fleet
from ident_opt.report import fleet as report
from ident_opt.report.figures import daily_figure
from tests.conftest import ROOT
from tests.test_fleet import PLANAR

#: The smallest fleet a run answers for: 2 robots × 3 days, no hidden change.
TINY = FleetSpec(robots=2, days=3, seconds=5.0, rate_hz=100.0, seed=7, changed=0.0)
#: A file name's limit (NAME_MAX on Linux), in bytes.
NAME_MAX = 255


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> tuple[Path, dict]:
    """The tiny fleet, and its run's JSON payload (the answers the hostile cases must leave intact)."""
    root = tmp_path_factory.mktemp("base") / "logs"
    simulate_fleet(PLANAR, root, TINY)
    return root, report.payload(_run(root))


@pytest.fixture
def fleet(base, tmp_path) -> Path:
    """A copy of the tiny fleet to spoil."""
    root = tmp_path / "logs"
    shutil.copytree(base[0], root)
    return root


def _run(logs: str | Path, **kwargs):
    """The fleet on a threaded local cluster (fast; the workers share this process, so a monkeypatch reaches them)."""
    return run_fleet(PLANAR, str(logs), workers=2, processes=False, progress=False, **kwargs)


def _day(root: Path, robot: str, index: int) -> Path:
    return sorted((root / f"robot={robot}").glob("day=*"))[index]


def _same_robot(a: dict, b: dict) -> None:
    """A robot's answers (days, fitted parameters) equal to 1e-9."""
    assert a["days"] == b["days"]
    for name, values in a["parameters"].items():
        assert np.allclose(np.array(values, float), np.array(b["parameters"][name], float), rtol=1e-9, equal_nan=True)


# ---------------------------------------------------------------------------------------------- 1. the scheduler
def _http_server() -> tuple[str, object]:
    """A plain HTTP server on a free local port (it waits for a request line: Dask's handshake never gets one)."""

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args) -> None:  # its log would go to stderr, which the test reads
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Quiet)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return f"tcp://127.0.0.1:{server.server_address[1]}", server.shutdown


def _junk_server() -> tuple[str, object]:
    """A TCP server that answers every connection with bytes that are not Dask's, and keeps it open."""
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen()
    kept = []

    def serve() -> None:
        while True:
            try:
                connection, _ = listener.accept()
            except OSError:
                return
            connection.sendall(b"\xff" * 64 + b"HTTP/1.0 200 OK\r\n\r\nhello")
            kept.append(connection)

    threading.Thread(target=serve, daemon=True).start()
    return f"tcp://127.0.0.1:{listener.getsockname()[1]}", listener.close


@pytest.mark.timeout(90)
@pytest.mark.parametrize("server", [_http_server, _junk_server], ids=["http", "junk"])
def test_a_scheduler_port_that_does_not_speak_dask_is_refused_in_bounded_time(tmp_path, capsys, server):
    """Dask's own handshake waits for the peer's forever: the address is refused within about --connect-timeout,
    exit 2, on one line naming it, nothing written."""
    logs = tmp_path / "logs" / "robot=A" / "day=2026-01-01"
    logs.mkdir(parents=True)
    (logs / "a.csv").write_text("t,q1,q2,tau1,tau2\n")  # the layout is found before the scheduler is asked
    address, stop = server()
    try:
        argv = ["fleet", "--problem", str(PLANAR), "--logs", str(tmp_path / "logs"), "--out", str(tmp_path / "r")]
        start = time.perf_counter()
        assert main([*argv, "--scheduler", address, "--connect-timeout", "2", "--no-progress"]) == 2
        assert time.perf_counter() - start < 20.0
    finally:
        stop()
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and address in err and "Dask" in err, err
    assert not (tmp_path / "r").exists()


# ---------------------------------------------------------------------------------------------- 2. unreadable files
def test_a_robot_none_of_whose_files_is_readable_is_skipped_and_the_others_answered(base, fleet, tmp_path):
    for path in (fleet / "robot=R02").rglob("log*"):
        path.unlink()
        (path.parent / "junk.csv").write_bytes(b"garbage,,,\x00zz\nnot a trial\n")
    result = _run(fleet)
    data = report.payload(result)
    assert list(data["robots"]) == ["R01"]
    _same_robot(data["robots"]["R01"], base[1]["robots"]["R01"])
    assert sorted(s["file"] for s in data["skipped"]) == [
        f"robot=R02/{day.name}/junk.csv" for day in sorted((fleet / "robot=R02").iterdir())
    ]
    (left_out,) = [w for w in data["warnings"] if w["code"] == "robot_skipped"]
    assert "robot R02" in left_out["message"] and "left out" in left_out["message"]
    report.write(result, tmp_path / "report", tmp_path / "fleet.json", "ident-opt fleet")
    assert "robot_skipped" in (tmp_path / "report" / "fleet.md").read_text(encoding="utf-8")


def test_a_file_whose_reading_raises_is_skipped_with_its_reason_not_the_run(base, fleet, monkeypatch):
    """Whatever one file's reading raises beyond the loader's InputError (here a ValueError, as SciPy raises on
    NaNs) skips that file, with the error as its reason: the run goes on."""
    victim = next(_day(fleet, "R01", 1).iterdir())
    real = tasks.load_dataset

    def choking(path, *args, **kwargs):
        if Path(path) == victim:
            raise ValueError("`y` must contain only finite values.")
        return real(path, *args, **kwargs)

    monkeypatch.setattr(tasks, "load_dataset", choking)
    data = report.payload(_run(fleet))
    name = f"robot=R01/{victim.parent.name}/{victim.name}"
    (reason,) = [s["reason"] for s in data["skipped"] if s["file"] == name]
    assert "ValueError" in reason and "finite" in reason
    assert victim.parent.name[4:] not in data["robots"]["R01"]["days"]
    _same_robot(data["robots"]["R02"], base[1]["robots"]["R02"])


def test_a_second_sample_1e_300_s_after_the_first_skips_that_file_only(base, fleet):
    victim = next(_day(fleet, "R01", 1).glob("*.parquet"))
    frame = pd.read_parquet(victim)
    frame.loc[1, "t"] = frame.loc[0, "t"] + 1e-300
    frame.to_parquet(victim, index=False)
    data = report.payload(_run(fleet))
    name = f"robot=R01/{victim.parent.name}/{victim.name}"
    assert [s["file"] for s in data["skipped"]] == [name]
    assert len(data["robots"]["R01"]["days"]) == 2
    _same_robot(data["robots"]["R02"], base[1]["robots"]["R02"])


# ---------------------------------------------------------------------------------------------- 3. file names
def test_a_file_name_that_is_not_utf8_is_skipped_and_every_report_written(fleet, tmp_path):
    day = _day(fleet, "R01", 1)
    try:
        for raw in (b"\xff.csv", b"\xfe\nx.parquet"):
            (Path(os.fsdecode(os.fsencode(day) + b"/" + raw))).write_bytes(b"t,q1\n0,1\n")
    except OSError:
        pytest.skip("this filesystem refuses names that are not UTF-8")
    result = _run(fleet)
    report.write(result, tmp_path / "report", tmp_path / "fleet.json", "ident-opt fleet")
    data = json.loads((tmp_path / "fleet.json").read_bytes().decode("utf-8"))  # strict UTF-8, no lone surrogate
    skipped = {s["file"]: s["reason"] for s in data["skipped"]}
    assert skipped == {
        f"robot=R01/{day.name}/\\xff.csv": layout.UNNAMED,
        f"robot=R01/{day.name}/\\xfe\\nx.parquet": layout.UNNAMED,
    }
    text = (tmp_path / "report" / "fleet.md").read_bytes().decode("utf-8")
    assert f"robot=R01/{day.name}/\\xff.csv" in text
    assert len(data["robots"]["R01"]["days"]) == 3  # the day's own trial still read


# ---------------------------------------------------------------------------------------------- 4. a long robot id
def test_a_robot_id_too_long_for_its_figures_name_gets_a_short_stem(base, fleet, tmp_path):
    long_id = "R" * 240  # robot=<id> is 246 bytes: a folder may be named so, fleet_<id>.png under a temporary name not
    (fleet / "robot=R01").rename(fleet / f"robot={long_id}")
    result = _run(fleet)
    files = report.write(result, tmp_path / "report", tmp_path / "fleet.json", "ident-opt fleet", figures="all")
    data = json.loads((tmp_path / "fleet.json").read_text())
    assert sorted(data["robots"]) == ["R02", long_id]  # the id kept whole in the data
    _same_robot(data["robots"][long_id], base[1]["robots"]["R01"])
    figures = sorted(p.name for p in (tmp_path / "report" / "figures").iterdir())
    stem = layout.file_stem(long_id)
    assert figures == sorted([f"fleet_{stem}.png", "fleet_R02.png", "fleet_overview.png"])
    assert len(f"fleet_{stem}.png") + 30 < NAME_MAX
    assert stem.startswith("R" * layout.STEM_KEEP) and stem != layout.file_stem("R" * 239)
    assert f"figures/fleet_{stem}.png" in (tmp_path / "report" / "fleet.md").read_text()
    assert all(p.exists() for p in files)


# ---------------------------------------------------------------------------------------------- 5. zip:// URLs
def test_a_missing_zip_archive_exits_2_naming_it(tmp_path, capsys):
    logs = f"zip://::{tmp_path / 'missing.zip'}"
    argv = ["fleet", "--problem", str(PLANAR), "--logs", logs, "--out", str(tmp_path / "r"), "--no-progress"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert logs in err and "missing.zip" in err and "Traceback" not in err, err
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("form", ["zip://::{zip}", "zip::{zip}", "simplecache::zip://::{zip}"])
def test_a_fleet_in_a_zip_archive_is_read_as_from_its_folder(base, tmp_path, form):
    """The workers' URLs put each file's path inside the archive (not after the archive's own path, nor one
    character short): the same robots, days and fits as from the folder."""
    archive = tmp_path / "fleet.zip"
    with zipfile.ZipFile(archive, "w") as z:
        for path in sorted(base[0].rglob("*")):
            if path.is_file():
                z.write(path, path.relative_to(base[0]).as_posix())
    logs = form.format(zip=archive)
    found = layout.discover(logs)
    assert len(found.files) == 6 and all("robot=R0" in f.url and f.url.count("robot=") == 1 for f in found.files)
    data = report.payload(_run(logs))
    assert data["skipped"] == [] and sorted(data["robots"]) == ["R01", "R02"]
    for robot in ("R01", "R02"):
        _same_robot(data["robots"][robot], base[1]["robots"][robot])


# ---------------------------------------------------------------------------------------------- 6. signals
def _group(pgid: int) -> list[psutil.Process]:
    """The live processes of process group `pgid` (zombies are gone already, waiting to be reaped)."""
    out = []
    for process in psutil.process_iter():
        try:
            if os.getpgid(process.pid) == pgid and process.status() != psutil.STATUS_ZOMBIE:
                out.append(process)
        except (ProcessLookupError, psutil.NoSuchProcess):
            pass
    return out


def _ignores(pid: int, signum: int) -> bool:
    """Whether process `pid` ignores `signum` now (Linux: /proc/<pid>/status, SigIgn)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigIgn:"):
            return bool(int(line.split()[1], 16) >> (signum - 1) & 1)
    return False


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads /proc (Linux)")
@pytest.mark.timeout(180)
@pytest.mark.parametrize(
    ("signum", "status", "line"),
    [
        (signal.SIGINT, 130, "ident-opt: interrupted"),
        (signal.SIGTERM, 143, "ident-opt: terminated (SIGTERM); nothing it was writing was left behind"),
    ],
)
def test_a_signal_to_the_process_group_ends_the_run_in_one_line_and_no_worker_is_left(
    base, tmp_path, signum, status, line
):
    """Ctrl-C (SIGINT) or SIGTERM to the whole process group, as a terminal or a supervisor sends it, once the
    local cluster's worker is up: the run ends with the status of the signal and one line on stderr (no traceback
    of a worker, no error of the scheduler), and no process of the group is left."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    argv = [sys.executable, "-m", "ident_opt", "fleet", "--problem", str(PLANAR), "--logs", str(base[0])]
    argv += ["--out", str(tmp_path / "report"), "--workers", "1", "--no-progress"]
    process = subprocess.Popen(
        argv,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
        text=True,
        # as from a terminal: pytest-xdist's workers ignore SIGINT, and a child would inherit that (Python keeps an
        # ignored SIGINT ignored, and so would the run, rightly: a background job is not for Ctrl-C)
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and process.poll() is None:  # the worker spawned, the client listening
            workers = [c for c in psutil.Process(process.pid).children() if "spawn_main" in " ".join(c.cmdline())]
            if workers and not _ignores(process.pid, signal.SIGINT):
                break
            time.sleep(0.05)
        assert process.poll() is None, process.communicate()
        time.sleep(1.0)  # into the run (the check of the workers, or the tasks): any moment must do
        os.killpg(process.pid, signum)
        _, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
    assert process.returncode == status, err
    assert err.strip() == line, err
    deadline = time.monotonic() + 30
    while _group(process.pid) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert _group(process.pid) == []
    assert not (tmp_path / "report").exists()


def test_a_signal_during_a_run_is_taken_where_the_engine_delivers_it():
    """While a run is on the cluster a Ctrl-C is noted, not raised inside a call of Dask's; it is raised where the
    engine delivers it, and the handler before is back."""
    outer = signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal (xdist's workers ignore it)
    try:
        _deferred_delivery()
    finally:
        signal.signal(signal.SIGINT, outer)


def _deferred_delivery() -> None:
    before = signal.getsignal(signal.SIGINT)
    with interrupts.Deferred() as deferred:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)  # a handler that raised would have by now
        assert deferred.pending == signal.SIGINT
        with pytest.raises(KeyboardInterrupt):
            deferred.deliver()
        assert signal.getsignal(signal.SIGINT) is before
    assert signal.getsignal(signal.SIGINT) is before


# ---------------------------------------------------------------------------------------------- 7. one day
@pytest.mark.parametrize("tested", [False, True])
def test_a_one_day_robots_figure_draws_without_a_warning(tmp_path, tested):
    panel = {
        "name": "a1",
        "values": np.array([1.0]),
        "se": np.array([0.1]),
        "mean": 1.0 if tested else None,
        "band": np.array([0.2]) if tested else None,
        "moved": False,
        "since": None,
    }
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        path = daily_figure(["2026-03-01"], [panel], 5, "baseline ± 3 σ", "robot A", tmp_path / "a.png")
    assert path.exists()


# ---------------------------------------------------------------------------------------------- 8. run_fleet's door
@pytest.mark.parametrize("value", [0, -3, 1, 2.5, True, 10**6, float("nan")])
def test_run_fleet_refuses_a_baseline_outside_the_flags_range(fleet, value):
    low, high = range_of("fleet", "baseline_days")
    with pytest.raises(InputError, match="baseline_days") as caught:
        ident_opt.run_fleet(PLANAR, str(fleet), baseline_days=value, processes=False, progress=False)
    assert f"[{low:g}, {high:g}]" in str(caught.value)


@pytest.mark.parametrize(("flag", "value"), [("--baseline-days", "0"), ("--baseline-days", "-3")])
def test_the_flag_takes_the_same_range(fleet, tmp_path, capsys, flag, value):
    argv = ["fleet", "--problem", str(PLANAR), "--logs", str(fleet), "--out", str(tmp_path / "r"), flag, value]
    assert main(argv) == 2
    low, high = range_of("fleet", "baseline_days")
    assert f"{flag}: must be an integer in [{low:g}, {high:g}]" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------- 9. the generator
@pytest.mark.parametrize(
    ("extra", "named"),
    [
        (["--seconds", "1e9"], "--seconds"),
        (["--rate-hz", "1e12"], "--rate-hz"),
        (["--days", "1e8"], "--days"),
        (["--days", "100000000"], "--days"),
        (["--robots", "-3"], "--robots"),
        (["--seed", "-1"], "--seed"),
        (["--changed", "2"], "--changed"),
        (["--seconds", "3600", "--rate-hz", "5000"], "--seconds 3600 at --rate-hz 5000"),
        (["--robots", "10000", "--days", "3650"], "--robots 10000 × --days 3650"),
        (["--start", "9999-12-30"], "--start"),
        (["--causes", "wear,rust"], "--causes"),
    ],
)
def test_the_simulated_fleets_options_are_checked_before_anything_is_written(tmp_path, capsys, extra, named):
    out = tmp_path / "fleet"
    argv = ["--problem", str(PLANAR), "--out", str(out), *extra]
    script = ROOT / "benchmarks" / "simulate_fleet.py"
    done = subprocess.run([sys.executable, str(script), *argv], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    assert named in done.stderr and "Traceback" not in done.stderr
    assert list(tmp_path.iterdir()) == []


def test_the_simulated_fleet_is_written_whole_or_not_at_all(tmp_path, monkeypatch):
    """Interrupted while writing (Ctrl-C on the third file): no --out, no half-written folder beside it."""
    real, calls = simulated._write, []

    def interrupted(*args):
        calls.append(args)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(*args)

    monkeypatch.setattr(simulated, "_write", interrupted)
    with pytest.raises(KeyboardInterrupt):
        simulate_fleet(PLANAR, tmp_path / "a" / "fleet", TINY)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match="--robots"):
        simulate_fleet(PLANAR, tmp_path / "b", FleetSpec(robots=-3))
    assert list(tmp_path.iterdir()) == []


def test_json_onto_the_zip_archive_the_logs_are_read_from_is_refused(base, tmp_path, capsys):
    """Found by `make fuzz`: `--logs zip://…::file:///…/logs.zip --json logs.zip` exited 0 and overwrote the archive
    (the logs themselves): the archive a chained URL reads is an input of the run."""
    archive = tmp_path / "logs.zip"
    with zipfile.ZipFile(archive, "w") as z:
        for path in sorted(base[0].rglob("*")):
            if path.is_file():
                z.write(path, path.relative_to(base[0]).as_posix())
    before = archive.read_bytes()
    for logs in (f"zip://::file://{archive}", f"zip://::{archive}"):
        argv = ["fleet", "--problem", str(PLANAR), "--logs", logs, "--json", str(archive), "--workers", "1"]
        assert main([*argv, "--out", str(tmp_path / "r"), "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert "--json" in err and "logs.zip" in err and "Traceback" not in err, err
    assert archive.read_bytes() == before and not (tmp_path / "r").exists()
