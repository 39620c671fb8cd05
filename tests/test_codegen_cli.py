"""`ident-opt codegen` end to end on a short slice of the real MERIt trial, and its exit-2 paths."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from ident_opt.arm.planar import PlanarArm
from ident_opt.cli import main
from ident_opt.models.gmr import GMR
from ident_opt.shipping import codegen

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = str(ROOT / "problems" / "tudor_2dof.toml")
FILES = {"ident_opt_model.c", "ident_opt_model.h", codegen.library_name(), "parameters.json", "README.md", "main.c"}

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")


@pytest.fixture(scope="module")
def real_slice(tmp_path_factory) -> Path:
    """15 s (1500 rows) of exp1 with motion on both joints (the first 15 s are at rest), same format."""
    lines = (ROOT / "data" / "merit" / "exp1.csv").read_text().splitlines()[1500:3000]
    path = tmp_path_factory.mktemp("data") / "exp1_slice.csv"
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory, real_slice) -> Path:
    out = tmp_path_factory.mktemp("cg") / "c"
    assert (
        main(["codegen", "--problem", PROBLEM, "--data", str(real_slice), "--out", str(out), "--components", "3"]) == 0
    )
    return out


@needs_gcc
def test_cli_writes_the_contract_files(run_dir):
    assert FILES <= {p.name for p in run_dir.iterdir()}
    saved = json.loads((run_dir / "parameters.json").read_text())
    assert saved["estimator"] == "constrained"  # the spec's default: the physically consistent fit
    assert list(saved["parameters"]) == list(PlanarArm().names)
    assert saved["gmr"]["n_components"] == 3
    check = saved["check"]
    assert check["tau_hat"]["max_relative_error"] <= 1e-12 and check["ddq_hat"]["max_backward_error"] <= 1e-12
    assert check["tau_hat_gmr"]["max_relative_error"] <= 1e-10
    header = (run_dir / "ident_opt_model.h").read_text()
    for entry in ("tau_hat(", "tau_hat_gmr(", "tau_hat_work(", "tau_hat_incref(", "tau_hat_gmr_checkout("):
        assert entry in header


@needs_gcc
def test_cli_library_matches_the_saved_parameters_on_the_data(run_dir, real_slice):
    """What the library computes is the Python model with the parameters.json values (π and GMR)."""
    saved = json.loads((run_dir / "parameters.json").read_text())
    model = PlanarArm()
    pi = model.vector(saved["parameters"])
    raw = np.loadtxt(real_slice, delimiter=",")
    q, dq, ddq = raw[:, [2, 3]], raw[:, [5, 6]], raw[:, [15, 16]]
    lib = run_dir / codegen.library_name()
    tau = model.predict(pi, q, dq, ddq)
    assert codegen.relative_error(codegen.evaluate(codegen.load_external(lib, "tau_hat"), q, dq, ddq), tau) <= 1e-12
    g = GMR()
    g.weights_, g.means_, g.covariances_ = (np.array(saved["gmr"][k]) for k in ("weights", "means", "covariances"))
    g.n_inputs = 6
    ref = tau + g.predict_mean(np.hstack([q, dq, ddq]))
    got = codegen.evaluate(codegen.load_external(lib, "tau_hat_gmr"), q, dq, ddq)
    assert codegen.relative_error(got, ref) <= 1e-10


@needs_gcc
def test_cli_reuses_a_parameters_file_with_extensions(run_dir, tmp_path):
    """--parameters skips identification; an extension absent from the file is an input error, and an
    explicit --extension whose parameters the file has is generated with them."""
    params = json.loads((run_dir / "parameters.json").read_text())
    assert (
        main(
            [
                "codegen",
                "--problem",
                PROBLEM,
                "--parameters",
                str(run_dir / "parameters.json"),
                "--extension",
                "armature",
                "--out",
                str(tmp_path / "x"),
            ]
        )
        == 2
    )
    params["parameters"]["ia2"] = 0.004
    (tmp_path / "p.json").write_text(json.dumps(params))
    out = tmp_path / "y"
    assert (
        main(
            [
                "codegen",
                "--problem",
                PROBLEM,
                "--parameters",
                str(tmp_path / "p.json"),
                "--extension",
                "armature",
                "--no-forward",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    saved = json.loads((out / "parameters.json").read_text())
    assert saved["functions"] == ["tau_hat", "tau_hat_gmr"] and "ddq_hat" not in (out / "ident_opt_model.h").read_text()
    assert saved["model"]["extensions"] == ["armature"] and saved["parameters"]["ia2"] == 0.004
    assert saved["estimator"].startswith("constrained (loaded from")


def test_unwritable_output_folder_exits_2(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert main(["codegen", "--problem", PROBLEM, "--out", str(blocker / "sub")]) == 2
    err = capsys.readouterr().err
    assert "output folder" in err and "Traceback" not in err


def test_a_compiler_that_writes_nothing_exits_2(tmp_path, monkeypatch, capsys, real_slice):
    monkeypatch.setenv("CC", "true")  # exits 0, compiles nothing
    out = tmp_path / "o"
    assert (
        main(
            [
                "codegen",
                "--problem",
                PROBLEM,
                "--data",
                str(real_slice),
                "--components",
                "1",
                "--estimator",
                "ols",
                "--out",
                str(out),
            ]
        )
        == 2
    )
    assert "wrote no" in capsys.readouterr().err


def test_missing_compiler_exits_2(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("CC", "no-such-cc")
    assert main(["codegen", "--problem", PROBLEM, "--out", str(tmp_path / "a")]) == 2
    assert "no-such-cc" in capsys.readouterr().err
    monkeypatch.delenv("CC")
    monkeypatch.setenv("PATH", str(tmp_path))  # nothing on PATH: no gcc, no cc
    assert main(["codegen", "--problem", PROBLEM, "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "no C compiler" in err and "Traceback" not in err


@needs_gcc
def test_unknown_extension_exits_2(tmp_path, capsys):
    assert main(["codegen", "--problem", PROBLEM, "--extension", "elastic_magic", "--out", str(tmp_path)]) == 2
    assert "elastic_magic" in capsys.readouterr().err


@needs_gcc
def test_bad_parameters_file_exits_2(tmp_path, capsys):
    bad = tmp_path / "p.json"
    bad.write_text("{not json")
    assert main(["codegen", "--problem", PROBLEM, "--parameters", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "p.json" in capsys.readouterr().err
