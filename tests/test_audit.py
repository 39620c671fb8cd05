"""The paper audit: which datasheet reading is closer to the paper's own fit, and on the real data."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from ident_opt.cli import main
from ident_opt.paper import audit

from .conftest import PROBLEMS


def test_physical_convention_is_closer_to_the_papers_fit(paper_problem):
    closer = audit.physical_is_closer(paper_problem.robot)
    for name in ("b1", "fv1", "fv2", "fc1", "a1"):  # a1 holds the joint-1 armature under `physical`
        assert closer[name], name
    table = audit.parameter_table(paper_problem.robot)
    # β̂1 read physically (β̂1 + β̂2 = 4.00 N·m) is within 10 % of the physical datasheet's 3.72 N·m ...
    assert abs(table.loc["b1", "rel_diff_physical"]) < 0.10
    # ... and the paper's own datasheet β1 (8.23 N·m) is more than twice it.
    assert table.loc["b1", "rel_diff_paper"] > 1.0
    assert table.loc["b1", "paper_fit_physical"] == pytest.approx(3.6403 + 0.36291)


def test_audit_on_the_real_trial(paper_problem, exp1):
    result = audit.audit_data(paper_problem.robot, exp1, None, paper_problem.split)
    paper = result.table.xs("paper (shuffled 70/30, mean of seeds)", level="protocol")
    # The paper's reading predicts worse than a constant at joint 1; the physical reading is close to OLS.
    assert paper.loc["dm_paper (printed G)", "nmse_j1"] > 1.0
    assert paper.loc["dm_physical", "nmse_j1"] < 0.15
    assert paper.loc["ols (fitted)", "nmse_j1"] < paper.loc["dm_physical", "nmse_j1"]
    assert paper.loc["dm_physical", "nmse_j1"] < 1.3 * paper.loc["ols (fitted)", "nmse_j1"]
    # The paper's DM row (nmse_range 0.02326 / 0.03240) comes out with its printed gravity vector.
    assert paper.loc["dm_paper (printed G)", "nmse_range_j1"] == pytest.approx(0.02326, rel=0.25)
    assert paper.loc["dm_paper (printed G)", "nmse_range_j2"] == pytest.approx(0.03240, rel=0.25)


def test_audit_command_writes_report(tmp_path):
    out = tmp_path / "res"
    status = main(
        [
            "audit",
            "--problem",
            str(PROBLEMS / "tudor_2dof_paper.toml"),
            "--out",
            str(out),
            "--json",
            str(out / "audit.json"),
        ]
    )
    assert status == 0
    text = (out / "paper_audit.md").read_text()
    for phrase in (
        "Actuator mass on the wrong link",
        "not reflected through the gear ratio",
        "rotor inertia omitted",
        "β2 cos q1 twice",
        "cross-trial",
    ):
        assert phrase in text
    assert (out / "figures" / "paper_audit_torque.png").stat().st_size > 10_000
    params = pd.read_csv(out / "paper_audit_parameters.csv", index_col=0)
    assert list(params.index) == ["a1", "a2", "a3", "b1", "b2", "fv1", "fv2", "fc1", "fc2"]
    payload = json.loads((out / "audit.json").read_text())
    assert payload["physical_closer"]["b1"] is True
