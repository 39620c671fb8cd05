"""The README's "Your robot in five steps", followed as a newcomer would on an arm the project never saw: a 3-joint
URDF arm written here, a problem file as step 1 shows it, two logs recorded in the simulator, then every command
of the README's block (between its `five-steps` markers) run as written, from the problem's folder. Each must
succeed and leave what the README says: the reports with their `index.html`, the identified URDF, the C library."""

from __future__ import annotations

import json
import os
import re
import shlex
from pathlib import Path

import pytest

from ident_opt.cli import main
from tests.conftest import ROOT

README = ROOT / "README.md"
BLOCK = re.compile(r"<!-- five-steps:[^>]*-->\s*```sh\n(.*?)```\s*<!-- five-steps: end -->", re.S)


def _link(name: str, mass: float, length: float) -> str:
    """A slender link along z of `length` [m] and `mass` [kg], its centre of mass half way."""
    i_side = mass * length**2 / 12 + 1e-3
    return (
        f'<link name="{name}"><inertial><origin xyz="0 0 {length / 2}"/><mass value="{mass}"/>'
        f'<inertia ixx="{i_side}" iyy="{i_side}" izz="2e-3" ixy="0" ixz="0" iyz="0"/></inertial></link>'
    )


def _joint(name: str, parent: str, child: str, axis: str, z: float) -> str:
    return (
        f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="0 0 {z}"/><axis xyz="{axis}"/>'
        '<limit lower="-2.5" upper="2.5" velocity="3.0" effort="80"/></joint>'
    )


#: Three joints written for this test: a yaw, then two pitches (a spatial arm, gravity on two of them).
URDF = (
    '<?xml version="1.0"?><robot name="arm3"><link name="base"/>'
    + _link("upper", 2.0, 0.3)
    + _link("fore", 1.2, 0.25)
    + _link("hand", 0.5, 0.1)
    + _joint("shoulder", "base", "upper", "0 0 1", 0.1)
    + _joint("elbow", "upper", "fore", "0 1 0", 0.3)
    + _joint("wrist", "fore", "hand", "0 1 0", 0.25)
    + "</robot>"
)

#: Step 1's problem file, with each joint's friction and rotor inertia as problems/kuka_lwr4.toml shows them.
PROBLEM = """name = "mine"
[robot]
urdf = "arm.urdf"
joints = ["shoulder", "elbow", "wrist"]
gravity = 9.81
{drives}
[data]
train = ["log1.csv"]
test = ["log2.csv"]

[limits]
acceleration = 6.0
"""
DRIVE = '[robot.{joint}]\nside = "joint"\nviscous_friction = {fv}\ncoulomb_friction = {fc}\nrotor_inertia = {ia}\n'


def readme_commands() -> list[list[str]]:
    """The README's five-step commands, each as argv without the leading `ident-opt`."""
    block = BLOCK.search(README.read_text(encoding="utf-8"))
    assert block, "README.md: the five-steps block (its markers) is missing"
    lines = [line.split("#")[0].strip() for line in block[1].splitlines()]
    commands = [shlex.split(line) for line in lines if line]
    assert commands and all(c[0] == "ident-opt" for c in commands), commands
    return [c[1:] for c in commands]


@pytest.fixture(scope="module")
def newcomer(tmp_path_factory) -> Path:
    """The newcomer's folder: arm.urdf, mine.toml, two logs simulated from the arm (another seed each)."""
    folder = tmp_path_factory.mktemp("newcomer")
    (folder / "arm.urdf").write_text(URDF)
    drives = "".join(
        DRIVE.format(joint=j, fv=fv, fc=fc, ia=ia)
        for j, fv, fc, ia in (("shoulder", 0.5, 1.2, 0.1), ("elbow", 0.4, 1.0, 0.08), ("wrist", 0.1, 0.3, 0.01))
    )
    text = PROBLEM.format(drives=drives)
    (folder / "robot.toml").write_text(text.split("[data]")[0])  # the logs are recorded before they are listed
    (folder / "mine.toml").write_text(text)
    for seed, name in ((1, "log1.csv"), (2, "log2.csv")):
        argv = ["simulate", "--problem", str(folder / "robot.toml"), "--out", str(folder / name)]
        assert main([*argv, "--duration", "30", "--seed", str(seed)]) == 0
    return folder


def test_the_readme_five_steps_run_as_written_on_a_three_joint_arm(newcomer, capsys):
    here = Path.cwd()
    os.chdir(newcomer)
    try:
        for argv in readme_commands():
            status = main([*argv, "--no-progress"] if argv[0] in ("compare", "diagnose") else argv)
            assert status == 0, (argv, capsys.readouterr().err[-2000:])
    finally:
        os.chdir(here)
    out = newcomer / "results" / "mine"
    compare = json.loads((out / "compare.json").read_text())
    assert compare["joints"] == ["shoulder", "elbow", "wrist"] and compare["recommended"]
    diagnosis = json.loads((out / "diagnosis.json").read_text())
    assert diagnosis["verdict"] and len(diagnosis["nmse_after"]) == 3
    assert (out / "arm_identified.urdf").is_file() and (out / "codegen" / "parameters.json").is_file()
    for folder in (out, out / "diagnosis"):
        assert (folder / "index.html").is_file(), folder  # the page the README tells the newcomer to open
