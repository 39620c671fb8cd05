"""`ident-opt fleet` on hostile input: symbolic links under --logs (a trial file, a day folder, a robot folder, and a
link put in after the layout was found) are skipped unread, and nothing of the file they point to (a credentials
line) reaches the reports or the terminal; a skip reason shows a bad file only as far as needed; and no output
(--out, --json) may lie inside the logs, however --logs names them (a path, relative, a file:// URL): exit 2 before
any work, the logs untouched. A tiny simulated fleet (2 robots × 3 days, one worker) keeps each run to seconds."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from ident_opt.cli import main
from ident_opt.fitting import recommend
from ident_opt.fleet import layout, tasks
from ident_opt.fleet.simulated import FleetSpec, simulate_fleet
from tests.test_fleet import PLANAR

#: The smallest fleet a run answers for: 2 robots × 3 days, no hidden change.
TINY = FleetSpec(robots=2, days=3, seconds=5.0, rate_hz=100.0, seed=7, changed=0.0)
#: What must never leave the file outside the logs: its first line (wide enough for the planar problem's column
#: indices, so that a loader that read it would quote its first cell in the skip reason).
SECRET = "aws_secret_access_key=HUNTER2-do-not-leak"
SECRET_FILE = SECRET + ",0" * 20 + "\n" + ",".join(["1"] * 21) + "\n"


@pytest.fixture
def fleet(tmp_path) -> Path:
    """A tiny planar fleet under tmp_path/logs, and a secret file beside it (outside the logs)."""
    root = tmp_path / "logs"
    simulate_fleet(PLANAR, root, TINY)
    (tmp_path / "secret.csv").write_text(SECRET_FILE)
    return root


def _days(root: Path, robot: str) -> list[Path]:
    return sorted((root / f"robot={robot}").glob("day=*"))


def _run(root: Path, out: Path, capfd) -> tuple[int, dict, str]:
    """The command on `root` (one worker): its status, its JSON and everything it and its workers printed."""
    argv = ["fleet", "--problem", str(PLANAR), "--logs", str(root), "--out", str(out / "report")]
    status = main([*argv, "--json", str(out / "fleet.json"), "--workers", "1", "--no-progress"])
    printed = capfd.readouterr()
    data = json.loads((out / "fleet.json").read_text()) if status == 0 else {}
    return status, data, printed.out + printed.err


def _nowhere(secret: str, out: Path, printed: str) -> None:
    """`secret` in none of the files written under `out` (reports, JSON, series, figures) nor on the terminal."""
    assert secret not in printed
    for path in out.rglob("*"):
        if path.is_file():
            assert secret.encode() not in path.read_bytes(), path


def test_a_linked_file_pointing_outside_is_skipped_unread(fleet, tmp_path, capfd):
    day = _days(fleet, "R01")[1]
    (day / "leak.csv").symlink_to(tmp_path / "secret.csv")
    status, data, printed = _run(fleet, tmp_path / "out", capfd)
    assert status == 0, printed
    _nowhere(SECRET, tmp_path / "out", printed)
    name = f"robot=R01/{day.name}/leak.csv"
    assert {"file": name, "reason": layout.LINK} in data["skipped"]
    assert name in (tmp_path / "out" / "report" / "fleet.md").read_text()
    assert {r: len(v["days"]) for r, v in data["robots"].items()} == {"R01": 3, "R02": 3}  # the rest still answered


def test_linked_day_and_robot_folders_pointing_outside_are_skipped_unread(fleet, tmp_path, capfd):
    """A day folder and a robot folder that are links out of the logs, each holding a readable trial and the secret:
    skipped (named, not followed), the fleet's own robots and days answered as without them."""
    elsewhere = tmp_path / "elsewhere"
    trial = next(_days(fleet, "R02")[0].iterdir())
    for folder in (elsewhere / "day=2026-03-09", elsewhere / "robot=R09" / "day=2026-03-01"):
        folder.mkdir(parents=True)
        shutil.copy(trial, folder / trial.name)
        shutil.copy(tmp_path / "secret.csv", folder / "leak.csv")
    (fleet / "robot=R01" / "day=2026-03-09").symlink_to(elsewhere / "day=2026-03-09", target_is_directory=True)
    (fleet / "robot=R09").symlink_to(elsewhere / "robot=R09", target_is_directory=True)
    status, data, printed = _run(fleet, tmp_path / "out", capfd)
    assert status == 0, printed
    skipped = {s["file"]: s["reason"] for s in data["skipped"]}
    assert skipped == {"robot=R01/day=2026-03-09": layout.LINK, "robot=R09": layout.LINK}
    assert sorted(data["robots"]) == ["R01", "R02"] and "2026-03-09" not in data["robots"]["R01"]["days"]
    assert data["fleet"]["files"] == 6
    _nowhere(SECRET, tmp_path / "out", printed)


@pytest.mark.parametrize("swapped", ["file", "day folder"])
def test_a_link_put_in_after_the_layout_was_found_is_not_read(fleet, tmp_path, swapped):
    """A worker checks again when it opens a file: a trial (or its day folder) replaced by a link to a readable
    trial outside the logs between discovery and reading is skipped, unread."""
    found = layout.discover(str(fleet))
    file = found.files_of("R01", found.days("R01")[0])[0]
    target = Path(file.url)
    moved = tmp_path / "elsewhere" / (target.name if swapped == "file" else target.parent.name)
    moved.parent.mkdir()
    shutil.move(target if swapped == "file" else target.parent, moved)
    (target if swapped == "file" else target.parent).symlink_to(moved, target_is_directory=swapped != "file")
    job = tasks.Job(str(PLANAR.resolve()))
    s = tasks.setup(job.problem)
    choice = tasks.RobotChoice("R01", recommend.Choice(s.robot.default_estimator, "asked"))
    got = tasks.file_stats(job, file, choice)
    assert got.stats is None and got.reason == layout.LINK


def test_a_bad_files_reason_quotes_it_on_one_short_line(tmp_path):
    """A skip reason shows a bad file only as far as it says what is wrong: one line of at most
    `tasks.REASON_CHARS` characters, not the file's whole header (here 30 long column names)."""
    text = PLANAR.read_text()
    start, end = text.index("[data]\n"), text.index("[split]")
    problem = tmp_path / "named.toml"  # the planar arm, its time column mapped by name
    problem.write_text(text[:start] + '[data]\nheader = true\n\n[data.columns]\nt = "time"\n\n' + text[end:])
    names = [f"field_{i}_" + "x" * 40 for i in range(30)]
    bad = tmp_path / "logs" / "robot=A" / "day=2026-01-01" / "bad.csv"
    bad.parent.mkdir(parents=True)
    bad.write_text(",".join(names) + "\n" + ",".join(["1"] * 30) + "\n")
    job = tasks.Job(str(problem))
    (file,) = layout.discover(str(tmp_path / "logs")).files
    got = tasks.file_stats(job, file, tasks.RobotChoice("A", recommend.Choice("ols", "asked")))
    assert got.stats is None and "'time'" in got.reason
    assert names[-1] not in got.reason and "\n" not in got.reason and len(got.reason) <= tasks.REASON_CHARS


def _snapshot(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("form", ["path", "file://", "relative file://"])
def test_json_onto_a_log_file_is_refused_and_the_log_kept(fleet, tmp_path, monkeypatch, capfd, form):
    victim = next(_days(fleet, "R01")[0].iterdir())
    before = _snapshot(fleet)
    monkeypatch.chdir(tmp_path)
    logs = {"path": str(fleet), "file://": f"file://{fleet}", "relative file://": "file://logs"}[form]
    argv = ["fleet", "--problem", str(PLANAR), "--logs", logs, "--out", str(tmp_path / "report")]
    assert main([*argv, "--json", str(victim), "--workers", "1", "--no-progress"]) == 2
    err = capfd.readouterr().err
    assert "--json" in err and "inside --logs" in err, err
    assert _snapshot(fleet) == before and not (tmp_path / "report").exists()


@pytest.mark.parametrize("inside", ["", "robot=R01/report"])
@pytest.mark.parametrize("form", ["file://", "file:", "local://", "relative file://", "simplecache::file://"])
def test_out_inside_the_logs_through_a_url_is_refused_and_nothing_written(
    fleet, tmp_path, monkeypatch, capfd, form, inside
):
    """--out the logs' root itself (the reports would land beside the robot folders and break the next run) or a
    folder inside it, with --logs a URL or relative: refused before any work."""
    before = _snapshot(fleet)
    monkeypatch.chdir(tmp_path)
    logs = "file://logs" if form == "relative file://" else f"{form}{fleet}"
    out = fleet / inside if inside else fleet
    argv = ["fleet", "--problem", str(PLANAR), "--logs", logs, "--out", str(out)]
    assert main([*argv, "--json", str(tmp_path / "fleet.json"), "--workers", "1", "--no-progress"]) == 2
    err = capfd.readouterr().err
    assert "--out" in err and "inside --logs" in err, err
    assert _snapshot(fleet) == before and not (tmp_path / "fleet.json").exists()
    assert sorted(p.name for p in fleet.iterdir()) == ["_truth.json", "robot=R01", "robot=R02"]
    assert sorted(p.name for p in (fleet / "robot=R01").iterdir()) == [p.name for p in _days(fleet, "R01")]


def test_a_named_pipe_among_the_trials_is_skipped_not_read(tmp_path):
    # A FIFO named like a trial would block the worker that opens it: the scan lists it as skipped.
    day = tmp_path / "logs" / "robot=r1" / "day=2026-03-01"
    day.mkdir(parents=True)
    (day / "a.csv").write_text("t,q1,q2,tau1,tau2\n")
    os.mkfifo(day / "b.csv")
    found = layout.discover(str(tmp_path / "logs"))
    assert [f.name for f in found.files] == ["robot=r1/day=2026-03-01/a.csv"]
    assert any(s["file"].endswith("b.csv") and "not a regular file" in s["reason"] for s in found.skipped)
