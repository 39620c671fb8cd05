"""`ident-opt check` on arms from a URDF (robot summary, n-joint data ranges, exit 0), and the commands that
model the two-link arm only refusing a URDF problem with one sentence and exit 2, never a traceback."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from ident_opt.cli import main

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = ROOT / "problems"
#: problem -> (joints, standard parameters, base parameters, first joint name)
URDF_PROBLEMS = {
    "kuka_lwr4": (7, 98, 69, "lwr_0_joint"),
    "franka_panda": (7, 98, 69, "panda_joint1"),
    "staubli_tx40": (6, 84, 58, "joint_1"),
}


@pytest.mark.parametrize("name", sorted(URDF_PROBLEMS))
def test_check_summarises_a_urdf_problem(name, tmp_path, capsys):
    n, params, base, first = URDF_PROBLEMS[name]
    problem = PROBLEMS / f"{name}.toml"
    out_json = tmp_path / "check.json"
    assert main(["check", "--problem", str(problem), "--json", str(out_json)]) == 0
    text = capsys.readouterr().out
    assert f"{n}-joint arm from the URDF" in text
    assert f"joints: {first}," in text
    assert "gravity [m/s²]: (0, 0, -9.81)" in text
    assert f"parameters: {params} standard" in text and f"{base} base" in text
    assert "URDF mass of the moving links:" in text and " kg" in text
    assert "samples" in text and f"joint {n} [" in text and f"joint {n + 1} [" not in text
    payload = json.loads(out_json.read_text())
    robot = payload["robot"]
    assert len(robot["joints"]) == n and robot["parameters"] == params and robot["base_parameters"] == base
    assert robot["urdf_mass_kg"] > 0
    for trial in payload["trials"]:
        assert all(len(ranges) == n for ranges in trial["ranges"].values())


def test_check_as_a_console_command():
    """The installed entry point, as a user runs it: exit 0, no traceback."""
    done = subprocess.run(
        [sys.executable, "-m", "ident_opt", "check", "--problem", str(PROBLEMS / "kuka_lwr4.toml")],
        capture_output=True,
        text=True,
        check=False,
        cwd=ROOT,
    )
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    assert "7-joint arm from the URDF" in done.stdout and "coupling" not in done.stdout


def test_check_names_the_coupled_drive(capsys):
    assert main(["check", "--problem", str(PROBLEMS / "staubli_tx40.toml")]) == 0
    assert "coupling: drive joint_6 also acts on joint_5 (ratio 1)" in capsys.readouterr().out


def _arguments(command: str, problem: Path, tmp_path: Path) -> list[str]:
    """The command's minimal arguments on `problem` (outputs under tmp_path)."""
    out = tmp_path / ("trial.csv" if command in ("simulate", "excite") else "out")
    extra = ["--real", str(PROBLEMS / "tudor_2dof.toml")] if command == "calibrate" else []
    return [command, "--problem", str(problem), *extra, "--out", str(out)]


@pytest.mark.parametrize("command", ["audit", "calibrate"])  # online, excite, simulate, diagnose: any arm
def test_two_joint_commands_refuse_a_urdf_arm(command, tmp_path, capsys):
    problem = PROBLEMS / "kuka_lwr4.toml"
    assert main(_arguments(command, problem, tmp_path)) == 2
    err = capsys.readouterr().err
    assert f"{command} supports two-joint problems only; {problem} describes a 7-joint URDF arm" in err
    assert "Traceback" not in err and err.count("\n") == 1
    assert not list(tmp_path.iterdir())  # refused before any work


def test_calibrate_refuses_a_urdf_arm_as_the_real_problem(tmp_path, capsys):
    real = PROBLEMS / "staubli_tx40.toml"
    args = ["calibrate", "--problem", str(PROBLEMS / "tudor_2dof.toml"), "--real", str(real)]
    assert main([*args, "--out", str(tmp_path / "out")]) == 2
    assert f"{real} describes a 6-joint URDF arm" in capsys.readouterr().err


def test_a_two_joint_urdf_on_the_n_joint_path_is_refused_too(tmp_path, capsys):
    """Two joints of the KUKA (axes not parallel): the n-joint path, which the two-link commands cannot take;
    the sentence says why a two-joint problem is refused."""
    urdf = ROOT / "data" / "kuka_lwr4" / "kuka_lwr4.urdf"
    problem = tmp_path / "two.toml"
    robot = f'urdf = "{urdf.as_posix()}"\njoints = ["lwr_0_joint", "lwr_1_joint"]\ngravity = 9.81\n'
    problem.write_text(f'name = "two"\n[robot]\n{robot}')
    assert main(["audit", "--problem", str(problem), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "describes a 2-joint URDF arm on the n-joint path (its axes are not parallel" in err
