"""Problem files of URDF arms: the shipped ones load; bad URDFs and mismatched data exit 2 naming the culprit."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ident_opt.arm.chain_robot import ChainRobot
from ident_opt.cli import main
from ident_opt.data.loader import load_dataset
from ident_opt.errors import InputError
from ident_opt.problem import load_problem

ROOT = Path(__file__).resolve().parents[1]
KUKA_PROBLEM = ROOT / "problems" / "kuka_lwr4.toml"
URDF = ROOT / "data" / "kuka_lwr4" / "kuka_lwr4.urdf"
JOINTS = [f"lwr_{i}_joint" for i in range(7)]


def _problem(tmp_path: Path, urdf: Path | str, joints: list[str], extra: str = "") -> Path:
    path = tmp_path / "arm.toml"
    names = ", ".join(f'"{j}"' for j in joints)
    path.write_text(f'name = "t"\n[robot]\nurdf = "{urdf}"\njoints = [{names}]\ngravity = 9.81\n{extra}')
    return path


def test_kuka_problem_loads():
    problem = load_problem(KUKA_PROBLEM)
    assert isinstance(problem.robot, ChainRobot)
    assert problem.robot.joint_names == tuple(JOINTS) and problem.robot.gravity == (0.0, 0.0, -9.81)
    assert problem.robot.arm.n_params == 7 * 14 and problem.robot.offsets
    assert [p.name for p in problem.data.training] == ["measurements_1.csv.gz", "measurements_3.csv.gz"]
    assert [p.name for p in problem.data.testing] == ["measurements_2.csv.gz"]


def test_panda_and_tx40_problems_load():
    panda = load_problem(ROOT / "problems" / "franka_panda.toml")
    assert panda.robot.arm.n_joints == 7 and panda.data.derivative_cutoff_hz == 10.0
    tx40 = load_problem(ROOT / "problems" / "staubli_tx40.toml")
    C = tx40.robot.arm.drive_matrix
    assert C[5, 4] == 1.0 and np.count_nonzero(C - np.eye(6)) == 1


@pytest.mark.parametrize(
    ("urdf_text", "joints", "expected"),
    [
        ("<robot><link name='a'>", JOINTS, ["broken.urdf", "XML"]),
        (None, [*JOINTS[:6], "lwr_9_joint"], ["broken.urdf", "'lwr_9_joint'"]),
        (None, [JOINTS[0], JOINTS[2]], ["broken.urdf", "<joint name='lwr_2_joint'>", "serial chain"]),
    ],
)
def test_bad_urdf_exits_2_naming_file_and_element(tmp_path, capsys, urdf_text, joints, expected):
    urdf = tmp_path / "broken.urdf"
    urdf.write_text(URDF.read_text() if urdf_text is None else urdf_text)
    assert main(["check", "--problem", str(_problem(tmp_path, urdf, joints))]) == 2
    err = capsys.readouterr().err
    for text in expected:
        assert text in err


def test_unknown_robot_key_and_missing_urdf(tmp_path):
    with pytest.raises(InputError, match="unknown key"):
        load_problem(_problem(tmp_path, URDF, JOINTS, "frobnicate = 1\n"))
    with pytest.raises(InputError, match=r"nowhere\.urdf"):
        load_problem(_problem(tmp_path, tmp_path / "nowhere.urdf", JOINTS))


def _trial(tmp_path: Path, n_joints: int) -> Path:
    rng = np.random.default_rng(0)
    cols = {"t": np.arange(200) * 0.01}
    for s in ("q", "dq", "ddq", "tau"):
        cols.update({f"{s}{j + 1}": rng.normal(size=200) * 0.1 for j in range(n_joints)})
    path = tmp_path / f"trial{n_joints}.csv"
    pd.DataFrame(cols).to_csv(path, index=False)
    return path


@pytest.mark.parametrize("n_joints", [6, 8])
def test_data_with_another_joint_count_is_refused(tmp_path, n_joints):
    problem = load_problem(_problem(tmp_path, URDF, JOINTS))
    with pytest.raises(InputError) as info:
        load_dataset(_trial(tmp_path, n_joints), problem.data, problem.robot)
    assert f"trial{n_joints}.csv" in str(info.value)
    assert "7" in str(info.value)


def test_comparison_on_a_time_split_keeps_the_json_contract(tmp_path):
    problem = load_problem(KUKA_PROBLEM)
    out = tmp_path / "r.json"
    command = ["compare", "--problem", str(KUKA_PROBLEM), "--data", str(problem.data.training[0])]
    assert main([*command, "--out", str(tmp_path / "out"), "--json", str(out), "--no-progress"]) == 0
    result = json.loads(out.read_text())
    assert set(result["metrics"]) == {"chronological"} and result["joints"] == JOINTS
    scores = result["metrics"]["chronological"]
    assert set(scores["rmse"]) == {"ols", "constrained", "consistent", "robust", "datasheet_urdf"}
    assert all(len(v) == 7 for metric in ("rmse", "nmse") for v in scores[metric].values())
    params = result["parameters"]["consistent"]
    for name in (
        "m_lwr_1_link",
        "mx_lwr_7_link",
        "ixy_lwr_3_link",
        "fv_lwr_0_joint",
        "ia_lwr_6_joint",
        "off_lwr_6_joint",
    ):
        assert name in params
    base = result["base_parameters"]["ols"]
    assert len(base) == 69
    assert base["izz_lwr_1_link"]["definition"].startswith("izz_lwr_1_link + 1·izz_lwr_2_link")
    assert result["consistency"]["consistent"]["consistent"] and result["consistency"]["constrained"]["consistent"]
    masses = result["masses"]["consistent"]["links"]
    cad = result["masses"]["datasheet_urdf"]["links"]
    assert all(0.5 * cad[k] - 1e-6 <= v <= 1.5 * cad[k] + 1e-6 for k, v in masses.items())
    assert isinstance(result["warnings"], list) and result["recommended"] in ("consistent", "robust")
    assert result["recommended_why"]


def test_identify_writes_its_report(tmp_path):
    problem = load_problem(KUKA_PROBLEM)
    out, result_path = tmp_path / "out", tmp_path / "identify.json"
    argv = ["identify", "--problem", str(KUKA_PROBLEM), "--data", str(problem.data.training[0])]
    assert main([*argv, "--out", str(out), "--json", str(result_path)]) == 0
    result = json.loads(result_path.read_text())
    assert set(result["metrics"]) == {"chronological"} and result["joints"] == JOINTS
    assert {"pbr", "cpbr", "dm", "rr", "pbr+gmr"} <= set(result["metrics"]["chronological"]["rmse"])
    assert all(len(v) == 7 for v in result["metrics"]["chronological"]["nmse"].values())
    assert "m_lwr_1_link" in result["standard_errors"]["consistent"] and (out / "README.md").is_file()
    assert isinstance(result["warnings"], list)


def test_optional_robot_keys(tmp_path):
    extra = (
        'base = "lwr_base_link"\nfriction = false\narmature = false\noffsets = true\nmass_range = false\n'
        "com_box = 0.05\nprior_weight = 1e-4\n[robot.lwr_0_joint]\ngear_ratio = 100.0\n"
    )
    path = _problem(tmp_path, URDF, JOINTS, extra).read_text().replace("gravity = 9.81", "gravity = [0.0, 0.5, -9.8]")
    (tmp_path / "b.toml").write_text(path)
    robot = load_problem(tmp_path / "b.toml").robot
    assert robot.gravity == (0.0, 0.5, -9.8) and robot.mass_range is None and robot.com_box == 0.05
    assert robot.arm.joint_terms == ("off",) and robot.arm.n_params == 7 * 11
    assert robot.joints[0].gear_ratio == 100.0
    with pytest.raises(InputError, match="couplings"):
        load_problem(_problem(tmp_path, URDF, JOINTS, 'couplings = [["lwr_6_joint", "nope", 1.0]]\n'))


def test_compare_cli_on_the_kuka(tmp_path):
    out = tmp_path / "out"
    assert main(["compare", "--problem", str(KUKA_PROBLEM), "--out", str(out), "--json", str(tmp_path / "r.json")]) == 0
    result = json.loads((tmp_path / "r.json").read_text())
    assert "cross_trial" in result["metrics"] and (out / "compare.md").is_file()
    assert len(result["metrics"]["cross_trial"]["rmse"]["consistent"]) == len(JOINTS)


def test_compare_cli_refuses_data_of_another_joint_count(tmp_path, capsys):
    path = _trial(tmp_path, 6)
    assert main(["compare", "--problem", str(KUKA_PROBLEM), "--data", str(path), "--out", str(tmp_path)]) == 2
    assert "trial6.csv" in capsys.readouterr().err
