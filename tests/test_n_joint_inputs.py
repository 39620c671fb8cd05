"""Inputs of arms with n joints (the problem file's and data format's contract, "Arms with n joints"): `[limits]`
for any n (lists of n, one number for every joint, the URDF's <limit> as defaults), `[reference]` by names or
by a URDF validated at load, currents per joint from `[robot.<joint>]`, and un-mapping a standard column
(`i1 = false`). Every bad input exits 2 naming the culprit, with nothing written; the good ones run `check`,
`compare`, `identify` and `codegen` without a traceback. On the shipped KUKA (7 joints) and TX40 (6 joints) and
on a 3-joint URDF arm written here."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ident_opt.adaptation.lines import LineParser, Mapping
from ident_opt.cli import main
from ident_opt.data.loader import load_dataset
from ident_opt.errors import InputError
from ident_opt.problem import load_problem
from tests.test_urdf_arm import TWISTED

ROOT = Path(__file__).resolve().parents[1]
#: The shipped n-joint arms: name -> (URDF, joints).
SHIPPED = {
    "kuka": (ROOT / "data" / "kuka_lwr4" / "kuka_lwr4.urdf", tuple(f"lwr_{i}_joint" for i in range(7))),
    "tx40": (ROOT / "data" / "staubli_tx40" / "tx40.urdf", tuple(f"joint_{i}" for i in range(1, 7))),
}
#: The 3-joint arm's drives: joint -> (torque constant [N m/A], gear ratio).
DRIVES = {"a": (0.05, 100.0), "b": (0.04, 120.0), "c": (0.03, 50.0)}
LIMIT_KEYS = ("position_min", "position_max", "velocity", "acceleration", "torque")


def _robot(urdf: Path | str, joints: tuple[str, ...], drives: dict | None = None) -> str:
    """A `[robot]` section of a URDF arm, with `[robot.<joint>]` drive data (torque constant, gear ratio)."""
    names = ", ".join(f'"{j}"' for j in joints)
    text = f'[robot]\nurdf = "{urdf}"\njoints = [{names}]\ngravity = 9.81\n'
    for joint, (kt, ratio) in (drives or {}).items():
        text += f"[robot.{joint}]\ntorque_constant = {kt}\ngear_ratio = {ratio}\n"
    return text


def _write(tmp_path: Path, robot: str, extra: str = "", name: str = "p.toml") -> Path:
    path = tmp_path / name
    path.write_text(f'name = "n-joint"\n{robot}\n{extra}')
    return path


def _toml(value) -> str:
    """A value of the `[limits]` helper in TOML: a list, a number, or a string written as it is."""
    if isinstance(value, list):
        return "[" + ", ".join(repr(v) if isinstance(v, str) else f"{v:g}" for v in value) + "]"
    return value if isinstance(value, str) else f"{value:g}"


def _limits(n: int, **replace) -> str:
    """A `[limits]` section of n joints (every key a list of n numbers), with keys replaced or dropped (None)."""
    values = {
        "position_min": [-1.0 - 0.1 * j for j in range(n)],
        "position_max": [1.0 + 0.1 * j for j in range(n)],
        "velocity": [2.0] * n,
        "acceleration": [8.0 + j for j in range(n)],
        "torque": [50.0] * n,
    }
    values.update(replace)
    lines = [f"{k} = {_toml(v)}" for k, v in values.items() if v is not None]
    return "[limits]\n" + "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def arm3(tmp_path_factory) -> Path:
    """A folder with the 3-joint arm (`TWISTED`: joints a, b, c; b is continuous, without a <limit>)."""
    folder = tmp_path_factory.mktemp("arm3")
    (folder / "arm.urdf").write_text(TWISTED)
    return folder


def _arm3_robot(drives: dict | None = DRIVES) -> str:
    return _robot("arm.urdf", ("a", "b", "c"), drives)


def _shipped(tmp_path: Path, name: str, extra: str = "") -> Path:
    urdf, joints = SHIPPED[name]
    return _write(tmp_path, _robot(urdf, joints), extra)


def _refused(path: Path, capsys, *named: str) -> str:
    """`load_problem` and `ident-opt check` refuse `path`: exit 2, one paragraph naming the file and `named`."""
    with pytest.raises(InputError) as info:
        load_problem(path)
    message = str(info.value)
    assert str(path) in message, message
    for text in named:
        assert text in message, (text, message)
    assert main(["check", "--problem", str(path)]) == 2
    captured = capsys.readouterr()
    assert "Traceback" not in captured.out + captured.err
    return message


# ---------------------------------------------------------------------------------------------- (a) [limits]
@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_per_joint_and_scalar_limits_load_for_a_shipped_arm(tmp_path, name):
    n = len(SHIPPED[name][1])
    limits = load_problem(_shipped(tmp_path, name, _limits(n))).limits
    assert limits.acceleration == tuple(8.0 + j for j in range(n)) and limits.torque == (50.0,) * n
    assert all(len(getattr(limits, key)) == n for key in LIMIT_KEYS)
    scalar = "[limits]\nposition_min = -1\nposition_max = 1.5\nvelocity = 2\nacceleration = 10.0\ntorque = 40\n"
    limits = load_problem(_shipped(tmp_path, name, scalar)).limits
    assert limits.position_min == (-1.0,) * n and limits.velocity == (2.0,) * n and limits.torque == (40.0,) * n
    assert all(isinstance(v, float) for v in limits.position_max)


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_urdf_limits_are_the_defaults(tmp_path, name):
    problem = load_problem(_shipped(tmp_path, name, "[limits]\nacceleration = 10.0\n"))
    urdf = problem.robot.limits()
    limits = problem.limits
    for key in ("position_min", "position_max", "velocity", "torque"):
        assert getattr(limits, key) == tuple(urdf[key]), key
    assert limits.acceleration == (10.0,) * problem.robot.n_joints
    # A key the file gives replaces the URDF's for every joint.
    n = problem.robot.n_joints
    given = load_problem(_shipped(tmp_path, name, "[limits]\nacceleration = 10.0\nvelocity = 1.0\n")).limits
    assert given.velocity == (1.0,) * n and given.torque == tuple(urdf["torque"])


def test_limits_of_the_three_joint_arm(arm3, capsys):
    path = _write(arm3, _arm3_robot(), _limits(3))
    assert load_problem(path).limits.position_max == (1.0, 1.1, 1.2)
    # The URDF's <limit> lacks joint b (continuous): its position limits must come from the file.
    bare = _write(arm3, _arm3_robot(), "[limits]\nacceleration = 5.0\n", "bare.toml")
    message = _refused(bare, capsys, "'position_min'", "[limits]", "joint 2 (b)")
    assert "<limit" in message


def test_a_key_the_urdf_lacks_for_one_joint_names_that_joint(arm3, capsys):
    text = "[limits]\nacceleration = 5.0\nposition_min = -2\nposition_max = 2\n"
    path = _write(arm3, _arm3_robot(), text, "partial.toml")
    _refused(path, capsys, "'velocity'", "[limits]", "joint 2 (b)")
    # The optional torque: the URDF's efforts of a and c are not dropped silently either.
    path = _write(arm3, _arm3_robot(), text + "velocity = 1.5\n", "partial_torque.toml")
    _refused(path, capsys, "'torque'", "joint 2 (b)")
    limits = load_problem(_write(arm3, _arm3_robot(), text + "velocity = 1.5\ntorque = [1, 2, 3]\n")).limits
    assert limits.torque == (1.0, 2.0, 3.0) and limits.velocity == (1.5,) * 3


def test_no_urdf_limit_at_all_leaves_torque_unlimited(tmp_path):
    urdf = tmp_path / "arm.urdf"
    limit = '<limit effort="1" lower="-3" upper="3" velocity="1"/>'
    urdf.write_text(TWISTED.replace(limit, "").replace('type="revolute"', 'type="continuous"'))
    limits = load_problem(_write(tmp_path, _robot(urdf, ("a", "b", "c")), _limits(3, torque=None))).limits
    assert limits.torque is None


@pytest.mark.parametrize(
    ("replace", "named"),
    [
        ({"velocity": [2.0, 2.0]}, ("'velocity'", "3", "joint 3 (c)")),  # too short: the joint without a value
        ({"acceleration": [1.0, 2.0, 3.0, 4.0]}, ("'acceleration'", "3", "4")),  # too long
        ({"torque": [1.0, "x", 3.0]}, ("'torque'", "joint 2 (b)", "'x'")),  # not a number
        ({"velocity": [1.0, 2.0, -1.0]}, ("'velocity'", "joint 3 (c)")),  # out of range
        ({"acceleration": "nan"}, ("'acceleration'",)),  # a scalar that is not finite
        ({"velocity": '"fast"'}, ("'velocity'",)),  # neither a number nor a list
        ({"position_max": [1.0, -1.2, 1.2]}, ("'position_min'", "'position_max'", "joint 2 (b)")),  # min ≥ max
        ({"position_min": 0.5, "position_max": 0.5}, ("'position_max'", "joint 1 (a)")),  # equal for every joint
    ],
    ids=["short", "long", "not-a-number", "range", "nan", "string", "min-max", "equal"],
)
def test_bad_limits_name_key_and_joint(arm3, capsys, replace, named):
    path = _write(arm3, _arm3_robot(), _limits(3, **replace), "bad.toml")
    _refused(path, capsys, "[limits]", *named)


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_bad_limits_of_a_shipped_arm(tmp_path, capsys, name):
    joints = SHIPPED[name][1]
    n = len(joints)
    path = _shipped(tmp_path, name, _limits(n, velocity=[2.0] * (n - 1)))
    _refused(path, capsys, "'velocity'", f"{n}", f"joint {n} ({joints[-1]})")
    path = _shipped(tmp_path, name, _limits(n, position_min=[5.0] + [-1.0] * (n - 1)))
    _refused(path, capsys, "'position_max'", f"joint 1 ({joints[0]})")


def _planar(tmp_path: Path, extra: str) -> Path:
    """The datasheet robot of `tudor_2dof.toml` (no limits, no data) with `extra` sections."""
    text = (ROOT / "problems" / "tudor_2dof.toml").read_text()
    return _write(tmp_path, text[text.index("[robot]") : text.index("[limits]")], extra)


def test_planar_limits_keep_their_form(tmp_path):
    # The two-joint arm of the datasheet: lists of 2, or one number for both joints; no defaults.
    limits = load_problem(_planar(tmp_path, _limits(2, velocity=3.0))).limits
    assert limits.velocity == (3.0, 3.0) and limits.position_min == (-1.0, -1.1)
    with pytest.raises(InputError, match=r"key 'acceleration' in \[limits\] is required"):
        load_problem(_planar(tmp_path, _limits(2, acceleration=None)))


# ---------------------------------------------------------------------------------------------- (b) [reference]
#: The 3-joint arm as a paper identified it: other masses, a renamed tip link, friction on joint a.
REFERENCE_URDF = (
    TWISTED.replace('<mass value="2.0"/>', '<mass value="2.2"/>')
    .replace('"l4"', '"tip"')
    .replace('<axis xyz="0 0 1"/>', '<axis xyz="0 0 1"/><dynamics damping="0.3" friction="0.2"/>')
)


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_reference_by_names_and_by_urdf_on_a_shipped_arm(tmp_path, capsys, name):
    urdf, joints = SHIPPED[name]
    robot = load_problem(_shipped(tmp_path, name)).robot
    link = robot.arm.links[1]
    text = f'[reference]\nlabel = "a paper"\n[reference.parameters]\nm_{link} = 2.5\nfv_{joints[0]} = 0.1\n'
    reference = load_problem(_shipped(tmp_path, name, text)).reference
    assert reference.label == "a paper" and reference.parameters == {f"m_{link}": 2.5, f"fv_{joints[0]}": 0.1}
    assert reference.urdf is None
    # The arm's own URDF as the reference: its inertials are the CAD prior's, and it has no <dynamics>.
    reference = load_problem(_shipped(tmp_path, name, f'[reference]\nlabel = "CAD"\nurdf = "{urdf}"\n')).reference
    _, pi = robot.reference(reference.parameters)
    assert reference.urdf == urdf and np.allclose(pi, robot.arm.cad_parameters())
    _refused(_shipped(tmp_path, name, text.replace(f"m_{link}", "m_nowhere")), capsys, "'m_nowhere'", "[reference")


def test_reference_by_urdf(arm3):
    (arm3 / "ref.urdf").write_text(REFERENCE_URDF)
    problem = load_problem(_write(arm3, _arm3_robot(), '[reference]\nlabel = "paper"\nurdf = "ref.urdf"\n', "r.toml"))
    params = problem.reference.parameters
    assert params["m_l1"] == pytest.approx(2.2) and params["m_l2"] == pytest.approx(1.7)  # l3 merged into l2
    assert params["m_l4"] == pytest.approx(0.8)  # the reference's "tip" is the problem's l4, by position
    assert params["fv_a"] == pytest.approx(0.3) and params["fc_a"] == pytest.approx(0.2)
    arm, pi = problem.robot.reference(params)
    assert arm == problem.robot.arm and pi[0] == pytest.approx(2.2)
    assert np.allclose(pi[10:30], arm.cad_parameters()[10:30])  # links l2 and l4 are the problem's own


@pytest.mark.parametrize(
    ("text", "named"),
    [
        ("[reference.parameters]\nm_nowhere = 1.0\n", ("'m_nowhere'", "[reference")),
        ('urdf = "missing_joint.urdf"\n', ("'c'", "[reference]", "missing_joint.urdf")),
        ('urdf = "nowhere.urdf"\n', ("[reference]", "nowhere.urdf")),
        ('urdf = "ref.urdf"\n[reference.parameters]\nm_l1 = 1.0\n', ("[reference]", "urdf", "parameters")),
        ("", ("[reference]", "urdf", "parameters")),
    ],
    ids=["unknown-name", "urdf-lacks-joint", "urdf-missing", "both", "neither"],
)
def test_bad_reference_is_refused_at_load(arm3, capsys, text, named):
    (arm3 / "ref.urdf").write_text(REFERENCE_URDF)
    (arm3 / "missing_joint.urdf").write_text(TWISTED.replace('joint name="c"', 'joint name="c2"'))
    path = _write(arm3, _arm3_robot(), f'[reference]\nlabel = "x"\n{text}', "bad_ref.toml")
    _refused(path, capsys, *named)


def test_reference_urdf_friction_the_model_lacks_is_named(arm3, capsys):
    (arm3 / "ref.urdf").write_text(REFERENCE_URDF)
    robot = _arm3_robot().replace("gravity = 9.81\n", "gravity = 9.81\nfriction = false\n")
    path = _write(arm3, robot, '[reference]\nlabel = "x"\nurdf = "ref.urdf"\n', "no_friction.toml")
    _refused(path, capsys, "[reference]", "'a'", "friction")


def test_planar_reference_checked_at_load(tmp_path, capsys):
    from tests.test_data import minimal_problem

    good = minimal_problem(tmp_path, '[reference]\nlabel = "x"\n[reference.parameters]\na1 = 0.5\nia2 = 0.01\n')
    assert load_problem(good).reference.parameters == {"a1": 0.5, "ia2": 0.01}
    bad = minimal_problem(tmp_path, '[reference]\nlabel = "x"\n[reference.parameters]\na9 = 0.5\n')
    _refused(bad, capsys, "'a9'", "[reference.parameters]")
    urdf = minimal_problem(tmp_path, f'[reference]\nlabel = "x"\nurdf = "{SHIPPED["kuka"][0]}"\n')
    _refused(urdf, capsys, "'urdf'", "[reference]", "planar")


# ---------------------------------------------------------------------------------------------- (c) currents
def _motion(n: int = 600, rate: float = 100.0) -> pd.DataFrame:
    """A smooth motion of the 3 joints with its exact velocities and accelerations."""
    t = np.arange(n) / rate
    frame = pd.DataFrame({"t": t})
    for j in range(3):
        w, phase = 0.7 + 0.45 * j, 0.3 * j
        frame[f"q{j + 1}"] = 0.8 * np.sin(w * t + phase)
        frame[f"dq{j + 1}"] = 0.8 * w * np.cos(w * t + phase)
        frame[f"ddq{j + 1}"] = -0.8 * w**2 * np.sin(w * t + phase)
    return frame


def _trial(problem, kind: str = "i", seed: int = 0) -> pd.DataFrame:
    """A trial of the 3-joint arm: its URDF inertials with friction, logged as torques ("tau") or currents ("i")."""
    arm = problem.robot.arm
    frame = _motion()
    q, dq, ddq = (frame[[f"{s}{j}" for j in (1, 2, 3)]].to_numpy() for s in ("q", "dq", "ddq"))
    truth = arm.cad_parameters()
    truth[arm.n_link_params :] = 0.05
    tau = arm.predict(truth, q, dq, ddq) + 0.002 * np.random.default_rng(seed).standard_normal(q.shape)
    for j, (kt, ratio) in enumerate(DRIVES.values()):
        frame[f"{kind}{j + 1}"] = tau[:, j] / (kt * ratio) if kind == "i" else tau[:, j]
    return frame


def test_currents_give_the_torques_of_the_same_trial(arm3):
    problem = load_problem(_write(arm3, _arm3_robot(), name="c.toml"))
    (arm3 / "tau.csv").write_text(_trial(problem, "tau").to_csv(index=False))
    (arm3 / "i.csv").write_text(_trial(problem, "i").to_csv(index=False))
    by_tau = load_dataset(arm3 / "tau.csv", problem.data, problem.robot)
    by_current = load_dataset(arm3 / "i.csv", problem.data, problem.robot)
    assert np.allclose(by_current.tau, by_tau.tau, rtol=1e-12, atol=1e-12)
    assert np.allclose(by_current.q, by_tau.q)


def test_currents_without_a_torque_constant_name_the_joint(arm3, capsys):
    drives = {k: v for k, v in DRIVES.items() if k != "b"}
    problem = load_problem(_write(arm3, _arm3_robot(drives), name="no_b.toml"))
    (arm3 / "i.csv").write_text(_trial(problem, "i").to_csv(index=False))
    with pytest.raises(InputError, match=r"\[robot\.b\]") as info:
        load_dataset(arm3 / "i.csv", problem.data, problem.robot)
    assert "[robot.a]" not in str(info.value) and "torque_constant" in str(info.value)
    assert main(["check", "--problem", str(arm3 / "no_b.toml"), "--data", str(arm3 / "i.csv")]) == 2
    assert "[robot.b]" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------- (d) un-mapping
def _both(problem) -> pd.DataFrame:
    """A trial with currents i1…i3 and, beside them, a torque column per joint that is not the joint torque
    (a commanded value, say: here ten times too large)."""
    frame = _trial(problem, "i")
    torques = _trial(problem, "tau")
    for j in (1, 2, 3):
        frame[f"tau{j}"] = 10.0 * torques[f"tau{j}"]
    return frame


def test_unmapped_currents_let_a_file_with_both_be_read_by_torques(arm3, capsys):
    problem = load_problem(_write(arm3, _arm3_robot(), name="c.toml"))
    (arm3 / "both.csv").write_text(_both(problem).to_csv(index=False))
    with pytest.raises(InputError, match="both torques"):
        load_dataset(arm3 / "both.csv", problem.data, problem.robot)
    unmapped = "[data.columns]\ni1 = false\ni2 = false\ni3 = false\n"
    by_tau = load_problem(_write(arm3, _arm3_robot(), unmapped, "unmap.toml"))
    assert by_tau.data.ignored == ("i1", "i2", "i3")
    data = load_dataset(arm3 / "both.csv", by_tau.data, by_tau.robot)
    assert {"i1", "i2", "i3"} <= set(data.extra.columns)  # unread by the models, kept as extra channels
    assert np.allclose(data.tau, 10.0 * _trial(problem, "tau")[["tau1", "tau2", "tau3"]].to_numpy())
    # The case: the torques from the currents by a scale, the currents themselves not read.
    scales = {j: kt * ratio for j, (kt, ratio) in zip((1, 2, 3), DRIVES.values())}
    remap = "[data.columns]\n" + "".join(
        f'tau{j} = {{ column = "i{j}", scale = {scales[j]!r} }}\ni{j} = false\n' for j in (1, 2, 3)
    )
    remapped = load_problem(_write(arm3, _arm3_robot(), remap, "remap.toml"))
    data = load_dataset(arm3 / "both.csv", remapped.data, remapped.robot)
    assert np.allclose(data.tau, _trial(problem, "i")[["i1", "i2", "i3"]].to_numpy() * list(scales.values()))
    (arm3 / "i.csv").write_text(_trial(problem, "i").to_csv(index=False))
    assert np.allclose(data.tau, load_dataset(arm3 / "i.csv", problem.data, problem.robot).tau)
    assert main(["check", "--problem", str(arm3 / "remap.toml"), "--data", str(arm3 / "both.csv")]) == 0
    assert "Traceback" not in capsys.readouterr().err


def test_unmapping_one_current_of_three_names_it(arm3):
    problem = load_problem(_write(arm3, _arm3_robot(), "[data.columns]\ni2 = false\n", "one.toml"))
    (arm3 / "i.csv").write_text(_trial(problem, "i").to_csv(index=False))
    with pytest.raises(InputError, match=r"'i2'.*false"):
        load_dataset(arm3 / "i.csv", problem.data, problem.robot)


@pytest.mark.parametrize(
    ("entry", "named"),
    [("q1 = false", "'q1'"), ("t = false", "'t'"), ("i1 = true", "'i1'")],
)
def test_unmapping_refused_where_it_makes_no_sense(arm3, capsys, entry, named):
    path = _write(arm3, _arm3_robot(), f"[data.columns]\n{entry}\n", "bad_unmap.toml")
    _refused(path, capsys, named, "[data.columns]")


def test_unmapping_on_a_planar_arm_and_in_the_stream(tmp_path):
    from tests.conftest import kept
    from tests.test_data import minimal_problem, trial_frame

    frame = trial_frame()
    frame["i1"], frame["i2"] = frame["tau1"] / 10.0, frame["tau2"] / 5.0
    path = tmp_path / "both.csv"
    frame.to_csv(path, index=False)
    problem = load_problem(minimal_problem(tmp_path, "\n[data.columns]\ni1 = false\ni2 = false\n"))
    data = load_dataset(path, problem.data, problem.robot)
    assert np.allclose(data.tau, kept(frame, data)[["tau1", "tau2"]].to_numpy())
    positions, _ = Mapping.from_spec(problem.data).resolve_header(list(frame.columns))
    assert "i1" not in positions and "i2" not in positions and positions["tau1"] == 3
    mapped = load_problem(
        minimal_problem(
            tmp_path,
            '\n[data.columns]\ntau1 = { column = "i1", scale = 10.0 }\ni1 = false\n'
            'tau2 = { column = "i2", scale = 5.0 }\ni2 = false\n',
        )
    )
    positions, conversions = Mapping.from_spec(mapped.data).resolve_header(list(frame.columns))
    assert positions["tau1"] == list(frame.columns).index("i1") and "i1" not in positions
    assert conversions["tau1"] == (10.0, 0.0)
    parser = LineParser(mapping=Mapping.from_spec(mapped.data))
    assert parser.parse(",".join(frame.columns)) is None
    sample = parser.parse(",".join(repr(float(v)) for v in frame.iloc[5]))
    assert sample["tau1"] == pytest.approx(10.0 * frame["i1"][5]) and "i1" not in sample


# ---------------------------------------------------------------------------------------------- (e) commands
@pytest.fixture(scope="module")
def workspace(arm3) -> Path:
    """The 3-joint arm logged with currents (train and test trials), with per-joint [limits] and a URDF
    [reference]: a problem every n-joint command runs on."""
    (arm3 / "ref.urdf").write_text(REFERENCE_URDF)
    problem = load_problem(_write(arm3, _arm3_robot(), name="plain.toml"))
    (arm3 / "train.csv").write_text(_trial(problem, "i", seed=1).to_csv(index=False))
    (arm3 / "test.csv").write_text(_trial(problem, "i", seed=2).to_csv(index=False))
    extra = (
        '[data]\ntrain = ["train.csv"]\ntest = ["test.csv"]\n'
        + _limits(3)
        + '[reference]\nlabel = "a paper"\nurdf = "ref.urdf"\n'
    )
    _write(arm3, _arm3_robot(), extra, "full.toml")
    return arm3


def _run(args: list[str], capsys) -> tuple[int, str]:
    status = main(args)
    captured = capsys.readouterr()
    text = captured.out + captured.err
    assert "Traceback" not in text
    return status, text


def test_check_compare_identify_export_on_the_three_joint_arm(workspace, capsys, tmp_path):
    problem = str(workspace / "full.toml")
    assert _run(["check", "--problem", problem], capsys)[0] == 0
    out, result = tmp_path / "compare", tmp_path / "compare.json"
    status, text = _run(
        ["compare", "--problem", problem, "--out", str(out), "--json", str(result), "--no-progress"], capsys
    )
    assert status == 0, text
    payload = json.loads(result.read_text())
    assert payload["parameters"]["reference"]["m_l1"] == pytest.approx(2.2)
    assert payload["parameters"]["reference"]["fv_a"] == pytest.approx(0.3)
    assert any(
        "reference" in by_estimator for protocol in payload["metrics"].values() for by_estimator in protocol.values()
    )
    status, text = _run(["identify", "--problem", problem, "--out", str(tmp_path / "identify")], capsys)
    assert status == 0, text
    for fmt, name in (("urdf", "arm.urdf"), ("mjcf", "arm.xml")):
        status, text = _run(["export", "--problem", problem, "--format", fmt, "--out", str(tmp_path / name)], capsys)
        assert status == 0 and (tmp_path / name).is_file(), text


@pytest.mark.skipif(shutil.which("gcc") is None and shutil.which("cc") is None, reason="no C compiler")
def test_codegen_on_the_three_joint_arm(workspace, capsys, tmp_path):
    out = tmp_path / "c"
    status, text = _run(["codegen", "--problem", str(workspace / "full.toml"), "--out", str(out)], capsys)
    assert status == 0, text
    assert json.loads((out / "parameters.json").read_text())["joints"] == ["a", "b", "c"]


#: A bad input on each new path: (what to change in full.toml, the culprit named).
BAD = {
    "limits": (("velocity = [2, 2, 2]", "velocity = [2, 2]"), "'velocity'"),
    "reference-name": (('urdf = "ref.urdf"', "[reference.parameters]\nm_nowhere = 1.0"), "'m_nowhere'"),
    "reference-urdf": (('urdf = "ref.urdf"', 'urdf = "missing_joint.urdf"'), "missing_joint.urdf"),
    "currents": (("[robot.b]\ntorque_constant = 0.04\n", "[robot.b]\n"), "[robot.b]"),
    "unmapping": (("[data]\n", "[data.columns]\nq2 = false\n[data]\n"), "'q2'"),
}


@pytest.mark.parametrize("command", ["check", "compare", "identify", "codegen", "export", "online", "excite"])
@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_on_each_new_path_exits_2_writing_nothing(workspace, capsys, tmp_path, command, case):
    (workspace / "missing_joint.urdf").write_text(TWISTED.replace('joint name="c"', 'joint name="c2"'))
    (old, new), named = BAD[case]
    text = (workspace / "full.toml").read_text()
    assert old in text
    path = workspace / f"bad_{case}.toml"
    path.write_text(text.replace(old, new, 1))
    out = tmp_path / "out"
    args = [command, "--problem", str(path)] + ([] if command == "check" else ["--out", str(out)])
    if command in ("export", "excite"):  # --out is the file to write; nothing may appear in its folder
        out.mkdir()
        args[-1] = str(out / ("arm.urdf" if command == "export" else "trajectory.csv"))
        args += ["--format", "urdf"] if command == "export" else ["--starts", "1"]
    if command == "compare":
        args.append("--no-progress")
    status, message = _run(args, capsys)
    assert status == 2, message
    assert named in message, message
    assert not out.exists() or not any(out.iterdir())
