"""Problem files: the shipped ones load; every kind of mistake names the file and key, exit status 2."""

from __future__ import annotations

from pathlib import Path

import pytest

from ident_opt.cli import main
from ident_opt.errors import InputError
from ident_opt.problem import load_problem

from .conftest import PROBLEMS

BASE = (PROBLEMS / "tudor_2dof.toml").read_text()


def test_shipped_problems_load(physical_problem, paper_problem):
    assert physical_problem.robot.convention == "physical"
    assert paper_problem.robot.convention == "paper"
    for problem in (physical_problem, paper_problem):
        assert [p.name for p in problem.data.trials] == ["exp1.csv", "exp2.csv"]
        assert all(p.is_file() for p in problem.data.trials)
        assert problem.robot.joint1.current_to_torque == pytest.approx(10.304)
        assert problem.robot.joint2.current_to_torque == pytest.approx(3.1734)
        assert problem.split.train_fraction == 0.7 and len(problem.split.seeds) == 10


def test_minimal_problem_is_name_and_robot(tmp_path):
    robot = BASE[BASE.index("[robot]") : BASE.index("# The real MERIt")]
    path = tmp_path / "minimal.toml"
    path.write_text('name = "mine"\n' + robot)
    problem = load_problem(path)
    assert problem.data.trials == () and problem.simulate is None


def edit(tmp_path: Path, old: str, new: str) -> Path:
    assert old in BASE
    path = tmp_path / "broken.toml"
    text = BASE.replace(old, new, 1).replace('"../data/merit/', f'"{PROBLEMS.parent}/data/merit/')
    path.write_text(text)
    return path


CASES = [
    ("length = 0.430 ", "lenght = 0.430 ", ["lenght", "[robot.link1]"]),
    ("gear_ratio = 230.0", "gear_ratio = -230.0", ["gear_ratio", "[robot.joint1]", "positive"]),
    ("density = 7800.0                     # kg/m^3", 'density = "steel"', ["density", "number"]),
    ('convention = "physical"', 'convention = "metric"', ["convention", "physical"]),
    ("actuator_mass = 1.6680", "", ["actuator_mass", "missing"]),
    ("[robot.joint2]", "[robot.joint3]", ["joint3"]),
    ("train_fraction = 0.7", "train_fraction = 1.5", ["train_fraction"]),
    ('components = "auto"', "components = 0", ["components"]),
    ("header = false", "header = 1", ["header", "true or false"]),
    ("q1 = 2", "qq1 = 2", ["qq1", "[data.columns]"]),
    ("width = 0.015                        # m", "width = 0.0", ["width", "positive"]),
]


@pytest.mark.parametrize("old,new,words", CASES, ids=[c[2][0] for c in CASES])
def test_bad_problem_file_names_file_and_key(tmp_path, capsys, old, new, words):
    path = edit(tmp_path, old, new)
    with pytest.raises(InputError) as err:
        load_problem(path)
    message = str(err.value)
    assert str(path) in message
    for word in words:
        assert word in message
    # The same through the real CLI: exit status 2, one message, no traceback.
    assert main(["check", "--problem", str(path)]) == 2
    stderr = capsys.readouterr().err
    assert "Traceback" not in stderr and str(path) in stderr


def test_missing_and_malformed_problem_files(tmp_path, capsys):
    assert main(["check", "--problem", str(tmp_path / "nope.toml")]) == 2
    assert "not found" in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text("name = [unclosed")
    assert main(["check", "--problem", str(bad)]) == 2
    assert "not a valid TOML" in capsys.readouterr().err


def test_simulate_section_is_checked_when_the_file_loads(tmp_path):
    text = (PROBLEMS / "tudor_sim.toml").read_text()
    path = tmp_path / "sim.toml"
    path.write_text(
        text.replace("[simulate]", '[simulate]\neffects = ["springs:k=3"]', 1)
        if "effects" not in text
        else text.replace("effects = [", 'effects = ["springs:k=3", ', 1)
    )
    with pytest.raises(InputError) as err:
        load_problem(path)
    assert str(path) in str(err.value) and "springs" in str(err.value) and "effects" in str(err.value)
