"""Robots described by measured inertials ([robot.linkN] mass, com, inertia; [robot.jointN] side = "joint"):
parsed, turned into π by hand-checkable arithmetic, and refused with a clear message when mixed or incomplete."""

from __future__ import annotations

import numpy as np
import pytest

from ident_opt.arm.datasheet import datasheet_pi
from ident_opt.data.loader import load_dataset
from ident_opt.errors import InputError
from ident_opt.problem import DataSpec, load_problem

from .conftest import PROBLEMS

INERTIALS = """name = "two-link"
[robot]
gravity = 9.81
[robot.link1]
length = 0.2
mass = 0.6
com = 0.15
inertia = 0.002
[robot.link2]
length = 0.3
mass = 0.5
com = { x = 0.2 }
inertia = 0.004
[robot.joint1]
side = "joint"
viscous_friction = 0.01
coulomb_friction = { positive = 0.1, negative = 0.05 }
rotor_inertia = 0.003
[robot.joint2]
side = "joint"
rotor_inertia = 0.002
torque_constant = 0.09
gear_ratio = 6.0
"""


def write(tmp_path, text: str):
    path = tmp_path / "p.toml"
    path.write_text(text)
    return path


def test_inertials_give_pi_by_the_textbook_formulas(tmp_path):
    robot = load_problem(write(tmp_path, INERTIALS)).robot
    assert robot.description == "inertials" and robot.convention == "physical"
    pi = datasheet_pi(robot)
    m1, lc1, I1, m2, lc2, I2, l1, g = 0.6, 0.15, 0.002, 0.5, 0.2, 0.004, 0.2, 9.81
    a3 = I2 + m2 * lc2**2
    expected = {
        "a1": I1 + m1 * lc1**2 + m2 * l1**2 + a3 + 0.003,  # joint-1 armature folded into a1
        "a2": m2 * l1 * lc2,
        "a3": a3,
        "b1": g * (m1 * lc1 + m2 * l1),
        "b2": g * m2 * lc2,
        "fv1": 0.01,
        "fv2": 0.0,
        "fc1": 0.075,
        "fc2": 0.0,
        "ia2": 0.002,
    }
    assert pi == pytest.approx(expected, rel=1e-12)


def test_the_shipped_dfki_problem_loads_with_its_makers_values():
    problem = load_problem(PROBLEMS / "dfki_c0.toml")
    pi = datasheet_pi(problem.robot)
    # The makers' model_3.0: m2 l1 r2 and g (m1 r1 + m2 l1), g m2 r2.
    assert pi["a2"] == pytest.approx(0.56394 * 0.2 * 0.32127, rel=1e-9)
    assert pi["b1"] == pytest.approx(9.81 * (0.64169 * 0.2 + 0.56394 * 0.2), rel=1e-9)
    assert pi["b2"] == pytest.approx(9.81 * 0.56394 * 0.32127, rel=1e-9)


@pytest.mark.parametrize(
    ("old", "new", "words"),
    [
        ("mass = 0.6\n", "mass = 0.6\ndensity = 7800.0\n", ["[robot.link1]", "mixes a bar"]),
        (
            "length = 0.3\nmass = 0.5\ncom = { x = 0.2 }\ninertia = 0.004\n",
            "length = 0.3\nwidth = 0.01\nheight = 0.01\ndensity = 7800.0\n",
            ["different descriptions"],
        ),
        ('[robot.joint1]\nside = "joint"', '[robot.joint1]\nside = "motor"', ["'side'", "[robot.joint1]"]),
        ("com = { x = 0.2 }", "com = { x = 0.2, y = 0.01 }", ["'y'", "not supported"]),
        ("gravity = 9.81\n", 'gravity = 9.81\nconvention = "paper"\n', ["'convention'", "physical"]),
        ("inertia = 0.004", "inertia = -0.004", ["'inertia'", "[robot.link2]"]),
    ],
)
def test_bad_inertial_descriptions_name_the_table_and_key(tmp_path, old, new, words):
    assert old in INERTIALS
    path = write(tmp_path, INERTIALS.replace(old, new, 1))
    with pytest.raises(InputError) as err:
        load_problem(path)
    assert str(path) in str(err.value)
    for word in words:
        assert word in str(err.value)


def test_currents_need_a_torque_constant_for_every_joint(tmp_path):
    robot = load_problem(write(tmp_path, INERTIALS)).robot
    t = np.arange(100) / 100.0
    data = tmp_path / "currents.csv"
    np.savetxt(data, np.column_stack([t, 0.1 * t, 0.2 * t, t, t]), delimiter=",", header="t,q1,q2,i1,i2", comments="")
    with pytest.raises(InputError, match=r"\[robot.joint1\] gives no torque_constant"):
        load_dataset(data, DataSpec(), robot)


def test_compare_frees_the_rotor_inertia_of_a_geared_inertials_robot_by_default():
    robot = load_problem(PROBLEMS / "dfki_c0.toml").robot
    model, why = robot.model(), robot.model_note
    assert "ia2" in model.names and "rotor inertia" in why
    # The paper's bars-and-cylinders datasheet keeps the paper's rigid model.
    robot = load_problem(PROBLEMS / "tudor_2dof.toml").robot
    model, why = robot.model(), robot.model_note
    assert "ia2" not in model.names and why is None
