"""Hostile paths: outputs and inputs that are not regular files. An output that is a device, a named pipe or a
socket (or a link to one) is refused with exit 2 naming the flag and the path, and is left as it was (the atomic
rename would replace the device node itself when run as root); a URDF ([robot] or [reference]) that is a named pipe
or a device, or larger than `MAX_URDF_BYTES`, is refused before it is opened; a ROS 2 bag whose storage file or
metadata.yaml is a named pipe is refused before SQLite opens it. Each command runs in a thread with a time limit: a
regression blocks on a pipe instead of hanging the suite (the pipe is then opened for writing to release it)."""

from __future__ import annotations

import os
import socket
import stat
import threading
import time
from pathlib import Path

import pytest
from rosbags.rosbag2.enums import StoragePlugin

from ident_opt import outputs
from ident_opt.arm.urdf import MAX_URDF_BYTES
from ident_opt.cli import main
from ident_opt.errors import InputError
from tests.test_hostile import small_problem
from tests.test_hostile_inputs import ARM3, _motion
from tests.test_rosbag import CSV, bag_problem, write_bag
from tests.test_urdf_arm import TWISTED

#: Seconds a refusal may take (each is a check before any work: well under a second when the suite is alone).
LIMIT_S = 60.0


def _release(fifo: Path) -> None:
    """Open `fifo` for writing and close it, so that a reader blocked in open() gets end-of-file."""
    for _ in range(50):
        try:
            os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        except OSError:  # ENXIO: no reader yet
            time.sleep(0.1)


def bounded(call, *fifos: Path, seconds: float = LIMIT_S):
    """`call()` in a thread; fails the test when it has not returned after `seconds` (blocked on one of `fifos`,
    which are then released). Returns what `call` returned, or raises what it raised."""
    done: list = []

    def target():
        try:
            done.append(("value", call()))
        except BaseException as exc:  # handed back to the test's thread
            done.append(("raised", exc))

    thread = threading.Thread(target=target, daemon=True)
    start = time.monotonic()
    thread.start()
    thread.join(seconds)
    if thread.is_alive():
        for fifo in fifos:
            _release(fifo)
        thread.join(5.0)
        pytest.fail(f"still running after {seconds:g} s (blocked on a named pipe?)")
    assert time.monotonic() - start < seconds
    kind, value = done[0]
    if kind == "raised":
        raise value
    return value


def exits_2_bounded(capsys, argv: list[str], *named: str, fifos: tuple[Path, ...] = ()) -> str:
    """`argv` exits 2 within `LIMIT_S` with an `ident-opt: error:` naming each of `named`, no traceback."""
    status = bounded(lambda: main(argv), *fifos)
    err = capsys.readouterr().err
    assert status == 2, err
    assert "ident-opt: error:" in err and "Traceback" not in err, err
    for word in named:
        assert word in err, (word, err)
    return err


def is_fifo(path: Path) -> bool:
    return stat.S_ISFIFO(os.lstat(path).st_mode)


def is_char_device(path: str | Path) -> bool:
    return stat.S_ISCHR(os.stat(path).st_mode)


@pytest.fixture
def work(tmp_path, monkeypatch) -> Path:
    """p.toml and small.csv (`tests.test_hostile.small_problem`) in the current folder."""
    small_problem(tmp_path)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _special(folder: Path, kind: str, name: str = "out.json") -> tuple[str, list]:
    """An output path `name` of `kind` in `folder` (the current one): (the word its refusal names, what to close
    after)."""
    path, keep = folder / name, []
    if kind == "fifo":
        os.mkfifo(path)
        return "named pipe", keep
    if kind == "socket":
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.bind(name)  # relative: the current folder (a socket's path is at most 107 bytes)
        keep.append(sock)
        return "socket", keep
    if kind == "link-to-dev-null":
        path.symlink_to("/dev/null")
        return "character device", keep
    if kind == "link-to-fifo":
        os.mkfifo(folder / "pipe")
        path.symlink_to("pipe")
        return "named pipe", keep
    raise AssertionError(kind)


def _unchanged(folder: Path, kind: str, name: str = "out.json") -> None:
    """The special output of `_special` is still what it was, and no temporary file is left beside it."""
    path = folder / name
    if kind == "fifo":
        assert is_fifo(path)
    elif kind == "socket":
        assert stat.S_ISSOCK(os.lstat(path).st_mode)
    else:
        assert path.is_symlink()
        assert is_char_device(path) if kind == "link-to-dev-null" else is_fifo(folder / "pipe")
    assert is_char_device("/dev/null")
    assert not [p.name for p in folder.iterdir() if p.name.startswith(f".{name}.")]


# ------------------------------------------------------------------------------------------------------- outputs
KINDS = ["fifo", "socket", "link-to-dev-null", "link-to-fifo"]


@pytest.mark.parametrize("kind", KINDS)
def test_a_json_output_that_is_not_a_regular_file_is_refused_and_left_alone(work, capsys, kind):
    word, keep = _special(work, kind)
    try:
        exits_2_bounded(capsys, ["check", "--problem", "p.toml", "--json", "out.json"], "--json", "out.json", word)
        _unchanged(work, kind)
    finally:
        for sock in keep:
            sock.close()


@pytest.mark.parametrize("kind", ["fifo", "link-to-dev-null"])
def test_a_file_out_that_is_not_a_regular_file_is_refused_before_any_work(work, capsys, kind):
    word, _ = _special(work, kind, "trial.csv")
    argv = ["simulate", "--problem", "p.toml", "--out", "trial.csv", "--duration", "1", "--no-noise"]
    err = exits_2_bounded(capsys, argv, "--out", "trial.csv", word)
    assert "simulate:" not in err  # refused before the simulation started
    _unchanged(work, kind, "trial.csv")


def test_an_out_folder_that_is_a_fifo_is_refused_naming_it(work, capsys):
    os.mkfifo(work / "r")
    exits_2_bounded(
        capsys, ["compare", "--problem", "p.toml", "--out", "r", "--no-progress"], "--out", "r", "named pipe"
    )
    assert is_fifo(work / "r")


def test_dev_null_as_json_is_refused_and_stays_a_device(work, capsys):
    exits_2_bounded(capsys, ["check", "--problem", "p.toml", "--json", "/dev/null"], "--json", "/dev/null", "device")
    assert is_char_device("/dev/null")


def test_every_write_refuses_a_fifo_without_opening_it(tmp_path):
    """The choke point every writer goes through (`atomic_path`: write_text, write_bytes, figures; `claim`; the
    owned-files guard) refuses a pipe, inside a run or not, and leaves no temporary file."""
    fifo = tmp_path / "x.md"
    os.mkfifo(fifo)

    def in_a_run(write):
        def call():
            with outputs.run():
                write()

        return call

    writes = [
        lambda: outputs.write_text(fifo, "x"),
        lambda: outputs.write_bytes(fifo, b"x"),
        in_a_run(lambda: outputs.write_text(fifo, "x")),
        in_a_run(lambda: outputs.claim([fifo])),
        lambda: outputs.guard_owned(tmp_path, ["x.md"]),
    ]
    for write in writes:
        with pytest.raises(InputError, match=r"x\.md: exists and is a named pipe"):
            bounded(write, fifo)
        assert is_fifo(fifo)
        assert sorted(p.name for p in tmp_path.iterdir()) == ["x.md"]


def test_the_owned_files_record_is_never_read_from_a_pipe(tmp_path):
    os.mkfifo(tmp_path / outputs.OWNED)
    with pytest.raises(InputError, match="named pipe"):
        bounded(lambda: outputs.guard_owned(tmp_path, ["a.c"]), tmp_path / outputs.OWNED)
    assert is_fifo(tmp_path / outputs.OWNED)


def test_a_regular_output_and_a_link_to_one_are_still_written(work, capsys):
    (work / "target.json").write_text("old")
    (work / "link.json").symlink_to("target.json")
    assert bounded(lambda: main(["check", "--problem", "p.toml", "--json", "plain.json"])) == 0
    assert bounded(lambda: main(["check", "--problem", "p.toml", "--json", "link.json"])) == 0
    assert (work / "plain.json").read_text().startswith("{") and (work / "link.json").read_text().startswith("{")


# ---------------------------------------------------------------------------------------------------------- URDFs
@pytest.fixture
def arm3(tmp_path, monkeypatch) -> Path:
    """arm.urdf (`TWISTED`), trial.csv and p.toml (3 joints), as the current folder."""
    (tmp_path / "arm.urdf").write_text(TWISTED)
    _motion().to_csv(tmp_path / "trial.csv", index=False)
    (tmp_path / "p.toml").write_text(ARM3 + '[data]\ntrials = ["trial.csv"]\n')
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_a_urdf_that_is_a_fifo_is_refused_without_blocking(arm3, capsys):
    (arm3 / "arm.urdf").unlink()
    os.mkfifo(arm3 / "arm.urdf")
    exits_2_bounded(capsys, ["check", "--problem", "p.toml"], "arm.urdf", "named pipe", fifos=(arm3 / "arm.urdf",))
    assert is_fifo(arm3 / "arm.urdf")


def test_a_reference_urdf_that_is_a_fifo_is_refused_without_blocking(arm3, capsys):
    os.mkfifo(arm3 / "ref.urdf")
    (arm3 / "p.toml").write_text(
        ARM3 + '[data]\ntrials = ["trial.csv"]\n[reference]\nlabel = "published"\nurdf = "ref.urdf"\n'
    )
    exits_2_bounded(
        capsys, ["check", "--problem", "p.toml"], "ref.urdf", "[reference]", "named pipe", fifos=(arm3 / "ref.urdf",)
    )


@pytest.mark.parametrize("how", ["absolute", "link"])
def test_a_urdf_that_is_dev_zero_is_refused_before_reading(arm3, capsys, how):
    if how == "absolute":
        (arm3 / "p.toml").write_text(ARM3.replace('"arm.urdf"', '"/dev/zero"'))
    else:
        (arm3 / "arm.urdf").unlink()
        (arm3 / "arm.urdf").symlink_to("/dev/zero")
    exits_2_bounded(
        capsys, ["check", "--problem", "p.toml"], "/dev/zero" if how == "absolute" else "arm.urdf", "character device"
    )


def test_a_urdf_larger_than_the_limit_is_refused_naming_the_limit(arm3, capsys):
    with open(arm3 / "arm.urdf", "r+b") as file:  # sparse: no disk space used
        file.truncate(MAX_URDF_BYTES + 1)
    exits_2_bounded(capsys, ["check", "--problem", "p.toml"], "arm.urdf", f"{MAX_URDF_BYTES // 2**20} MiB")


def test_a_urdf_folder_is_refused(arm3, capsys):
    (arm3 / "arm.urdf").unlink()
    (arm3 / "arm.urdf").mkdir()
    exits_2_bounded(capsys, ["check", "--problem", "p.toml"], "arm.urdf", "is a folder, not a regular file")


# ----------------------------------------------------------------------------------------------------- ROS 2 bags
@pytest.fixture
def sqlite_bag(tmp_path, monkeypatch) -> Path:
    """A ROS 2 bag `b` (SQLite3 storage) of 50 DFKI samples and bag.toml reading it, in the current folder."""
    import pandas as pd

    write_bag(tmp_path / "b", pd.read_csv(CSV).iloc[:50], StoragePlugin.SQLITE3)
    bag_problem(tmp_path)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _fifo_instead(path: Path) -> Path:
    path.unlink()
    os.mkfifo(path)
    return path


@pytest.mark.parametrize("given", ["folder", "storage-file"])
def test_a_bag_whose_db3_is_a_fifo_is_refused_before_sqlite_opens_it(sqlite_bag, capsys, given):
    db3 = _fifo_instead(next((sqlite_bag / "b").glob("*.db3")))
    data = "b" if given == "folder" else f"b/{db3.name}"
    exits_2_bounded(capsys, ["check", "--problem", "bag.toml", "--data", data], db3.name, "named pipe", fifos=(db3,))
    assert is_fifo(db3)


def test_a_bag_whose_metadata_is_a_fifo_is_refused(sqlite_bag, capsys):
    metadata = _fifo_instead(sqlite_bag / "b" / "metadata.yaml")
    exits_2_bounded(
        capsys, ["check", "--problem", "bag.toml", "--data", "b"], "metadata.yaml", "named pipe", fifos=(metadata,)
    )


def test_a_bag_whose_db3_links_to_dev_zero_is_refused(sqlite_bag, capsys):
    db3 = next((sqlite_bag / "b").glob("*.db3"))
    db3.unlink()
    db3.symlink_to("/dev/zero")
    exits_2_bounded(capsys, ["check", "--problem", "bag.toml", "--data", "b"], db3.name, "character device")


def test_a_sqlite_bag_still_reads(sqlite_bag, capsys):
    assert bounded(lambda: main(["check", "--problem", "bag.toml", "--data", "b", "--json", "c.json"])) == 0
    assert (sqlite_bag / "c.json").is_file()
