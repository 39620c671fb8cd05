"""Compiled libraries are loaded only from the user's own code cache, and only when this tool built them there
(`ident_opt.cache.CodeCache`): a shared library planted where the tool used to look (`.cache/regressor/` beside a
URDF) or in the code cache itself (no record, a forged one, a world-writable folder) never runs, and the results
are the same; a genuine build is reused, not compiled again.

A planted library is a real one: its constructor writes a marker file the moment it is loaded (`dlopen`), so
"never runs" is checked by the marker's absence, whatever the library exports."""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ident_opt import cbuild
from ident_opt.arm.chain import ChainArm
from ident_opt.cache import cache_root, code_root
from ident_opt.cli import main

ROOT = Path(__file__).resolve().parents[1]
URDF = ROOT / "data" / "staubli_tx40" / "tx40.urdf"
JOINTS = tuple(f"joint_{i}" for i in range(1, 7))
COUPLINGS = (("joint_6", "joint_5", 1.0),)

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="the compiled path and the planted library use gcc")

PLANTED = r"""
#include <stdio.h>
__attribute__((constructor)) static void planted(void) {
    FILE *f = fopen("%s", "w");
    if (f) { fputs("the planted library ran\n", f); fclose(f); }
}
int urdf_regressor(void) { return 0; }
"""


def _arm(urdf: Path = URDF) -> ChainArm:
    return ChainArm(str(urdf), JOINTS, offsets=True, couplings=COUPLINGS)


def _states(n: int = 600):
    rng = np.random.default_rng(3)
    q, dq, ddq = (rng.uniform(-a, a, (n, 6)) for a in (np.pi, 2.0, 5.0))
    dq[:3] = 0.0
    return q, dq, ddq


@pytest.fixture(scope="module")
def genuine(tmp_path_factory):
    """The tx40 regressor as this tool builds it in a clean cache: its library's file name (how the tool names it
    for this model), its bytes, and Pinocchio's rows on `_states()` (the reference)."""
    clean = tmp_path_factory.mktemp("clean")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("IDENT_OPT_CACHE", str(clean / "cache"))
        assert _arm()._compiled_regressor is not None
        mp.setenv("IDENT_OPT_REGRESSOR", "pinocchio")
        expected = _arm().regressor(*_states())
    (lib,) = (clean / "cache" / "regressor").iterdir()
    return lib.name, lib.read_bytes(), expected


@pytest.fixture
def planted(tmp_path):
    """(the bytes of a shared library that writes `marker` when loaded, `marker`)."""
    marker = tmp_path / "PLANTED_LIBRARY_RAN"
    source = tmp_path / "planted.c"
    source.write_text(PLANTED % marker)
    lib = tmp_path / "libplanted.so"
    subprocess.run(["gcc", "-shared", "-fPIC", str(source), "-o", str(lib)], check=True, capture_output=True)
    return lib.read_bytes(), marker


def _plant(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    path.write_bytes(data)
    path.chmod(0o600)


def _sign(key: bytes, name: str, data: bytes) -> bytes:
    """A record as the tool writes them, under `key` (an attacker's, not the user's)."""
    tag = hmac.new(key, name.encode() + b"\0" + data, hashlib.sha256).hexdigest()
    return f"hmac-sha256 {tag}\n".encode()


def _project(tmp_path: Path) -> Path:
    """A downloaded dataset: a folder with a pyproject.toml, the tx40 URDF, 1500 rows of its recording, a problem."""
    project = tmp_path / "dataset"
    project.mkdir()
    (project / "pyproject.toml").write_text("")
    shutil.copy(URDF, project / "tx40.urdf")
    import gzip

    with gzip.open(ROOT / "data" / "staubli_tx40" / "tx40.csv.gz", "rt") as fh:
        (project / "tx40.csv").write_text("".join(next(fh) for _ in range(1501)))
    problem = (ROOT / "problems" / "staubli_tx40.toml").read_text().split("[output]")[0]
    problem = problem.replace("../data/staubli_tx40/tx40.urdf", "tx40.urdf")
    problem = problem.replace("../data/staubli_tx40/tx40.csv.gz", "tx40.csv")
    (project / "problem.toml").write_text(problem)
    return project


def test_a_library_planted_beside_the_urdf_never_runs(genuine, planted, tmp_path, monkeypatch, capsys):
    """A dataset shipping `.cache/regressor/<the exact library name>`: `ident-opt check` on it compiles its own
    library into the user's cache, never loads the planted one, and prints what a run without the compiled path
    prints."""
    name, _, _ = genuine
    data, marker = planted
    project = _project(tmp_path)
    monkeypatch.delenv("IDENT_OPT_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.chdir(project)
    old = cache_root(project / "tx40.urdf") / "regressor" / name
    assert old.parent == project.resolve() / ".cache" / "regressor"
    _plant(old, data)
    try:
        status = main(["check", "--problem", "problem.toml", "--json", str(tmp_path / "check.json")])
    except Exception:  # what a planted library exports may break the run too: the marker says whether it ran
        status = None
    assert not marker.exists(), "the planted library was loaded"
    assert status == 0
    assert code_root() == tmp_path / "xdg" / "ident-opt"
    assert (code_root() / "regressor" / name).read_bytes() != data  # the tool's own build
    capsys.readouterr()
    monkeypatch.setenv("IDENT_OPT_REGRESSOR", "pinocchio")
    assert main(["check", "--problem", "problem.toml", "--json", str(tmp_path / "reference.json")]) == 0
    got, want = (json.loads((tmp_path / f).read_text()) for f in ("check.json", "reference.json"))
    assert got["robot"]["base_parameters"] == want["robot"]["base_parameters"] == 58
    assert got == want


RECORDS = ["none", "sha256", "foreign key", "genuine record of other bytes", "signed link", "signed, others write"]


@pytest.mark.parametrize("record", RECORDS)
def test_a_library_planted_in_the_code_cache_never_runs(record, genuine, planted, tmp_path, monkeypatch):
    """The exact file the tool would load, in the user's own cache, with no record, a bare hash of its bytes, a
    record under another key, or the record of the genuine build; or even signed with the user's key but a link
    to a file elsewhere, or writable by others: rebuilt, replaced, never loaded."""
    name, genuine_bytes, expected = genuine
    data, marker = planted
    monkeypatch.setenv("IDENT_OPT_CACHE", str(tmp_path / "cache"))
    root = code_root()
    assert root == tmp_path / "cache"
    if record not in ("none", "sha256", "foreign key"):  # a real build first: the cache's key and records exist
        assert _arm()._compiled_regressor is not None
        assert (root / "regressor" / name).read_bytes() == genuine_bytes
    lib = root / "regressor" / name
    records = root / "records" / "regressor" / f"{name}.hmac"
    _plant(lib, data)
    if record == "sha256":
        _plant(records, f"hmac-sha256 {hashlib.sha256(data).hexdigest()}\n".encode())
    elif record == "foreign key":
        _plant(records, _sign(b"k" * 32, name, data))
    elif record.startswith("signed"):
        _plant(records, _sign((root / "key").read_bytes(), name, data))
        if record == "signed link":
            lib.unlink()
            _plant(tmp_path / "elsewhere.so", data)
            lib.symlink_to(tmp_path / "elsewhere.so")
        else:
            lib.chmod(0o666)
    Y = _arm().regressor(*_states())
    assert not marker.exists(), "the planted library was loaded"
    assert np.abs(Y - expected).max() <= 1e-10
    assert (root / "regressor" / name).read_bytes() == genuine_bytes  # replaced by the tool's own build


@pytest.mark.parametrize(("loose", "mode"), [("", 0o777), ("", 0o770), ("regressor", 0o777), ("records", 0o757)])
def test_a_cache_folder_others_can_write_is_not_trusted(loose, mode, genuine, planted, tmp_path, monkeypatch, capsys):
    """The user's cache folder (or one inside it) writable by group or others: whoever could write there may have
    left a library with a key and a record that match, so nothing is loaded from it (a warning says so); this run
    compiles into a private temporary folder and its results are unchanged."""
    name, _, expected = genuine
    data, marker = planted
    root = tmp_path / "shared"
    monkeypatch.setenv("IDENT_OPT_CACHE", str(root))
    key = b"attacker's key, 32 bytes long..."
    _plant(root / "key", key)
    _plant(root / "regressor" / name, data)
    _plant(root / "records" / "regressor" / f"{name}.hmac", _sign(key, name, data))
    (root / loose).chmod(mode)
    Y = _arm().regressor(*_states())
    assert not marker.exists(), "the planted library was loaded"
    assert np.abs(Y - expected).max() <= 1e-10
    err = capsys.readouterr().err
    assert "warning: not using the code cache" in err and "other users can write it" in err
    assert (root / "regressor" / name).read_bytes() == data  # left alone: not this tool's folder to repair


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() != 0, reason="only root can give a folder away")
def test_a_cache_folder_of_another_user_is_not_trusted(genuine, planted, tmp_path, monkeypatch, capsys):
    name, _, expected = genuine
    data, marker = planted
    root = tmp_path / "theirs"
    monkeypatch.setenv("IDENT_OPT_CACHE", str(root))
    key = b"k" * 32
    _plant(root / "key", key)
    _plant(root / "regressor" / name, data)
    _plant(root / "records" / "regressor" / f"{name}.hmac", _sign(key, name, data))
    for path in (root, *root.rglob("*")):
        os.chown(path, 65534, 65534, follow_symlinks=False)
    Y = _arm().regressor(*_states())
    assert not marker.exists(), "the planted library was loaded"
    assert np.abs(Y - expected).max() <= 1e-10
    assert "not to you" in capsys.readouterr().err


def test_a_genuine_build_is_reused(genuine, tmp_path, monkeypatch):
    """Built once, then loaded as is: by a new arm in this process (no compile, same file) and by another process
    that has no compiler at all."""
    name, genuine_bytes, expected = genuine
    monkeypatch.setenv("IDENT_OPT_CACHE", str(tmp_path / "cache"))
    compiled = []
    real = cbuild.compile_library

    def spy(*args, **kwargs):
        compiled.append(args)
        return real(*args, **kwargs)

    monkeypatch.setattr(cbuild, "compile_library", spy)
    assert _arm()._compiled_regressor is not None and len(compiled) == 1
    lib = code_root() / "regressor" / name
    before = lib.stat()
    assert lib.read_bytes() == genuine_bytes and before.st_mode & 0o077 == 0
    assert (code_root() / "regressor").stat().st_mode & 0o777 == 0o700
    Y = _arm().regressor(*_states())
    assert len(compiled) == 1, "the second arm compiled again"
    assert np.abs(Y - expected).max() <= 1e-10
    after = lib.stat()
    assert (after.st_ino, after.st_mtime_ns) == (before.st_ino, before.st_mtime_ns)
    env = {**os.environ, "IDENT_OPT_CACHE": str(tmp_path / "cache"), "CC": str(tmp_path / "no-such-cc")}
    probe = (
        "from tests.test_cache_security import _arm; "
        "print('compiled' if _arm()._compiled_regressor is not None else 'pinocchio')"
    )
    done = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "compiled"


RACE = """
import casadi as ca
from ident_opt.cbuild import cached_function
x = ca.SX.sym("x", 3)
f = cached_function(ca.Function("race_probe", [x], [2 * ca.sin(x) + x[0] * x[2]]), "race")
print(repr(float(f([0.5, 1.0, 1.5])[1])))
"""


def test_processes_racing_to_build_one_library_all_load_a_good_one(tmp_path):
    """Three processes build the same library into an empty cache at once: each loads a working one, and no
    temporary file is left behind."""
    env = {**os.environ, "IDENT_OPT_CACHE": str(tmp_path / "cache")}
    runs = [
        subprocess.Popen([sys.executable, "-c", RACE], cwd=ROOT, env=env, stdout=subprocess.PIPE, text=True)
        for _ in range(3)
    ]
    outputs = [run.communicate(timeout=120)[0] for run in runs]
    assert all(run.returncode == 0 for run in runs)
    want = 2 * np.sin(1.0) + 0.5 * 1.5
    assert all(abs(float(out) - want) < 1e-12 for out in outputs)
    files = [p.name for p in (tmp_path / "cache").rglob("*") if p.is_file()]
    assert not [f for f in files if f.endswith(".part")]
    assert sum(f.startswith("librace_probe_") and f.endswith(".so") for f in files) == 1
