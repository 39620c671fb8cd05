"""Generated C for an arm from a URDF: tau_hat and ddq_hat for n joints agree with the Python model."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest

from ident_opt.cli import main
from ident_opt.problem import load_problem
from tests.test_urdf_arm import TWISTED


@pytest.mark.skipif(shutil.which("gcc") is None and shutil.which("cc") is None, reason="no C compiler")
def test_codegen_for_a_three_joint_urdf(tmp_path):
    (tmp_path / "arm.urdf").write_text(TWISTED)
    rng = np.random.default_rng(0)
    n = 400
    cols = {"t": np.arange(n) * 0.01}
    for s, scale in (("q", 1.0), ("dq", 1.0), ("ddq", 3.0)):
        for j in range(3):
            cols[f"{s}{j + 1}"] = scale * np.sin(0.3 * (j + 1) * (2 + j) * cols["t"] + s.count("d"))
    problem_path = tmp_path / "arm.toml"
    problem_path.write_text(
        'name = "twisted"\n[robot]\nurdf = "arm.urdf"\njoints = ["a", "b", "c"]\ngravity = 9.81\n'
        '[data]\ntrials = ["trial.csv"]\n'
    )
    problem = load_problem(problem_path)
    arm = problem.robot.arm
    frame = pd.DataFrame(cols)
    q, dq, ddq = (frame[[f"{s}{j}" for j in (1, 2, 3)]].to_numpy() for s in ("q", "dq", "ddq"))
    truth = arm.cad_parameters()
    truth[arm.n_link_params :] = 0.2
    tau = arm.predict(truth, q, dq, ddq) + 0.01 * rng.standard_normal((n, 3))
    for j in range(3):
        frame[f"tau{j + 1}"] = tau[:, j]
    frame.to_csv(tmp_path / "trial.csv", index=False)
    out = tmp_path / "c"
    command = ["codegen", "--problem", str(problem_path), "--out", str(out), "--estimator", "consistent"]
    assert main([*command, "--allow-implausible"]) == 0
    saved = json.loads((tmp_path / "c" / "parameters.json").read_text())
    check = saved["check"]
    assert check["tau_hat"]["max_relative_error"] < 1e-12 and check["ddq_hat"]["max_backward_error"] < 1e-12
    assert set(saved["parameters"]) == set(arm.names) and saved["joints"] == ["a", "b", "c"]
