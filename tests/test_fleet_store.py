"""`ident-opt fleet --store`: a daily run reads only what the store does not hold and answers as a run from scratch
(a day added, a file changed, a file gone), the statistics stored bit for bit, a store of another model or no store
at all refused (exit 2, naming it), an interrupted write leaving the store as it was; and the alerting outputs
(changes.jsonl, metrics.prom) written with every run."""

from __future__ import annotations

import json
import os
import re
import shutil
import sqlite3
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ident_opt.cli import main
from ident_opt.errors import InputError
from ident_opt.fleet import store, tasks
from ident_opt.fleet.layout import discover
from ident_opt.fleet.run import run_fleet
from ident_opt.fleet.simulated import FleetSpec, simulate_fleet
from ident_opt.report import fleet as fleet_report
from ident_opt.report.fleet import payload
from tests.conftest import PROBLEMS

PLANAR = PROBLEMS / "tudor_2dof.toml"
#: 3 robots × 11 days, one 8 s file a day at 100 Hz; hidden changes on some robots.
SPEC = FleetSpec(robots=3, days=11, seconds=8.0, rate_hz=100.0, seed=51, changed=0.7)
#: The `fleet` numbers that are timings or say what the store gave: the only part of two runs' JSON that differs.
#: (Everything else, floats included, must be equal bit for bit.)
COUNTERS = "fleet"


def _run(root: Path, db: Path | str | None, **options) -> dict:
    result = run_fleet(PLANAR, str(root), workers=2, processes=False, progress=False, store=db, **options)
    return payload(result)


def _answer(data: dict, drop: tuple[str, ...] = ()) -> str:
    """A run's JSON without its `fleet` numbers (and warnings of the codes `drop`), as text: equal texts are equal
    answers, every float bit for bit."""
    data = {k: v for k, v in data.items() if k != COUNTERS}
    data["warnings"] = [w for w in data["warnings"] if w["code"] not in drop]
    return json.dumps(data, sort_keys=True)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("fleet") / "logs"
    simulate_fleet(PLANAR, root, SPEC)
    return root


def _copy_without_last_day(root: Path, to: Path) -> list[Path]:
    """`root` copied to `to` without each robot's last day; the last days' folders (in `root`)."""
    shutil.copytree(root, to)
    last = [sorted(robot.glob("day=*"))[-1] for robot in sorted(root.glob("robot=*"))]
    for day in last:
        shutil.rmtree(to / day.relative_to(root))
    return last


def test_a_day_added_reads_only_that_day_and_answers_as_from_scratch(fleet, tmp_path, monkeypatch):
    logs, db = tmp_path / "logs", tmp_path / "fleet.db"
    last = _copy_without_last_day(fleet, logs)
    first = _run(logs, db)
    assert first["fleet"]["files_new"] == len(discover(str(logs)).files) and first["fleet"]["files_cached"] == 0
    for day in last:
        shutil.copytree(day, logs / day.relative_to(fleet))
    shutil.copyfile(db, tmp_path / "before.db")
    read: list[str] = []  # the stored statistics the run reads back (the real reader, counted)
    real = store.read_files
    monkeypatch.setattr(
        store, "read_files", lambda stored, files: read.extend(f.name for f in files) or real(stored, files)
    )
    daily = _run(logs, db)
    monkeypatch.undo()
    scratch = _run(fleet, None)
    assert daily["fleet"]["files_new"] == len(last)
    assert daily["fleet"]["files_cached"] == first["fleet"]["files_new"]
    assert daily["changes"], "the simulated fleet hides changes: the comparison must cover some"
    assert _answer(daily).replace(str(logs), str(fleet)) == _answer(scratch)
    # baselines and scales came from the store: only the files of a change (phase 2 pools them) were read back
    changed: dict[str, str] = {}  # robot → its latest change's first day
    for c in daily["changes"]:
        changed[c["robot"]] = max(changed.get(c["robot"], ""), c["first_day"])
    assert read and len(read) < daily["fleet"]["files_cached"]
    for name in read:
        robot, day = (part.split("=")[1] for part in name.split("/")[:2])
        assert robot in changed and day >= changed[robot], name
    again = _run(logs, db)  # nothing new: nothing read, the same answer
    assert again["fleet"]["files_new"] == 0 and _answer(again) == _answer(daily)
    # a store written before scales were kept: they are computed, stored, and the answer is the same
    with sqlite3.connect(tmp_path / "before.db") as con:
        con.execute("DROP TABLE scales")
    older = _run(logs, tmp_path / "before.db")
    assert _answer(older) == _answer(daily)
    assert len(_rows(tmp_path / "before.db")["scales"]) == len(_rows(db)["scales"]) > 0


def test_a_changed_file_is_read_again_and_a_gone_one_dropped_with_warnings(fleet, tmp_path):
    """Another file's bytes under a name, and one byte changed in a file of the same size whose modification time is
    put back (its stamp still differs: the change time), are read again; a file gone is dropped; each with its
    warning, and the answer is a run's from scratch on the logs as they are now."""
    logs, db = tmp_path / "logs", tmp_path / "fleet.db"
    shutil.copytree(fleet, logs)
    _run(logs, db)
    days = sorted((logs / "robot=R01").glob("day=*"))
    changed = next(days[6].iterdir())
    shutil.copyfile(next(days[7].iterdir()), changed)  # another day's bytes under this day's name
    tampered = next(days[9].iterdir())  # the same size, its modification time put back: its change time moved
    before = tampered.stat()
    data = bytearray(tampered.read_bytes())
    data[len(data) // 2] ^= 0xFF
    tampered.write_bytes(bytes(data))
    os.utime(tampered, ns=(before.st_atime_ns, before.st_mtime_ns))
    gone = next(days[8].iterdir())
    gone.unlink()
    shutil.rmtree(days[8])
    daily = _run(logs, db)
    codes = {w["code"]: w["message"] for w in daily["warnings"]}
    assert changed.relative_to(logs).as_posix() in codes["store_changed"]
    assert tampered.relative_to(logs).as_posix() in codes["store_changed"]
    assert gone.relative_to(logs).as_posix() in codes["store_gone"]
    assert daily["fleet"]["files_new"] == 2 and daily["fleet"]["files_gone"] == 1
    scratch = _run(logs, None)
    assert _answer(daily, drop=("store_changed", "store_gone")) == _answer(scratch)
    with sqlite3.connect(db) as con:
        names = {row[0] for row in con.execute("SELECT name FROM files")}
        days_stored = {row[0] for row in con.execute("SELECT day FROM fits WHERE robot = 'R01'")}
    assert gone.relative_to(logs).as_posix() not in names and days[8].name[4:] not in days_stored
    assert len(names) == len(discover(str(logs)).files)


def test_the_statistics_are_stored_bit_for_bit(fleet):
    """A file's Stats and InstrumentStats (the robust fit's) come back as the same float64 bytes."""
    job = tasks.Job(str(PLANAR.resolve()))
    file = discover(str(fleet)).files[0]
    choice = tasks.choose(job, file.robot, [file])
    for estimator in ("robust", "ols"):
        choice.choice = type(choice.choice)(estimator, "test", 1.0)
        made = tasks.file_stats(job, file, choice)
        back = store.decode_file(file, *store.encode_file(made))
        assert (made.instruments is None) == (back.instruments is None) == (estimator != "robust")
        pairs = [(made.stats.G, back.stats.G), (made.stats.b, back.stats.b), (made.stats.s, back.stats.s)]
        if made.instruments is not None:
            pairs += [(made.instruments.A, back.instruments.A), (made.instruments.K, back.instruments.K)]
        for a, b in pairs:
            assert a.dtype == b.dtype == np.float64 and a.tobytes() == b.tobytes()
        assert (back.stats.n, back.samples, back.notes) == (made.stats.n, made.samples, made.notes)


def _rows(db: Path) -> dict:
    with sqlite3.connect(db) as con:
        return {
            t: sorted(con.execute(f"SELECT * FROM {t}"))
            for t in ("meta", "files", "choices", "fits", "baselines", "scales")
        }


def test_an_interrupted_write_leaves_the_store_as_it_was(fleet, tmp_path, monkeypatch):
    logs, db = tmp_path / "logs", tmp_path / "fleet.db"
    last = _copy_without_last_day(fleet, logs)
    before = _run(logs, db)
    rows = _rows(db)
    for day in last:
        shutil.copytree(day, logs / day.relative_to(fleet))
    real, calls = store.encode_file, []

    def interrupted(result):
        calls.append(result)
        if len(calls) == 2:  # inside the transaction, one file written already
            raise KeyboardInterrupt
        return real(result)

    monkeypatch.setattr(store, "encode_file", interrupted)
    with pytest.raises(KeyboardInterrupt):
        _run(logs, db)
    assert len(calls) == 2 and _rows(db) == rows
    monkeypatch.setattr(store, "encode_file", real)
    after = _run(logs, db)
    assert after["fleet"]["files_new"] == len(last) and before["fleet"]["files_new"] > len(last)


def test_a_store_of_another_model_or_not_a_store_is_refused(fleet, tmp_path, capsys):
    db = tmp_path / "fleet.db"
    _run(fleet, f"sqlite:///{db}")  # the URL form names the same file
    assert db.is_file()
    with pytest.raises(InputError, match=r"estimator: stored 'recommended per robot', now 'ols'"):
        _run(fleet, db, estimator="ols")
    text = tmp_path / "notes.txt"
    text.write_text("not a database, but somebody's notes\n" * 50)
    folder = tmp_path / "folder.db"
    folder.mkdir()
    argv = ["fleet", "--problem", str(PLANAR), "--logs", str(fleet), "--workers", "1", "--no-progress"]
    cases = [
        (["--store", str(db), "--estimator", "ols"], ["another model", "estimator", str(db)]),
        (["--store", str(text)], [str(text), "cannot be used as a fleet store"]),
        (["--store", str(folder)], [str(folder), "is a folder"]),
        (["--store", "postgresql://db/fleet"], ["--store postgresql://db/fleet", "SQLite"]),
        (["--store", str(fleet / "fleet.db")], ["--store", "inside --logs"]),
        (["--store", str(db), "--json", str(db)], ["--json", "is the store"]),
    ]
    for extra, named in cases:
        assert main([*argv, "--out", str(tmp_path / "out"), *extra]) == 2
        err = capsys.readouterr().err
        assert all(n in err for n in named) and "Traceback" not in err, err
    assert text.read_text().startswith("not a database") and not (tmp_path / "out").exists()
    assert store.read(store.location(db), json.loads(_stored_key(db))).files  # the store itself untouched


def _stored_key(db: Path) -> str:
    with sqlite3.connect(db) as con:
        return con.execute("SELECT value FROM meta WHERE key = 'model_key'").fetchone()[0]


#: A Prometheus sample line: name{labels} value.
SAMPLE = re.compile(r'([a-zA-Z_:][a-zA-Z0-9_:]*)\{((?:[a-zA-Z_][a-zA-Z0-9_]*="(?:[^"\\\n]|\\.)*",?)*)\} (\S+)')


def test_every_run_writes_changes_jsonl_and_metrics_prom(fleet, tmp_path):
    out = tmp_path / "report"
    argv = ["fleet", "--problem", str(PLANAR), "--logs", str(fleet), "--out", str(out), "--workers", "2"]
    assert main([*argv, "--json", str(tmp_path / "f.json"), "--no-progress"]) == 0
    data = json.loads((tmp_path / "f.json").read_text())
    assert (out / "fleet.db").is_file()  # the default store
    lines = (out / "changes.jsonl").read_text().splitlines()
    assert data["changes"] and [json.loads(line) for line in lines] == data["changes"]
    assert all(list(json.loads(line)) == list(data["changes"][0]) for line in lines)
    typed, seen = set(), {}
    for line in (out / "metrics.prom").read_text().splitlines():
        if line.startswith("# TYPE "):
            name, kind = line.split()[2:]
            assert kind == "gauge"
            typed.add(name)
        elif not line.startswith("# HELP "):
            match = SAMPLE.fullmatch(line)
            assert match and match[1] in typed, line
            value = float(match[3])
            assert np.isfinite(value), line
            seen[match[1], match[2]] = value
    for robot, entry in data["robots"].items():
        for parameter, tested in entry["tested"].items():
            labels = f'robot="{robot}",parameter="{parameter}"'
            assert seen["ident_opt_fleet_parameter_latest", labels] == tested["values"][-1]
            assert seen["ident_opt_fleet_parameter_z", labels] == pytest.approx(tested["z"][-1], rel=1e-15)
        changed = any(c["robot"] == robot for c in data["changes"])
        assert seen["ident_opt_fleet_changes", f'robot="{robot}"'] == float(changed)


def test_a_robots_figure_is_drawn_once_per_change_and_again_when_its_change_moves(fleet, tmp_path):
    """--figures new (the default): the first run into a folder draws each changed robot's figure; a run with the
    same changes redraws none (the bytes stay) but names them in fleet.md; a change that moves (here its first day)
    is drawn again, alone; `all` draws every robot; the overview every time."""
    result = run_fleet(PLANAR, str(fleet), workers=2, processes=False, progress=False)
    out = tmp_path / "report"
    changed = sorted(c.robot for c in result.changes)
    assert changed and len(changed) < len(result.robots), "the test needs changed and unchanged robots"

    def figures() -> dict[str, bytes]:
        return {p.name: p.read_bytes() for p in (out / "figures").iterdir()}

    fleet_report.write(result, out, None, "first")
    first = figures()
    assert sorted(first) == sorted(["fleet_overview.png", *(f"fleet_{r}.png" for r in changed)])
    fleet_report.write(result, out, None, "again")
    again = figures()
    assert {k: v for k, v in again.items() if k != "fleet_overview.png"} == {
        k: v for k, v in first.items() if k != "fleet_overview.png"
    }
    assert all(f"figures/fleet_{r}.png" in (out / "fleet.md").read_text() for r in changed)
    moved = result.changes[0]
    result.changes[0] = replace(moved, first_day=result.robots[moved.robot].days[-1])
    fleet_report.write(result, out, None, "moved")
    redrawn = {k for k, v in figures().items() if v != again[k]} - {"fleet_overview.png"}
    assert redrawn == {f"fleet_{moved.robot}.png"}
    fleet_report.write(result, out, None, "all", figures="all")
    assert sorted(figures()) == sorted(["fleet_overview.png", *(f"fleet_{r}.png" for r in result.robots)])
