"""Hostile input, the fuzz issue's reproducers 3, 4, 6, 7, 8, 10, 14–18 (1, 2, 5, 9, 11–13, 19 are in
test_problem_limits.py and test_data_mapping.py): each gives exit status 2 with the culprit named, no traceback,
no NaN in any JSON, inputs unchanged and nothing half-written; plus the output rules (`ident_opt.outputs`)."""

from __future__ import annotations

import json
import os
import shutil
import stat
from pathlib import Path

import pytest

from ident_opt import outputs
from ident_opt.cli import main
from ident_opt.data.dataset import chronological_split, shuffled_split
from ident_opt.errors import InputError
from ident_opt.report import write_json

ROOT = Path(__file__).resolve().parents[1]
PROBLEM_TEXT = (ROOT / "problems" / "tudor_2dof.toml").read_text()

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")


def small_problem(folder: Path, rows: tuple[int, int] = (1500, 3000), seeds: str = "[0]") -> Path:
    """A copy of tudor_2dof.toml in `folder` on 15 s of exp1 (`small.csv`), few seeds, 2 GMR components."""
    lines = (ROOT / "data" / "merit" / "exp1.csv").read_text().splitlines()[rows[0] : rows[1]]
    (folder / "small.csv").write_text("\n".join(lines) + "\n")
    text = (
        PROBLEM_TEXT.replace('"../data/merit/exp1.csv", "../data/merit/exp2.csv"', '"small.csv"')
        .replace("seeds = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]", f"seeds = {seeds}")
        .replace('components = "auto"', "components = 2")
        .replace('dir = "../results"', 'dir = "out"')
    )
    path = folder / "p.toml"
    path.write_text(text)
    return path


def edit_columns(src: Path, dst: Path, change) -> Path:
    """`dst`: `src` (headerless MERIt CSV) with each row's cells passed through `change(cells) -> cells`."""
    rows = [change(line.split(",")) for line in src.read_text().splitlines()]
    dst.write_text("\n".join(",".join(r) for r in rows) + "\n")
    return dst


@pytest.fixture
def work(tmp_path, monkeypatch) -> Path:
    """A working folder with p.toml and small.csv, as the current folder."""
    small_problem(tmp_path)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def snapshot(folder: Path) -> dict[str, tuple[bytes, int]]:
    """Every file under `folder` with its bytes and mode."""
    return {
        str(p.relative_to(folder)): (p.read_bytes(), stat.S_IMODE(p.stat().st_mode))
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def exits_2(capsys, argv: list[str], *named: str) -> str:
    """Run `argv`; require exit 2, an `ident-opt: error:` naming each of `named`, and no traceback."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "ident-opt: error:" in err and "Traceback" not in err, err
    for word in named:
        assert word in err, (word, err)
    assert "np.float64" not in err and "array(" not in err, err
    return err


# --- 3: a split that leaves a part empty is refused with a clear message --------------------------------------


@pytest.mark.parametrize("split", [lambda: chronological_split(10, 0.01), lambda: shuffled_split(3, 0.1, 0)])
def test_split_with_an_empty_part_is_refused(split):
    with pytest.raises(InputError, match="leaves a part empty"):
        split()


def test_split_with_both_parts_is_kept():
    train, test = chronological_split(10, 0.7)
    assert len(train) == 7 and len(test) == 3


# --- 4 and every numeric flag: validated while parsing -----------------------------------------------------------


@pytest.mark.parametrize(
    "argv",
    [
        ["compare", "--problem", "p.toml", "--margin", "nan"],
        ["compare", "--problem", "p.toml", "--margin", "inf"],
        ["compare", "--problem", "p.toml", "--margin", "-1"],
        ["compare", "--problem", "p.toml", "--constraints-study", "0"],
        ["simulate", "--problem", "p.toml", "--out", "t.csv", "--seed", "-1"],
        ["simulate", "--problem", "p.toml", "--out", "t.csv", "--duration", "inf"],
        ["simulate", "--problem", "p.toml", "--out", "t.csv", "--rate", "1e400"],
        ["codegen", "--problem", "p.toml", "--out", "cg", "--components", "1e3"],
        ["online", "--problem", "p.toml", "--components", "0"],
        ["online", "--problem", "p.toml", "--checks", "99999999999999999999999"],
    ],
    ids=lambda a: " ".join(a[3:] if a[0] != "simulate" else a[5:]),
)
def test_bad_number_on_the_command_line_is_a_usage_error(work, capsys, argv):
    flag = argv[-2]
    exits_2(capsys, argv, flag)
    assert not (work / "out").exists() and not (work / "cg").exists() and not (work / "t.csv").exists()


def test_good_numbers_still_parse():
    from ident_opt.cli import build_parser

    args = build_parser().parse_args(["compare", "--problem", "p.toml", "--margin", "1e-5"])
    assert args.margin == 1e-5
    args = build_parser().parse_args(["simulate", "--problem", "p", "--out", "t.csv", "--seed", "4294967295"])
    assert args.seed == 2**32 - 1


# --- 6: values beyond double precision's reach, even with --allow-implausible -----------------------------------


@pytest.mark.parametrize("command", ["compare", "identify"])
def test_data_times_1e150_is_refused(work, capsys, command):
    scaled = {2, 3, 5, 6, 8, 9, 15, 16}
    edit_columns(
        work / "small.csv",
        work / "huge.csv",
        lambda c: [f"{float(x) * 1e150:.6g}" if i in scaled else x for i, x in enumerate(c)],
    )
    before = snapshot(work)
    exits_2(capsys, [command, "--problem", "p.toml", "--data", "huge.csv", "--allow-implausible"], "huge.csv", "1e+08")
    assert snapshot(work) == before


# --- 10: a joint whose torque never varies ---------------------------------------------------------------------


@pytest.mark.parametrize("value", ["0", "0.5"])
@pytest.mark.parametrize("command", ["compare", "identify"])
def test_constant_torque_is_refused_by_the_fitting_commands(work, capsys, command, value):
    edit_columns(work / "small.csv", work / "flat.csv", lambda c: [*c[:9], value, *c[10:]])
    exits_2(capsys, [command, "--problem", "p.toml", "--data", "flat.csv", "--json", "r.json"], "joint 2", "constant")
    assert not (work / "r.json").exists() and not (work / "out").exists()


def test_constant_torque_is_a_warning_in_check(work, capsys):
    edit_columns(work / "small.csv", work / "flat.csv", lambda c: [*c[:9], "0", *c[10:]])
    assert main(["check", "--problem", "p.toml", "--data", "flat.csv", "--json", "c.json"]) == 0
    assert "warning" in capsys.readouterr().err
    json.loads((work / "c.json").read_text(), parse_constant=pytest.fail)  # strict JSON


# --- 7, 8, 17: codegen ----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "payload",
    [{"parameters": {}, "model": 5}, {"parameters": {}, "model": {"extensions": "armature"}}, {"parameters": {}}],
)
def test_codegen_bad_parameters_file_leaves_no_folder(work, capsys, payload):
    (work / "p.json").write_text(json.dumps(payload))
    exits_2(capsys, ["codegen", "--problem", "p.toml", "--parameters", "p.json", "--out", "cg"], "p.json")
    assert not (work / "cg").exists()


@pytest.mark.parametrize("name", ["README.md", "main.c", "parameters.json"])
def test_codegen_refuses_a_folder_where_a_file_goes(work, capsys, name):
    (work / "cg" / name).mkdir(parents=True)
    before = snapshot(work)
    exits_2(capsys, ["codegen", "--problem", "p.toml", "--out", "cg", "--components", "2"], name, "folder")
    assert snapshot(work) == before
    assert sorted(p.name for p in (work / "cg").iterdir()) == [name]  # no .c, .h, .so left behind


def test_codegen_keeps_the_users_files_without_force(work, capsys):
    (work / "cg").mkdir()
    (work / "cg" / "README.md").write_text("my notes\n")
    exits_2(capsys, ["codegen", "--problem", "p.toml", "--out", "cg", "--components", "2"], "README.md", "--force")
    assert (work / "cg" / "README.md").read_text() == "my notes\n"
    assert sorted(p.name for p in (work / "cg").iterdir()) == ["README.md"]


@needs_gcc
def test_codegen_rewrites_its_own_files_and_the_users_with_force(work, capsys):
    argv = ["codegen", "--problem", "p.toml", "--out", "cg", "--components", "2", "--no-forward"]
    assert main(argv) == 0
    assert main(argv) == 0  # its own files: no --force needed
    (work / "cg" / "main.c").write_text("/* mine */\n")
    exits_2(capsys, argv, "main.c")
    assert (work / "cg" / "main.c").read_text() == "/* mine */\n"
    assert main([*argv, "--force"]) == 0
    assert "mine" not in (work / "cg" / "main.c").read_text()
    json.loads((work / "cg" / "parameters.json").read_text(), parse_constant=pytest.fail)
    # 14: a --parameters file inside --out is an input; codegen does not rewrite it
    before = snapshot(work / "cg")
    exits_2(capsys, [*argv, "--parameters", "cg/parameters.json"], "parameters.json", "input")
    assert snapshot(work / "cg") == before


# --- 14, 15, 16: the output contract -----------------------------------------------------------------------------


@pytest.mark.parametrize("target", ["small.csv", "p.toml", "./sub/../small.csv"])
def test_an_output_that_is_an_input_is_refused(work, capsys, target):
    (work / "sub").mkdir()
    before = snapshot(work)
    exits_2(capsys, ["check", "--problem", "p.toml", "--data", "small.csv", "--json", target], "input")
    assert snapshot(work) == before


def test_an_output_that_is_the_problems_own_trial_is_refused(work, capsys):
    before = snapshot(work)
    exits_2(capsys, ["check", "--problem", "p.toml", "--json", "small.csv"], "small.csv", "input")
    assert snapshot(work) == before


def test_an_output_through_a_link_to_an_input_is_refused(work, capsys):
    (work / "link.csv").symlink_to(work / "small.csv")
    before = snapshot(work)
    exits_2(capsys, ["check", "--problem", "p.toml", "--data", "small.csv", "--json", "link.csv"], "input")
    assert snapshot(work) == before


def test_json_into_a_folder_is_refused_and_leaves_no_temporary_file(work, capsys):
    (work / "results").mkdir()
    exits_2(capsys, ["check", "--problem", "p.toml", "--json", "results"], "results", "folder")
    assert list((work / "results").iterdir()) == []


@pytest.mark.parametrize("mask", [0o022, 0o002, 0o077])
def test_files_follow_the_umask(work, mask):
    old = os.umask(mask)
    try:
        assert main(["check", "--problem", "p.toml", "--json", "c.json"]) == 0
    finally:
        os.umask(old)
    assert stat.S_IMODE((work / "c.json").stat().st_mode) == 0o666 & ~mask


def test_json_is_checked_before_any_report_is_written(work, capsys):
    (work / "taken").mkdir()
    exits_2(capsys, ["compare", "--problem", "p.toml", "--out", "out", "--json", "taken", "--no-progress"], "taken")
    assert not (work / "out").exists()


@pytest.mark.parametrize("json_path", ["missing/sub/r.json", "small.csv/r.json"])
def test_json_in_an_impossible_place_is_refused_first(work, capsys, json_path):
    if json_path.startswith("missing"):  # a missing folder is created: not an error
        assert main(["check", "--problem", "p.toml", "--json", json_path]) == 0
        return
    exits_2(capsys, ["compare", "--problem", "p.toml", "--json", json_path, "--no-progress"], "not a folder")
    assert not (work / "out").exists()


def test_a_failed_run_leaves_nothing_and_restores_what_it_replaced(work, capsys, monkeypatch):
    """compare writes its reports, then fails: the new files go and the replaced ones come back."""
    assert main(["compare", "--problem", "p.toml", "--no-progress"]) == 0
    (work / "out" / "user.txt").write_text("keep\n")
    before = snapshot(work)
    from ident_opt.report import compare as report

    def broken(*args, **kwargs):
        raise InputError("simulated failure after the reports")

    monkeypatch.setattr(report, "write_json", broken)
    exits_2(capsys, ["compare", "--problem", "p.toml", "--json", "new.json", "--no-progress"], "simulated failure")
    assert snapshot(work) == before


def test_rollback_removes_new_files_and_folders(tmp_path):
    (tmp_path / "old.txt").write_text("old")
    with pytest.raises(RuntimeError), outputs.run() as run:
        run.watch_folder(tmp_path / "new" / "deeper")
        outputs.write_text(tmp_path / "old.txt", "new")
        outputs.write_text(tmp_path / "new" / "deeper" / "a.txt", "a")
        (tmp_path / "new" / "deeper" / "b.png").write_bytes(b"x")  # a writer outside outputs
        assert (tmp_path / "old.txt").read_text() == "new"
        raise RuntimeError("boom")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.txt"]
    assert (tmp_path / "old.txt").read_text() == "old"


def test_committed_run_keeps_files_and_drops_backups(tmp_path):
    (tmp_path / "old.txt").write_text("old")
    with outputs.run():
        outputs.write_text(tmp_path / "old.txt", "new")
    assert [p.name for p in tmp_path.iterdir()] == ["old.txt"]
    assert (tmp_path / "old.txt").read_text() == "new"


def test_atomic_write_cleans_its_temporary_file_on_failure(tmp_path):
    with pytest.raises(ZeroDivisionError), outputs.atomic_path(tmp_path / "x.csv") as tmp:
        tmp.write_text("half")
        1 / 0  # noqa: B018
    assert list(tmp_path.iterdir()) == []


# --- strict JSON ---------------------------------------------------------------------------------------------


def test_json_is_strict_non_finite_becomes_null_with_a_warning(tmp_path, capsys):
    import numpy as np

    write_json(tmp_path / "r.json", {"a": float("nan"), "b": [1.0, np.inf], "c": {"d": np.float64(-np.inf)}})
    text = (tmp_path / "r.json").read_text()
    assert json.loads(text, parse_constant=pytest.fail) == {"a": None, "b": [1.0, None], "c": {"d": None}}
    err = capsys.readouterr().err
    assert "3 non-finite" in err and "b[1]" in err and "c.d" in err


# --- 18: messages ---------------------------------------------------------------------------------------------


def test_too_few_samples_does_not_misname_them_as_parameters(work, capsys):
    lines = (work / "small.csv").read_text().splitlines()[:10]
    (work / "tiny.csv").write_text("\n".join(lines) + "\n")
    err = exits_2(capsys, ["compare", "--problem", "p.toml", "--data", "tiny.csv"], "tiny.csv", "10 valid samples")
    assert "parameters" not in err


def test_simulated_trial_follows_the_umask_and_never_overwrites_the_problem(work, capsys):
    old = os.umask(0o002)
    try:
        argv = ["simulate", "--problem", "p.toml", "--duration", "1", "--no-noise"]
        assert main([*argv, "--out", "s.csv"]) == 0
    finally:
        os.umask(old)
    for name in ("s.csv", "s.truth.json"):
        assert stat.S_IMODE((work / name).stat().st_mode) == 0o664
    before = snapshot(work)
    exits_2(capsys, [*argv, "--out", "p.toml"], "input")
    assert snapshot(work) == before


def test_time_in_megaseconds_with_allow_implausible_does_not_crash(work, capsys):
    """Found by the fuzz: t × 1e6 gave a 0-sample Welch segment (ValueError) in the derivative cut-off."""
    edit_columns(work / "small.csv", work / "slow.csv", lambda c: [f"{float(c[0]) * 1e6:.9g}", *c[1:]])
    argv = ["compare", "--problem", "p.toml", "--data", "slow.csv", "--allow-implausible", "--json", "r.json"]
    assert main([*argv, "--no-progress"]) == 0
    json.loads((work / "r.json").read_text(), parse_constant=pytest.fail)
