"""Hostile input, fourth round (issue 52), the command line: each bad input is exit 2 with one line naming the
culprit, no traceback, nothing written (not even half a file) and the inputs unchanged.

1. `simulate --out x.parquet` is refused before anything is simulated.
2. `excite --duration 3600 --rate 10000` (16 GiB of samples) is refused before any work, naming both flags and the
   memory bound.
3. Paths: an output name over NAME_MAX or a path over PATH_MAX (and a derived name, the truth file); an input so;
   a name of exactly 255 bytes still works (its temporary name fits); a problem file that is a folder or cannot be
   read; a full disk while a figure is saved (`compare`, and the figure writer `fleet` uses).
4. `codegen --parameters` with an absurd finite value (a1 = 1e308) or a name the model does not have.
5. Messages: the fit, not the URDF, named for an OLS link of mass 0 (`export`); the arm's joint count in a
   malformed per-joint effect value; a parquet file name that is not UTF-8; the codegen README's compile lines
   (built as written).
6. The shipped TX40 problem simulates.
7. Every writer goes through `outputs.atomic_path` (a scan of the sources).

The full disk is real, never a monkeypatched writer: a 64 kB tmpfs (as root, where mounting is allowed; else
skipped) and, for any user, a file-size limit (RLIMIT_FSIZE, a write then fails with EFBIG in the kernel) on a
child process running the command line.
"""

from __future__ import annotations

import json
import os
import re
import resource
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ident_opt import outputs
from ident_opt.cli import main
from ident_opt.errors import InputError
from tests.test_hostile import small_problem, snapshot

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = ROOT / "problems"
TUDOR = str(PROBLEMS / "tudor_2dof.toml")
KUKA = str(PROBLEMS / "kuka_lwr4.toml")

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")


def refused(capsys, argv: list[str], *named: str) -> str:
    """`argv` exits 2 with one `ident-opt: error:` line naming each of `named`, no traceback; returns the line."""
    status = main(argv)
    err = capsys.readouterr().err
    assert status == 2, err
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.startswith("ident-opt: error:")]
    assert len(lines) == 1, err
    for word in named:
        assert word in lines[0], (word, lines[0])
    return lines[0]


def inputs_unchanged(*paths: Path):
    """The bytes of `paths` now, to compare after a run."""
    return {p: p.read_bytes() for p in paths}


# ---------------------------------------------------------------------------------------------- 1. simulate


def test_simulate_refuses_a_parquet_name_before_simulating(tmp_path, capsys):
    """Before: the whole simulation ran (its progress bar on stderr), then the suffix was refused."""
    start = time.monotonic()
    line = refused(
        capsys,
        ["simulate", "--problem", TUDOR, "--out", str(tmp_path / "x.parquet"), "--duration", "60"],
        "--out",
        "x.parquet",
        "*.csv",
    )
    assert time.monotonic() - start < 30
    assert ".parquet" in line
    assert list(tmp_path.iterdir()) == []


def test_simulate_refuses_a_truth_file_name_too_long_before_simulating(tmp_path, capsys):
    """D.csv of 254 bytes fits, its D.truth.json (261 bytes) does not: refused before the simulation, named."""
    out = tmp_path / ("t" * 250 + ".csv")
    line = refused(capsys, ["simulate", "--problem", TUDOR, "--out", str(out), "--duration", "60"], "truth file")
    assert "NAME_MAX" in line and "261 bytes" in line
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------- 2. excite


def test_excite_refuses_an_output_too_large_for_memory_before_any_work(tmp_path, capsys):
    """An hour at 10 kHz is 3.6e7 samples, about 16 GiB at the measured ~480 B a sample of a 2-joint arm; before,
    nothing checked it and the run asked for 20 GB hours later. Now: exit 2 within seconds, both flags named with
    the bound, nothing written."""
    from ident_opt.excitation.excite import MEMORY_CAP, check_output_size, output_bytes

    assert output_bytes(2, 3600, 10000) > MEMORY_CAP  # over the cap on any machine: the refusal is deterministic
    check_output_size(2, 20.0, 1000.0)  # the default request passes
    start = time.monotonic()
    out = tmp_path / "t.csv"
    line = refused(
        capsys,
        ["excite", "--problem", TUDOR, "--out", str(out), "--duration", "3600", "--rate", "10000"],
        "--duration",
        "--rate",
        "GiB",
        "the bound is",
    )
    assert time.monotonic() - start < 30
    assert "36,000,000 samples" in line
    assert list(tmp_path.iterdir()) == []


def test_excite_memory_bound_is_documented():
    text = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    assert "The output's memory is checked before any work" in text and "8 GiB" in text


# ---------------------------------------------------------------------------------------------- 3. paths


LONG = "a" * 300


@pytest.mark.parametrize(
    "argv, flag",
    [
        (["simulate", "--problem", TUDOR, "--out", f"{LONG}.csv"], "--out"),
        (["check", "--problem", TUDOR, "--json", f"{LONG}.json"], "--json"),
        (["compare", "--problem", TUDOR, "--out", LONG], "--out"),
        (["excite", "--problem", TUDOR, "--out", f"{LONG}.csv"], "--out"),
        (["export", "--problem", TUDOR, "--format", "urdf", "--out", f"{LONG}.urdf"], "--out"),
        (["codegen", "--problem", TUDOR, "--out", f"{LONG}/c"], "--out"),
    ],
    ids=["simulate", "check-json", "compare", "excite", "export", "codegen"],
)
def test_an_output_name_over_name_max_is_exit_2(tmp_path, monkeypatch, capsys, argv, flag):
    """Before: a traceback (OSError: [Errno 36] File name too long) from the first look-up of the path."""
    monkeypatch.chdir(tmp_path)
    line = refused(capsys, argv, flag, "NAME_MAX", "bytes long")
    assert "…" in line  # the name is shown shortened, on one line
    assert list(tmp_path.iterdir()) == []


def test_an_output_path_over_path_max_is_exit_2(tmp_path, capsys):
    deep = tmp_path.joinpath(*["b" * 200] * 21)  # > 4096 bytes, every name within NAME_MAX
    refused(capsys, ["compare", "--problem", TUDOR, "--out", str(deep)], "--out", "PATH_MAX")
    refused(capsys, ["check", "--problem", TUDOR, "--json", str(deep / "c.json")], "--json", "PATH_MAX")
    assert list(tmp_path.iterdir()) == []


def test_an_output_name_of_255_bytes_is_written(tmp_path, capsys):
    """The longest name the file system takes works: its temporary name beside it is shortened to fit (before, the
    temporary name `.<name>.XXXXXXXX.tmp.json` was over NAME_MAX and the write failed with a traceback)."""
    problem = small_problem(tmp_path)
    out = tmp_path / ("j" * 250 + ".json")
    assert len(out.name) == 255
    assert main(["check", "--problem", str(problem), "--json", str(out)]) == 0, capsys.readouterr().err
    assert json.loads(out.read_text())
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([out.name, "p.toml", "small.csv"])  # no temporary


def test_an_input_name_over_name_max_is_exit_2(tmp_path, capsys):
    """Before: OSError tracebacks (ENAMETOOLONG from the first look-up) for the problem, --data and a trial the
    problem lists."""
    refused(capsys, ["check", "--problem", str(tmp_path / f"{LONG}.toml")], "NAME_MAX", "cannot be read")
    refused(capsys, ["check", "--problem", TUDOR, "--data", str(tmp_path / LONG / "d.csv")], "--data", "NAME_MAX")
    problem = small_problem(tmp_path)
    problem.write_text(problem.read_text().replace('"small.csv"', f'"{LONG}.csv"'))
    refused(capsys, ["check", "--problem", str(problem)], "p.toml: [data]", "NAME_MAX", "cannot be read")


def test_a_folder_given_as_the_problem_is_exit_2(tmp_path, capsys):
    """Before: "problem file not found" for a folder that exists."""
    refused(capsys, ["check", "--problem", str(tmp_path)], str(tmp_path), "is a folder", "not a problem file")


@pytest.mark.skipif(not Path("/proc/self/mem").exists(), reason="needs Linux's /proc")
def test_a_problem_file_whose_read_fails_is_exit_2(capsys):
    """A regular file whose read fails in the kernel, for any user (root too): /proc/self/mem at offset 0 (the
    unmapped first page) gives EIO. Before: an OSError traceback."""
    refused(capsys, ["check", "--problem", "/proc/self/mem"], "/proc/self/mem", "cannot read the problem file")


def test_an_unreadable_problem_file_is_exit_2(tmp_path, capsys):
    """chmod 000: "cannot read", not a PermissionError traceback. Root reads it anyway (CAP_DAC_OVERRIDE), and the
    venv's interpreter is not reachable for an unprivileged user here: the /proc/self/mem test above covers root."""
    path = tmp_path / "p.toml"
    path.write_text((PROBLEMS / "tudor_2dof.toml").read_text())
    path.chmod(0)
    try:
        if os.access(path, os.R_OK):
            pytest.skip("this user reads a mode-000 file (root)")
        refused(capsys, ["check", "--problem", str(path)], str(path), "cannot read the problem file")
    finally:
        path.chmod(0o644)


def _run_cli(argv: list[str], fsize: int | None = None, cwd: Path | None = None) -> tuple[int, str]:
    """`ident-opt argv` in a child process (optionally with RLIMIT_FSIZE = `fsize` bytes): (status, stderr)."""

    def limit() -> None:
        if fsize is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    done = subprocess.run(
        [sys.executable, "-m", "ident_opt", *argv],
        preexec_fn=limit,
        capture_output=True,
        text=True,
        cwd=cwd or ROOT,
        timeout=300,
    )
    return done.returncode, done.stderr


@pytest.fixture
def tiny_disk(tmp_path):
    """A 16 kB tmpfs mounted on tmp_path/disk (root only, and only where mounting is allowed), unmounted after."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a tmpfs needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=16k", "tmpfs", str(disk)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode(errors='replace').strip()}")
    try:
        yield disk
    finally:
        subprocess.run(["umount", str(disk)], check=False)


def test_compare_on_a_full_disk_is_exit_2_with_nothing_left(tmp_path, tiny_disk, capsys):
    """The seed heatmap (about 30 kB on this problem) does not fit a 16 kB file system: ENOSPC while the figure is
    saved. Before: an OSError traceback from PIL. Now: exit 2 naming the figure, the output folder removed again."""
    problem = small_problem(tmp_path)
    before = inputs_unchanged(problem, tmp_path / "small.csv")
    line = refused(
        capsys,
        ["compare", "--problem", str(problem), "--out", str(tiny_disk / "cmp"), "--no-progress"],
        "compare_seeds.png",
        "no space left on the device",
    )
    assert "nothing of it was left behind" in line
    assert list(tiny_disk.iterdir()) == []  # the folder it created, and every file, removed
    assert inputs_unchanged(problem, tmp_path / "small.csv") == before


def test_a_figure_on_a_full_disk_is_an_input_error_with_nothing_left(tiny_disk):
    """The figure writer of `fleet` (figures.daily_figure, through `_save`) on a full tmpfs: InputError naming the
    file; no temporary file left."""
    import matplotlib.pyplot as plt

    from ident_opt.report.figures import _save

    fig, ax = plt.subplots(figsize=(20, 20))
    ax.imshow(np.random.default_rng(0).random((800, 800)))  # noise: a PNG far over 16 kB
    target = tiny_disk / "fleet_R01.png"
    with pytest.raises(InputError, match=r"fleet_R01.png: cannot write \(no space left on the device\)"):
        _save(fig, target)
    assert list(tiny_disk.iterdir()) == []


def test_compare_over_a_file_size_limit_is_exit_2_with_nothing_left(tmp_path, capsys):
    """For any user: a file-size limit (RLIMIT_FSIZE) on a child process below the size of the seed heatmap, so the
    kernel fails the figure's write (EFBIG) as a full disk would. A first run without the limit sizes the figure
    (and fills the code cache, whose files the limited run then only reads). Before: a traceback, exit 1."""
    problem = small_problem(tmp_path)
    argv = ["compare", "--problem", str(problem), "--no-progress", "--out"]
    assert main([*argv, str(tmp_path / "full")]) == 0, capsys.readouterr().err
    figure = (tmp_path / "full" / "compare_seeds.png").stat().st_size
    # index.html embeds the figure and is written after it: the figure's write fails first
    text = max(p.stat().st_size for p in (tmp_path / "full").glob("*.*") if p.suffix not in (".png", ".html"))
    assert text < figure // 2, (text, figure)  # the text outputs fit under the limit, the figure does not
    out = tmp_path / "cmp"
    status, err = _run_cli([*argv, str(out)], figure // 2)
    assert status == 2, err
    assert "Traceback" not in err and "compare_seeds.png: cannot write" in err, err
    assert "file size limit" in err
    assert not out.exists()


# ---------------------------------------------------------------------------------------------- 4. codegen


def _parameters_file(folder: Path, name: str, **changes: float) -> Path:
    """A parameters.json of the planar arm's rigid model (its datasheet values) with `changes`, and a GMR, so that
    `codegen --parameters` reads no data."""
    from ident_opt.problem import load_problem

    robot = load_problem(TUDOR).robot
    model = robot.model()
    arm, pi = robot.datasheets()["physical"]
    values = dict(zip(arm.names, map(float, pi)))
    params = {k: values[k] for k in model.names} | changes
    d = 6
    gmr = {"weights": [1.0], "means": [[0.0] * (d + 2)], "covariances": [np.eye(d + 2).tolist()]}
    path = folder / name
    path.write_text(json.dumps({"parameters": params, "estimator": "test", "model": {"extensions": []}, "gmr": gmr}))
    return path


@needs_gcc
def test_codegen_refuses_a_parameter_whose_torques_overflow(tmp_path, capsys):
    """a1 = 1e308 is finite, but its torques are inf: before, overflow warnings, "the compiled code disagrees: nan",
    exit 1 and the generated files left in --out. Now exit 2 naming a1, --out never created."""
    path = _parameters_file(tmp_path, "p.json", a1=1e308)
    before = inputs_unchanged(path)
    out = tmp_path / "c"
    line = refused(
        capsys, ["codegen", "--problem", TUDOR, "--parameters", str(path), "--out", str(out)], "a1", "p.json"
    )
    assert "1e+308" in line and "overflow" in line
    assert not out.exists() and inputs_unchanged(path) == before


@needs_gcc
def test_codegen_refuses_unknown_and_non_numeric_parameters(tmp_path, capsys):
    """Before: a name the model does not have was silently left out of the generated code."""
    out = tmp_path / "c"
    unknown = _parameters_file(tmp_path, "u.json", bogus=3.0, a9=1.0)
    line = refused(capsys, ["codegen", "--problem", TUDOR, "--parameters", str(unknown), "--out", str(out)], "'bogus'")
    assert "'a9'" in line
    text = _parameters_file(tmp_path, "t.json")
    raw = json.loads(text.read_text())
    raw["parameters"]["fv1"] = "0.5"
    text.write_text(json.dumps(raw))
    refused(capsys, ["codegen", "--problem", TUDOR, "--parameters", str(text), "--out", str(out)], "fv1", "a number")
    assert not out.exists()


@needs_gcc
def test_codegen_readme_compile_lines_work_as_written(tmp_path, capsys):
    """The generated README lists the pi_update files, and every compile line it gives (the libraries', the two
    examples', the online update's example with its -D_POSIX_C_SOURCE) builds as written, with -Werror, in a copy
    of the output folder; the examples run."""
    problem = small_problem(tmp_path)
    out = tmp_path / "c"
    argv = ["codegen", "--problem", str(problem), "--out", str(out), "--components", "2", "--estimator", "ols"]
    assert main(argv) == 0, capsys.readouterr().err
    readme = (out / "README.md").read_text(encoding="utf-8")
    for name in ("pi_update.c", "pi_update_casadi.h", "libpi_update.so", "pi_update_main.c", "pi_update_samples.csv"):
        assert f"`{name}`" in readme, name
    assert "-D_POSIX_C_SOURCE=199309L" in readme
    inline = re.findall(r"\(`(cc [^`]*)`\)", readme)  # the libraries' lines, in the table of files
    blocks = [line.strip() for line in readme.splitlines() if line.startswith("    cc ") or line.startswith("    ./")]
    assert len(inline) == 2 and len(blocks) == 4, (inline, blocks)
    build = tmp_path / "build"
    shutil.copytree(out, build)
    for product in ("libident_opt_model.so", "libpi_update.so", "pi_update_example"):
        (build / product).unlink()  # built again below, from the README's lines alone
    cc = "cc" if shutil.which("cc") else "gcc"
    for line in [*inline, *blocks]:
        words = shlex.split(line)
        words = [cc, *words[1:]] if words[0] == "cc" else words
        done = subprocess.run(words, cwd=build, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, (line, done.stderr)
    assert (
        json.loads(
            subprocess.run(
                ["./pi_update_example", "pi_update_samples.csv"], cwd=build, capture_output=True, text=True, check=True
            ).stdout
        )["samples"]
        > 0
    )
    assert "tau_hat" in subprocess.run(["./example"], cwd=build, capture_output=True, text=True, check=True).stdout


# ---------------------------------------------------------------------------------------------- 5. messages


def test_export_of_an_ols_link_without_mass_names_the_fit(tmp_path, capsys):
    """Before: "kuka_lwr4.urdf: link 'lwr_1_link': mass 0 kg …", the URDF blamed for what the OLS fit gave."""
    data = str(ROOT / "data" / "kuka_lwr4" / "measurements_1.csv.gz")
    out = tmp_path / "k.xml"
    argv = ["export", "--problem", KUKA, "--data", data, "--estimator", "ols", "--format", "mjcf", "--out", str(out)]
    line = refused(capsys, argv, "the ols fit gave link 'lwr_1_link' a mass of 0 kg", "--estimator consistent")
    assert "kuka_lwr4.urdf" not in line
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "problem, count",
    [(KUKA, "a bracketed list of 7 ([v1,…,v7]"), (TUDOR, "a pair [v1,v2]")],
    ids=["7 joints", "2 joints"],
)
def test_a_malformed_per_joint_effect_value_says_the_arms_count(tmp_path, capsys, problem, count):
    """Before: "must be [v1,v2]" on the 7-joint KUKA too."""
    argv = ["simulate", "--problem", problem, "--out", str(tmp_path / "t.csv"), "--effect", "joint_offset:offset=[]"]
    line = refused(capsys, argv, "joint_offset", "'offset'", count)
    assert "got '[]'" in line
    assert list(tmp_path.iterdir()) == []


def test_a_parquet_file_whose_name_is_not_utf8_is_read_or_refused_clearly(tmp_path, capsys):
    """Before: "cannot read the file ('utf-8' codec can't encode character '\\udcff' …)": pyarrow's failure to
    encode the name, shown as the reason. The file is a valid trial: it should be read (or, if refused, the message
    show the name with a replacement character and say why)."""
    frame = pd.read_csv(ROOT / "data" / "merit" / "exp1.csv", header=None, nrows=3000).iloc[1500:]
    frame.columns = [f"c{k}" for k in range(frame.shape[1])]
    good = tmp_path / "good.parquet"
    frame.to_parquet(good, index=False)
    name = os.fsdecode(b"\xfftrial.parquet")
    os.rename(good, tmp_path / name)
    status = main(["check", "--problem", str(small_problem(tmp_path)), "--data", str(tmp_path / name)])
    err = capsys.readouterr().err
    assert "codec" not in err and "\\udcff" not in err, err
    assert status == 0 or ("\ufffdtrial.parquet" in err and status == 2), err


# ---------------------------------------------------------------------------------------------- 6. the TX40


def test_the_shipped_tx40_problem_simulates(tmp_path, capsys):
    """Before: "joint_6 has no inertia about its axis" (its URDF's link 6 is a point mass and the problem gave no
    rotor). The problem now gives motor 6's reflected rotor inertia (FIGAROH's nominal Iam6, see the file)."""
    out = tmp_path / "tx40.csv"
    argv = ["simulate", "--problem", str(PROBLEMS / "staubli_tx40.toml"), "--out", str(out), "--duration", "5"]
    assert main(argv) == 0, capsys.readouterr().err
    frame = pd.read_csv(out)
    assert len(frame) == 500 and {f"tau{j}" for j in range(1, 7)} <= set(frame.columns)
    assert np.isfinite(frame.to_numpy(dtype=float)).all()
    truth = json.loads(out.with_name("tx40.truth.json").read_text())
    assert truth["pi_datasheet"]["ia_joint_6"] == pytest.approx(0.00964)


# ---------------------------------------------------------------------------------------------- 7. atomic writes

#: Writers allowed outside `outputs.atomic_path`: (file, pattern, why).
ALLOWED = {
    ("ident_opt/outputs.py", "write_bytes("): "the atomic writer itself (into its temporary file)",
    ("ident_opt/report/fleet.py", "to_parquet("): "into a BytesIO, then outputs.write_bytes",
    ("ident_opt/simulator/unseen.py", "to_csv("): "scratch: a private TemporaryDirectory, read back at once",
    ("ident_opt/excitation/proof.py", "to_csv("): "scratch: a private TemporaryDirectory for the simulator",
    ("ident_opt/evaluation/cutoff_study.py", "to_csv("): "scratch: a private TemporaryDirectory, read back at once",
    ("ident_opt/fleet/simulated.py", "write_text("): "into the staging folder renamed onto --out when complete",
    ("ident_opt/fleet/simulated.py", "to_csv("): "into the staging folder renamed onto --out when complete",
    ("ident_opt/fleet/simulated.py", "to_parquet("): "into the staging folder renamed onto --out when complete",
}
WRITERS = ("savefig(", "to_csv(", "to_parquet(", "to_excel(", "write_text(", "write_bytes(", "np.savetxt(", "np.save(")


def test_every_writer_goes_through_the_atomic_path():
    """A write whose target is not the temporary path of `outputs.atomic_path` (named `tmp`), a buffer, or one of
    `ALLOWED` is a file a failed run would leave half-written."""
    found = []
    for path in sorted((ROOT / "ident_opt").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            code = line.split("#")[0]
            for writer in WRITERS:
                at = code.find("." + writer) if not writer.startswith("np.") else code.find(writer)
                if at < 0 or code.lstrip().startswith(("def ", '"', "'")):
                    continue
                if "outputs." in code[max(0, at - 8) : at + 1] or re.search(r"\btmp\b|buffer", code):
                    continue
                if (rel, writer) in ALLOWED:
                    continue
                found.append(f"{rel}:{number}: {line.strip()}")
    assert not found, "writes that bypass outputs.atomic_path:\n" + "\n".join(found)


def test_outputs_temporary_names_fit_and_oserrors_are_input_errors(tmp_path):
    """`atomic_path` at function level: a 255-byte name is written (temporary name shortened), an OSError of the
    body is an InputError naming the file, and its temporary file is gone."""
    long = tmp_path / ("n" * 251 + ".txt")
    outputs.write_text(long, "ok\n")
    assert long.read_text() == "ok\n"
    target = tmp_path / "x.csv"
    with pytest.raises(InputError, match=r"x\.csv: cannot write"), outputs.atomic_path(target) as tmp:
        tmp.write_text("half")
        raise OSError(28, "No space left on device")
    assert sorted(p.name for p in tmp_path.iterdir()) == [long.name]
    assert snapshot(tmp_path)[long.name][0] == b"ok\n"


# ---------------------------------------------------------------------------------------------- found by make fuzz
def test_export_to_a_name_that_is_not_utf8_is_written(tmp_path, capsys):
    """Before: UnicodeEncodeError (the sidecar names its description, and the name held a surrogate escape)."""
    out = tmp_path / os.fsdecode(b"\xff\xfe.urdf")
    data = str(ROOT / "data" / "dfki" / "trajectory_00.csv.gz")  # one trial: quick
    argv = [
        "export",
        "--problem",
        str(PROBLEMS / "dfki_c0.toml"),
        "--data",
        data,
        "--format",
        "urdf",
        "--out",
        str(out),
    ]
    assert main(argv) == 0, capsys.readouterr().err
    side = Path(str(out) + ".json")
    record = json.loads(side.read_bytes().decode("utf-8"))  # valid UTF-8, the name escaped
    assert record["urdf"] == out.name and out.stat().st_size > 0  # escaped in the file, the same name read back


@needs_gcc
def test_codegen_into_the_current_folder(tmp_path, monkeypatch, capsys):
    """Before: `--out .` ran the example program by its bare name, looked up on PATH: FileNotFoundError."""
    monkeypatch.chdir(tmp_path)
    assert main(["codegen", "--problem", TUDOR, "--out", "."]) == 0, capsys.readouterr().err
    assert (tmp_path / "parameters.json").is_file()


def test_codegen_into_a_folder_whose_name_is_not_utf8_is_refused_first(tmp_path, capsys):
    """Before: UnicodeDecodeError from the compiler's messages (CasADi had written the sources elsewhere)."""
    out = tmp_path / os.fsdecode(b"\xff\xfe")
    refused(capsys, ["codegen", "--problem", TUDOR, "--out", str(out)], "not UTF-8")
    assert list(tmp_path.iterdir()) == []
