"""results/README.md is rebuilt from what every report recorded, whatever order the commands ran in; the
estimator registry is the one list of estimators."""

from __future__ import annotations

import itertools

import pytest

from ident_opt.cli import main
from ident_opt.fitting import estimators
from ident_opt.problem import load_problem
from ident_opt.report import MANIFESTS, record

from .conftest import PROBLEMS


def _write(folder, name: str) -> str:
    (folder / name).parent.mkdir(parents=True, exist_ok=True)
    (folder / name).write_text("x")
    return name


@pytest.mark.parametrize("order", list(itertools.permutations(["identify", "audit", "online", "diagnosis"])))
def test_index_is_the_same_whatever_the_order(tmp_path, order):
    out = tmp_path / "results"
    out.mkdir()
    steps = {
        "identify": lambda: record(
            out,
            "identify",
            "all models",
            [_write(out, "identify_metrics.md")],
            readme_head="# Head",
            readme_tail="## Tail",
        ),
        "audit": lambda: record(out, "audit", "the audit", [_write(out, "paper_audit.md")]),
        "online": lambda: record(out, "online", "online", [_write(out, "online.md"), _write(out, "online.json")]),
        "diagnosis": lambda: record(
            out / "diagnosis", "diagnosis", "the diagnosis", [_write(out / "diagnosis", "d.md")]
        ),
    }
    (out / MANIFESTS).mkdir()  # a results folder that has been written to before
    for step in order:
        steps[step]()
    text = (out / "README.md").read_text()
    assert text == (
        "# Head\n\nOther reports in this folder:\n\n- [paper_audit.md](paper_audit.md): the audit\n"
        "- [diagnosis/d.md](diagnosis/d.md): the diagnosis\n- [online.md](online.md): online\n## Tail\n"
    )
    assert not (out / "diagnosis" / "README.md").exists()


def test_index_without_a_head_and_without_removed_reports(tmp_path):
    record(tmp_path, "compare", "comparison", [_write(tmp_path, "compare.md")])
    record(tmp_path, "audit", "the audit", [tmp_path / _write(tmp_path, "paper_audit.md")])
    (tmp_path / "compare.md").unlink()
    readme = record(tmp_path, "online", "online", [_write(tmp_path, "online.md")])
    assert readme.read_text() == (
        "# Results\n\nReports in this folder:\n\n- [paper_audit.md](paper_audit.md): the audit\n"
        "- [online.md](online.md): online\n"
    )


def test_a_file_outside_the_output_folder_is_refused(tmp_path):
    with pytest.raises(ValueError, match="not inside"):
        record(tmp_path / "a", "x", "x", [tmp_path / "elsewhere.md"])


def test_unknown_estimator_is_named():
    with pytest.raises(ValueError, match="unknown estimator 'lasso'; known: ols, constrained"):
        estimators.estimator("lasso")


@pytest.mark.parametrize("problem", ["tudor_2dof", "kuka_lwr4"])
def test_codegen_estimator_is_one_of_the_arms_fits(problem, tmp_path, capsys):
    # --estimator is checked against the arm's own fits (`Robot.estimators`, a subset of the registry), before any
    # work: an unknown name is exit 2, the arm's fits named, nothing written.
    path = PROBLEMS / f"{problem}.toml"
    robot = load_problem(path).robot
    assert set(robot.estimators) <= set(estimators.ESTIMATORS)
    out = tmp_path / "c"
    assert main(["codegen", "--problem", str(path), "--out", str(out), "--estimator", "nope"]) == 2
    err = capsys.readouterr().err
    assert "--estimator nope" in err and all(name in err for name in robot.estimators)
    assert not out.exists()


def test_calibrate_needs_a_simulate_section(capsys):
    problem = str(PROBLEMS / "tudor_2dof.toml")
    assert main(["calibrate", "--problem", problem, "--real", problem]) == 2
    assert "no [simulate] section" in capsys.readouterr().err
