"""`excite` on an arm of n joints (the 3-joint URDF arm of `tests.test_n_joint_inputs`, its [limits] per joint): a
trajectory at rest at both ends, within every limit on the 1 kHz grid, better than its random start; the
discriminating design refused (an n-joint model has no causes to tell apart); --out onto one of the problem's own
trials refused before any work, the trial unchanged (also on the planar arm)."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from ident_opt.cli import main
from ident_opt.problem import load_problem
from tests.test_n_joint_inputs import arm3, workspace  # noqa: F401  (the fixtures)

ROOT = Path(__file__).resolve().parents[1]


def test_excite_three_joints(workspace, tmp_path, capsys):  # noqa: F811
    out = tmp_path / "traj.csv"
    args = ["excite", "--problem", str(workspace / "full.toml"), "--out", str(out), "--duration", "4"]
    small = ["--harmonics", "2", "--starts", "2", "--rate", "200", "--no-progress"]
    assert main([*args, *small, "--workers", "2"]) == 0
    frame = pd.read_csv(out)
    # the starts in one process give the same design as in two (drawn beforehand; IPOPT is deterministic)
    one = ["excite", "--problem", str(workspace / "full.toml"), "--out", str(tmp_path / "one.csv"), "--duration", "4"]
    assert main([*one, *small, "--workers", "1"]) == 0
    assert pd.read_csv(tmp_path / "one.csv").equals(frame)
    joints = [f"{k}{j}" for k in ("q", "dq", "ddq") for j in (1, 2, 3)]
    assert list(frame.columns) == ["t", *joints, "tau_ff1", "tau_ff2", "tau_ff3"] and len(frame) == 800
    limits = load_problem(workspace / "full.toml").limits
    assert np.all(frame[["q1", "q2", "q3"]].to_numpy() >= np.array(limits.position_min))
    assert np.all(np.abs(frame[["dq1", "dq2", "dq3"]].to_numpy()) <= np.array(limits.velocity))
    assert np.abs(frame.loc[0, ["dq1", "dq2", "dq3", "ddq1", "ddq2", "ddq3"]]).max() < 1e-9  # at rest
    payload = json.loads(out.with_suffix(".json").read_text())
    assert all(min(m["margin"]) >= 0 and m["rate_hz"] == 1000.0 for m in payload["margins"].values())
    assert len(payload["margins"]["torque"]["margin"]) == 3
    assert payload["criteria"]["log_det"] > payload["start_criteria"]["log_det"]
    assert "Traceback" not in capsys.readouterr().err


def test_discriminating_design_is_refused_on_n_joints(workspace, tmp_path, capsys):  # noqa: F811
    args = ["excite", "--problem", str(workspace / "full.toml"), "--out", str(tmp_path / "t.csv")]
    assert main([*args, "--criterion", "discriminate", "--between", "asymmetric_coulomb,elasticity"]) == 2
    err = capsys.readouterr().err
    assert "discriminat" in err and "Traceback" not in err and not (tmp_path / "t.csv").exists()


def test_workers_out_of_range_exit_2(workspace, tmp_path, capsys):  # noqa: F811
    args = ["excite", "--problem", str(workspace / "full.toml"), "--out", str(tmp_path / "t.csv")]
    assert main([*args, "--workers", "0"]) == 2
    err = capsys.readouterr().err
    assert "--workers" in err and "Traceback" not in err and not (tmp_path / "t.csv").exists()


def test_model_extensions_are_refused_on_n_joints(workspace, tmp_path, capsys):  # noqa: F811
    args = ["excite", "--problem", str(workspace / "full.toml"), "--out", str(tmp_path / "t.csv")]
    assert main([*args, "--extension", "armature"]) == 2
    err = capsys.readouterr().err
    assert "armature" in err and "Traceback" not in err and not (tmp_path / "t.csv").exists()


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_out_onto_the_problems_own_trial_is_refused(workspace, tmp_path, capsys):  # noqa: F811
    trial = workspace / "train.csv"
    before = _digest(trial)
    assert main(["excite", "--problem", str(workspace / "full.toml"), "--out", str(trial), "--starts", "1"]) == 2
    err = capsys.readouterr().err
    assert "input" in err and str(trial.name) in err and _digest(trial) == before
    # The planar arm: its problem names exp1.csv as a trial; a copy of the problem and the trial here.
    problem = (ROOT / "problems" / "tudor_2dof.toml").read_text().replace("../data/merit/", "")
    (tmp_path / "p.toml").write_text(problem)
    for name in ("exp1.csv", "exp2.csv"):
        shutil.copy(ROOT / "data" / "merit" / name, tmp_path / name)
    before = _digest(tmp_path / "exp1.csv")
    assert main(["excite", "--problem", str(tmp_path / "p.toml"), "--out", str(tmp_path / "exp1.csv")]) == 2
    assert _digest(tmp_path / "exp1.csv") == before and not (tmp_path / "exp1.png").exists()
    assert "Traceback" not in capsys.readouterr().err
