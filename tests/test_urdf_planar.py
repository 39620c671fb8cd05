"""A two-joint URDF with parallel axes becomes the planar two-link robot (`ident_opt.arm.planar_urdf`):

(a) its M(q), gravity torque and inverse dynamics equal Pinocchio's RNEA on the same URDF (angles mapped
through the stated offset and sign) to 1e-10, for a URDF with off-axis centres of mass, fixed child links,
rotated joint origins and a tilted plane, with and without a flipped elbow axis;
(b) the DFKI double pendulum C.0 written as a URDF gives the robot of problems/dfki_c0.toml;
(c) bad input exits 2 naming the culprit, and writes nothing.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pinocchio as pin
import pytest

from ident_opt.arm.chain_robot import ChainRobot
from ident_opt.arm.datasheet import datasheet_pi
from ident_opt.arm.planar import PHYSICAL
from ident_opt.arm.planar_urdf import UrdfPlanarRobot
from ident_opt.cli import main
from ident_opt.data.loader import load_dataset
from ident_opt.problem import DataSpec, load_problem

from .conftest import PROBLEMS


def _rpy_matrix(rpy: tuple[float, float, float]) -> np.ndarray:
    """URDF's rpy: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    return pin.rpy.rpyToMatrix(*rpy)


def _xyz(v) -> str:
    return " ".join(repr(float(x)) for x in v)


#: The elbow's origin rotation: its axis is written in its own frame so that it is parallel to the shoulder's.
ELBOW_RPY = (0.4, -0.9, 1.3)
#: The shoulder's axis in its own frame (its origin is rotated too, and the base is tilted).
SHOULDER_AXIS = np.array([0.0, 1.0, 0.0])


def twisted_planar(flip: bool = False, elbow_axis: np.ndarray | None = None, slide: bool = False) -> str:
    """A planar 2R arm in a tilted plane, written the hard way: a tilted base, rotated joint origins, COMs off
    the link lines (link 2) and along the axis (both), full inertia tensors, fixed child links with and without
    <inertial>, and <dynamics>. Link 1's two parts have their joint centre of mass on the line between axes."""
    axis2 = _rpy_matrix(ELBOW_RPY).T @ SHOULDER_AXIS * (-1.0 if flip else 1.0)
    axis2 = axis2 if elbow_axis is None else elbow_axis
    return f"""<robot name="twisted">
  <link name="world"/>
  <link name="base"/>
  <joint name="mount" type="fixed"><origin xyz="0.1 -0.2 0.5" rpy="0.2 0.1 -0.3"/>
    <parent link="world"/><child link="base"/></joint>
  <link name="l1"><inertial><origin xyz="0.12 0.05 0.0" rpy="0.1 0.2 0.3"/><mass value="1.3"/>
    <inertia ixx="0.011" ixy="0.001" ixz="-0.002" iyy="0.013" iyz="0.0015" izz="0.009"/></inertial></link>
  <joint name="shoulder" type="{"prismatic" if slide else "revolute"}"><origin xyz="0.0 0.03 0.1" rpy="0.0 0.0 0.6"/>
    <axis xyz="{_xyz(SHOULDER_AXIS)}"/><parent link="base"/><child link="l1"/>
    <limit lower="-3" upper="3" effort="10" velocity="10"/><dynamics damping="0.02" friction="0.15"/></joint>
  <link name="motor"><inertial><origin xyz="0.0 -0.04 0.0"/><mass value="0.7"/>
    <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.002" iyz="0" izz="0.0015"/></inertial></link>
  <joint name="motor_mount" type="fixed"><origin xyz="0.25 0.0 0.0" rpy="0.5 -0.2 0.1"/>
    <parent link="l1"/><child link="motor"/></joint>
  <link name="l2"><inertial><origin xyz="0.2 0.03 -0.06" rpy="-0.3 0.2 0.5"/><mass value="0.9"/>
    <inertia ixx="0.02" ixy="-0.002" ixz="0.001" iyy="0.018" iyz="0.003" izz="0.01"/></inertial></link>
  <joint name="elbow" type="continuous"><origin xyz="0.35 0.0 0.0" rpy="{_xyz(ELBOW_RPY)}"/>
    <axis xyz="{_xyz(axis2)}"/><parent link="l1"/><child link="l2"/><dynamics damping="0.05"/></joint>
  <link name="tool"><inertial><origin xyz="0.01 0.02 0.03"/><mass value="0.25"/>
    <inertia ixx="0.0003" ixy="0.00001" ixz="0" iyy="0.0002" iyz="0" izz="0.0004"/></inertial></link>
  <joint name="flange" type="fixed"><origin xyz="0.3 0.05 0.02" rpy="1.0 0.5 -0.7"/>
    <parent link="l2"/><child link="tool"/></joint>
  <link name="tip"/>
  <joint name="tip_frame" type="fixed"><origin xyz="0.1 0 0"/><parent link="tool"/><child link="tip"/></joint>
</robot>
"""


def _on_line(text: str) -> str:
    """The URDF with link 1's own centre of mass moved in the plane so that link 1 + motor have theirs on the
    line between the axes (the motor is off that line; l1 compensates it)."""
    # Solve for l1's COM z (in l1's frame, in the plane; its y is along the axis) that zeroes the lumped body's
    # offset from the line: the offset is affine in it.
    offsets = []
    for y in (0.0, 1.0):
        model = pin.buildModelFromXML(text.replace('<origin xyz="0.12 0.05 0.0"', f'<origin xyz="0.12 0.05 {y!r}"'))
        offsets.append(_line_offset(model))
    z = -offsets[0] / (offsets[1] - offsets[0])
    return text.replace('<origin xyz="0.12 0.05 0.0"', f'<origin xyz="0.12 0.05 {z!r}"')


def _line_offset(model: pin.Model) -> float:
    """The in-plane distance of joint 1's body's centre of mass from the line between the axes (signed)."""
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    n = data.oMi[1].rotation @ SHOULDER_AXIS
    p1, p2 = data.oMi[1].translation, data.oMi[2].translation
    d = (p2 - p1) - ((p2 - p1) @ n) * n
    c = data.oMi[1].act(model.inertias[1]).lever - p1
    return float(c @ np.cross(n, d / np.linalg.norm(d)))


def _write(tmp_path: Path, urdf: str, joints=("shoulder", "elbow"), extra: str = "", name: str = "arm") -> Path:
    (tmp_path / f"{name}.urdf").write_text(urdf)
    names = ", ".join(f'"{j}"' for j in joints)
    path = tmp_path / f"{name}.toml"
    path.write_text(f'name = "t"\n[robot]\nurdf = "{name}.urdf"\njoints = [{names}]\ngravity = 9.81\n{extra}')
    return path


#: What a URDF cannot say, per joint: reflected rotor inertia [kg m²], gear ratio, torque constant [N m/A].
EXTRAS = (
    "[robot.joint1]\nrotor_inertia = 0.03\ngear_ratio = 10.0\n"
    "[robot.joint2]\nrotor_inertia = 0.011\ngear_ratio = 6.0\ntorque_constant = 0.1\n"
)


@pytest.fixture(scope="module", params=[False, True], ids=["aligned", "flipped"])
def planar(request, tmp_path_factory):
    """(robot, Pinocchio model of the same URDF, URDF text) for the twisted arm, elbow axis aligned or flipped."""
    tmp_path = tmp_path_factory.mktemp("planar")
    text = _on_line(twisted_planar(flip=request.param))
    robot = load_problem(_write(tmp_path, text, extra=EXTRAS)).robot
    # Pinocchio reads a continuous joint as (cos, sin): the reference reads the elbow as revolute, same dynamics.
    limited = text.replace(
        'type="continuous">', 'type="revolute"><limit lower="-9" upper="9" effort="1" velocity="1"/>'
    )
    return robot, pin.buildModelFromXML(limited), request.param


def _states(robot: UrdfPlanarRobot, k: int = 40, seed: int = 0):
    """Random URDF states and the same states in the tool's convention: q_t = s q_u + θ, dq_t = s dq_u, …"""
    rng = np.random.default_rng(seed)
    q_u, dq_u, ddq_u = rng.uniform(-math.pi, math.pi, (k, 2)), rng.normal(0, 2, (k, 2)), rng.normal(0, 5, (k, 2))
    s, off = np.asarray(robot.angle_signs), np.asarray(robot.angle_offsets)
    return (q_u, dq_u, ddq_u), (s * q_u + off, s * dq_u, s * ddq_u), s


def test_planar_dynamics_equal_pinocchio_rnea(planar):
    robot, model, flipped = planar
    assert isinstance(robot, UrdfPlanarRobot) and robot.description == "inertials"
    assert robot.angle_signs == ((1.0, -1.0) if flipped else (1.0, 1.0))
    pi = PHYSICAL.vector(datasheet_pi(robot))
    (q_u, dq_u, ddq_u), (q_t, dq_t, ddq_t), s = _states(robot)
    data = model.createData()
    armature, damping, friction = np.array([0.03, 0.011]), np.array([0.02, 0.05]), np.array([0.15, 0.0])
    G_fn = PHYSICAL.function("G")
    tau_tool = PHYSICAL.predict(pi, q_t, dq_t, ddq_t)
    M_tool = PHYSICAL.mass_matrices(pi, q_t)
    worst = {"M": 0.0, "g": 0.0, "tau": 0.0}
    for k in range(len(q_u)):
        M = pin.crba(model, data, q_u[k])
        M = np.triu(M) + np.triu(M, 1).T + np.diag(armature)
        g = pin.computeGeneralizedGravity(model, data, q_u[k])
        tau = pin.rnea(model, data, q_u[k], dq_u[k], ddq_u[k]) + armature * ddq_u[k]
        tau += damping * dq_u[k] + friction * np.sign(dq_u[k])
        worst["M"] = max(worst["M"], np.abs(M_tool[k] - np.outer(s, s) * M).max())
        worst["g"] = max(
            worst["g"], np.abs(np.asarray(G_fn(q_t[k], np.zeros(2), np.zeros(2), pi)).ravel() - s * g).max()
        )
        worst["tau"] = max(worst["tau"], np.abs(tau_tool[k] - s * tau).max())
    print(f"worst |difference| to Pinocchio ({'flipped' if flipped else 'aligned'}): {worst}")
    assert max(worst.values()) <= 1e-10


def test_the_statement_names_the_offsets_and_the_flip(planar):
    robot, _, flipped = planar
    text = "\n".join(robot.statement)
    assert (
        f"q1 = q_urdf(shoulder) {'+' if robot.angle_offsets[0] >= 0 else '−'} {abs(robot.angle_offsets[0]):.6f}" in text
    )
    assert ("points against" in text) == flipped and ("−q_urdf(elbow)" in text) == flipped
    assert "along the axes loads only the bearings" in text  # the tilted base: part of g is along the axes


def test_data_in_the_urdf_convention_are_mapped(planar, tmp_path):
    robot, _, _ = planar
    (q_u, dq_u, ddq_u), (q_t, dq_t, ddq_t), s = _states(robot, 200, seed=3)
    tau_u = np.random.default_rng(4).normal(size=(200, 2))
    cols = {"t": np.arange(200) * 0.01}
    for name, arr in (("q", q_u), ("dq", dq_u), ("ddq", ddq_u), ("tau", tau_u)):
        cols.update({f"{name}{j + 1}": arr[:, j] for j in range(2)})
    pd.DataFrame(cols).to_csv(tmp_path / "trial.csv", index=False)
    trial = load_dataset(tmp_path / "trial.csv", DataSpec(), robot, allow_implausible=True)
    np.testing.assert_allclose(trial.q, q_t, atol=1e-12)
    np.testing.assert_allclose(trial.dq, dq_t, atol=1e-12)
    np.testing.assert_allclose(trial.ddq, ddq_t, atol=1e-12)
    np.testing.assert_allclose(trial.tau, s * tau_u, atol=1e-12)


def test_not_planar_takes_the_n_joint_path(tmp_path):
    """Axes not parallel, or link 1's centre of mass off the line between the axes: the n-joint ChainRobot, as
    before; form = "n-joint" asks for it on a planar arm too."""
    skew = _write(tmp_path, twisted_planar(elbow_axis=np.array([0.0, 0.3, 1.0])), name="skew")
    assert isinstance(load_problem(skew).robot, ChainRobot)
    off_line = _write(tmp_path, twisted_planar(), name="off_line")  # l1's COM y = 0.05: not on the line
    assert isinstance(load_problem(off_line).robot, ChainRobot)
    chain = _write(tmp_path, _on_line(twisted_planar()), extra='form = "n-joint"\n', name="chain")
    assert isinstance(load_problem(chain).robot, ChainRobot)


# ---------------------------------------------------------------------------------------- (b) the DFKI arm
def dfki_urdf(robot) -> str:
    """The DFKI double pendulum C.0 (model 3.0) as its makers draw it: axes along x, hanging down along −z at
    zero, from the values of problems/dfki_c0.toml (each link's inertia about its centre of mass)."""
    l1, l2, j1, j2 = robot.link1, robot.link2, robot.joint1, robot.joint2

    def inertial(link, z):
        i = repr(link.inertia)
        return (
            f'<inertial><origin xyz="0 0 {z!r}"/><mass value="{link.mass!r}"/>'
            f'<inertia ixx="{i}" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial>'
        )

    def dynamics(j):
        return f'<dynamics damping="{j.viscous_friction.mean!r}" friction="{j.coulomb_friction.mean!r}"/>'

    return f"""<robot name="double_pendulum">
  <link name="base_link"/>
  <link name="Link1">{inertial(l1, -l1.com)}</link>
  <joint name="Joint1" type="revolute"><origin xyz="0.0342 0 0"/><parent link="base_link"/><child link="Link1"/>
    <axis xyz="1 0 0"/><limit lower="-3.14" upper="3.14" effort="6" velocity="20"/>{dynamics(j1)}</joint>
  <link name="Link2">{inertial(l2, -l2.com)}</link>
  <joint name="Joint2" type="revolute"><origin xyz="0.0522 0 {-l1.length!r}"/><parent link="Link1"/>
    <child link="Link2"/><axis xyz="1 0 0"/><limit lower="-3.14" upper="3.14" effort="6" velocity="20"/>
    {dynamics(j2)}</joint>
  <link name="Weight"><inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/>
    </inertial></link>
  <joint name="Weight" type="fixed"><origin xyz="0 0 {-l2.length!r}"/><parent link="Link2"/><child link="Weight"/>
  </joint>
</robot>
"""


def test_dfki_urdf_gives_the_inertials_robot(tmp_path):
    reference = load_problem(PROBLEMS / "dfki_c0.toml")
    j1, j2 = reference.robot.joint1, reference.robot.joint2
    extra = "".join(
        f"[robot.joint{k}]\nrotor_inertia = {j.rotor_inertia!r}\ngear_ratio = {j.gear_ratio!r}\n"
        f"torque_constant = {j.torque_constant!r}\n"
        for k, j in ((1, j1), (2, j2))
    )
    robot = load_problem(_write(tmp_path, dfki_urdf(reference.robot), ("Joint1", "Joint2"), extra, "dfki")).robot
    assert isinstance(robot, UrdfPlanarRobot)
    for ours, theirs in ((robot.link1, reference.robot.link1), (robot.link2, reference.robot.link2)):
        for key in ("mass", "com", "inertia"):
            assert getattr(ours, key) == pytest.approx(getattr(theirs, key), abs=1e-15)
    assert robot.link1.length == pytest.approx(reference.robot.link1.length, abs=1e-15)
    assert robot.link2.length == pytest.approx(reference.robot.link2.length, abs=1e-15)  # axis 2 to the tip
    assert (robot.joint1, robot.joint2) == (j1, j2)
    ours, theirs = datasheet_pi(robot), datasheet_pi(reference.robot)
    assert ours.keys() == theirs.keys()
    for name in ours:
        assert ours[name] == pytest.approx(theirs[name], rel=1e-12, abs=1e-15), name
    # Zero hanging down: the tool's q1 is the logged angle − π/2 (dfki_c0.toml maps it in [data.columns]).
    q1_offset = reference.data.conversions["q1"][1]
    assert robot.angle_offsets == pytest.approx((q1_offset, 0.0), abs=1e-15)
    assert robot.angle_signs == (1.0, 1.0) and robot.gravity == 9.81


def test_the_shipped_urdf_example_is_the_inertials_example():
    """problems/dfki_c0_urdf.toml (the same arm from problems/dfki_c0.urdf) gives dfki_c0.toml's π, and its data
    columns differ only by the q1 offset the tool now applies itself."""
    urdf, reference = load_problem(PROBLEMS / "dfki_c0_urdf.toml"), load_problem(PROBLEMS / "dfki_c0.toml")
    assert isinstance(urdf.robot, UrdfPlanarRobot)
    ours, theirs = datasheet_pi(urdf.robot), datasheet_pi(reference.robot)
    assert ours.keys() == theirs.keys()
    for name in ours:
        assert ours[name] == pytest.approx(theirs[name], rel=1e-12, abs=1e-15), name
    assert urdf.robot.joints == reference.robot.joints
    assert urdf.robot.angle_offsets == pytest.approx((reference.data.conversions["q1"][1], 0.0), abs=1e-15)
    assert "q1" not in urdf.data.conversions and urdf.data.training == reference.data.training


# ---------------------------------------------------------------------------------------- (c) bad input
BAD = [
    ({"joints": ("shoulder", "nope")}, ["arm.urdf", "'nope'", "not in the URDF"]),
    ({"slide": True}, ["arm.urdf", "<joint name='shoulder'>", "prismatic"]),
    ({"no_inertial": True}, ["arm.urdf", "<link name='l2'>", "<inertial>"]),
    ({"elbow_axis": (0.0, 0.3, 1.0), "extra": 'form = "planar"\n'}, ["arm.urdf", "'elbow'", "not parallel"]),
    ({"extra": 'form = "planar"\n'}, ["arm.urdf", "off the line between the axes"]),
    ({"extra": 'form = "flat"\n'}, ["arm.toml", "'form'", "planar"]),
    ({"on_line": True, "extra": "[robot.elbow]\ngear_ratio = 6.0\n"}, ["arm.toml", "[robot.elbow]", "[robot.joint2]"]),
    ({"on_line": True, "extra": '[robot.joint2]\nside = "motor"\n'}, ["arm.toml", "'side'", "joint2"]),
    ({"on_line": True, "extra": "friction = false\n"}, ["arm.toml", "unknown key", "friction"]),
    ({"on_line": True, "damping": "-0.1"}, ["arm.urdf", "<joint name='shoulder'>", "damping='-0.1'"]),
]


@pytest.mark.parametrize(("case", "expected"), BAD, ids=[str(i) for i in range(len(BAD))])
def test_bad_input_exits_2_naming_the_culprit(tmp_path, capsys, case, expected):
    axis = case.get("elbow_axis")
    text = twisted_planar(elbow_axis=None if axis is None else np.asarray(axis), slide=case.get("slide", False))
    text = _on_line(text) if case.get("on_line") else text
    text = text.replace('damping="0.02"', f'damping="{case["damping"]}"') if "damping" in case else text
    if case.get("no_inertial"):
        start = text.index('<link name="l2">')
        text = text[:start] + '<link name="l2"/>' + text[text.index("</link>", start) + len("</link>") :]
    path = _write(tmp_path, text, case.get("joints", ("shoulder", "elbow")), case.get("extra", ""))
    before = sorted(tmp_path.iterdir())
    assert main(["check", "--problem", str(path), "--json", str(tmp_path / "out.json")]) == 2
    err = capsys.readouterr().err
    for text in expected:
        assert text in err, (text, err)
    assert sorted(tmp_path.iterdir()) == before  # nothing written


def _trial(model: pin.Model, path: Path, seed: int) -> Path:
    """A noise-free trial logged in the URDF's convention: q, dq, ddq of a multisine, τ from Pinocchio's RNEA with
    the file's friction and joint 1's rotor inertia (joint 2's, ia2, is not in the rigid model compare fits)."""
    t = np.arange(0.0, 20.0, 0.01)
    rng = np.random.default_rng(seed)
    amp, freq, phase = rng.uniform(0.3, 1.0, (3, 2)), rng.uniform(0.2, 0.8, (3, 2)), rng.uniform(0, 6, (3, 2))
    arg = 2 * np.pi * freq[None] * t[:, None, None] + phase[None]
    q = (amp * np.sin(arg)).sum(axis=1)
    dq = (amp * 2 * np.pi * freq * np.cos(arg)).sum(axis=1)
    ddq = -(amp * (2 * np.pi * freq) ** 2 * np.sin(arg)).sum(axis=1)
    data = model.createData()
    tau = np.array([pin.rnea(model, data, *state) for state in zip(q, dq, ddq)])
    tau += np.array([0.03, 0.0]) * ddq + np.array([0.02, 0.05]) * dq + np.array([0.15, 0.0]) * np.sign(dq)
    cols = {"t": t}
    for name, arr in (("q", q), ("dq", dq), ("ddq", ddq), ("tau", tau)):
        cols.update({f"{name}{j + 1}": arr[:, j] for j in range(2)})
    pd.DataFrame(cols).to_csv(path, index=False)
    return path


def _problem(robot, model, tmp_path: Path, data: str, extra: str = "") -> Path:
    """The test arm's problem file with a training and a test trial logged in the URDF's convention; `data`:
    the [data] keys, with {train} and {test} standing for the two files."""
    train, test = _trial(model, tmp_path / "train.csv", 1), _trial(model, tmp_path / "test.csv", 2)
    problem = tmp_path / "arm.toml"
    problem.write_text(
        Path(robot.urdf.parent / "arm.toml").read_text().replace('urdf = "arm.urdf"', f'urdf = "{robot.urdf}"')
        + "[data]\n"
        + data.format(train=train, test=test)
        + "[split]\nseeds = [0]\n"
        + extra
    )
    return problem


def test_compare_on_urdf_data_recovers_the_urdf_and_states_the_offsets(planar, tmp_path):
    """Data logged in the URDF's convention: compare maps them, OLS finds the URDF's π, and compare.md and the
    JSON state the offsets applied."""
    robot, model, _ = planar
    problem = _problem(robot, model, tmp_path, 'train = ["{train}"]\ntest = ["{test}"]\n')
    out = tmp_path / "out"
    assert (
        main(["compare", "--problem", str(problem), "--out", str(out), "--json", str(out / "c.json"), "--no-progress"])
        == 0
    )
    payload = json.loads((out / "c.json").read_text())
    truth, ols = payload["parameters"]["datasheet"], payload["parameters"]["ols"]
    for name in ("a1", "a2", "a3", "b1", "b2", "fv1", "fv2", "fc1", "fc2"):
        assert ols[name] == pytest.approx(truth[name], rel=1e-6, abs=1e-8), name
    assert payload["robot"] == list(robot.statement)
    assert "## Robot" in (out / "compare.md").read_text() and robot.statement[1] in (out / "compare.md").read_text()


def test_a_simulated_trial_is_written_in_the_urdf_convention(planar, tmp_path):
    """The simulator's CSV of a URDF arm is logged as the URDF would (read back, it is the simulated trial)."""
    from ident_opt.problem import SimulateSpec
    from ident_opt.simulator.cache import spec_trial

    robot, _, _ = planar
    trial = spec_trial(robot, SimulateSpec(duration=5.0), 0)
    back = load_dataset(trial.write(tmp_path / "sim.csv"), DataSpec(), robot)
    truth = trial.dataset()
    for name in ("q", "dq", "ddq", "tau"):
        np.testing.assert_allclose(getattr(back, name), getattr(truth, name), atol=1e-12, err_msg=name)
    logged = pd.read_csv(tmp_path / "sim.csv")
    np.testing.assert_allclose(robot.angle_signs[1] * logged["q2"] + robot.angle_offsets[1], truth.q[:, 1], atol=1e-12)


def test_identify_states_the_offsets(planar, tmp_path):
    """identify's README and JSON carry the robot's statement (the offsets applied to its data)."""
    robot, model, _ = planar
    extra = "[residual]\ncandidates = [1]\nmax_train_samples = 500\n"
    problem = _problem(robot, model, tmp_path, 'trials = ["{train}", "{test}"]\n', extra)
    out = tmp_path / "out"
    args = ["identify", "--problem", str(problem), "--out", str(out), "--json", str(out / "i.json")]
    assert main(args) == 0
    assert json.loads((out / "i.json").read_text())["robot"] == list(robot.statement)
    readme = next(p for p in out.rglob("*.md") if robot.statement[1] in p.read_text())
    assert "what was applied to its data" in readme.read_text()


def test_check_states_the_offset_applied(tmp_path, capsys):
    """`ident-opt check` prints the offsets and signs a URDF arm's data went through, and puts them in its JSON."""
    out = tmp_path / "check.json"
    assert main(["check", "--problem", str(PROBLEMS / "dfki_c0_urdf.toml"), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "as a planar two-link arm (joints Joint1, Joint2)" in text
    assert "q1 = q_urdf(Joint1) − 1.570796 rad (-90.00°)" in text and "q2 = q_urdf(Joint2) + 0.000000 rad" in text
    robot = json.loads(out.read_text())["robot"]
    assert robot["angle_signs"] == [1.0, 1.0] and robot["angle_offsets_rad"] == pytest.approx([-math.pi / 2, 0.0])


def test_link_lengths_are_axis_to_axis_and_axis_to_tip():
    """Link 2's length is its farthest frame (the DFKI URDF's tip at 0.3 m, with the centre of mass beyond it at
    0.32127 m, as the makers' model has it), so the physical fit's bounds are dfki_c0.toml's."""
    robot = load_problem(PROBLEMS / "dfki_c0_urdf.toml").robot
    assert robot.link1.length == pytest.approx(0.2, abs=1e-15) and robot.link2.length == pytest.approx(0.3, abs=1e-15)


def test_a_stream_in_the_urdf_convention_is_mapped(planar):
    """`online --stream` reads a URDF arm's samples as the batch loader does: q_t = s q_u + θ, the rest × s."""
    from ident_opt.adaptation.lines import LineParser, Mapping

    robot, _, _ = planar
    parser = LineParser(mapping=Mapping.from_spec(DataSpec(), robot))
    assert parser.parse("t,q1,q2,dq1,dq2,ddq1,ddq2,tau1,tau2") is None
    sample = parser.parse("0.0,0.1,-0.2,0.3,0.4,0.5,-0.6,0.7,0.8")
    s, off = robot.angle_signs, robot.angle_offsets
    assert sample["q1"] == pytest.approx(s[0] * 0.1 + off[0]) and sample["q2"] == pytest.approx(s[1] * -0.2 + off[1])
    assert sample["dq2"] == pytest.approx(s[1] * 0.4) and sample["tau2"] == pytest.approx(s[1] * 0.8)
    assert sample["ddq1"] == pytest.approx(0.5) and sample["t"] == 0.0


def test_codegen_readme_states_the_offsets(planar, tmp_path):
    """The generated C takes ident-opt's angles: its README and parameters.json carry the URDF arm's offsets."""
    robot, model, _ = planar
    problem = tmp_path / "arm.toml"
    problem.write_text(
        Path(robot.urdf.parent / "arm.toml").read_text().replace('urdf = "arm.urdf"', f'urdf = "{robot.urdf}"')
    )
    out = tmp_path / "cg"
    args = ["codegen", "--problem", str(problem), "--data", str(_trial(model, tmp_path / "t.csv", 5))]
    assert main([*args, "--out", str(out), "--components", "1"]) == 0
    readme = (out / "README.md").read_text()
    assert "## This robot's angles" in readme and robot.statement[1] in readme
    assert json.loads((out / "parameters.json").read_text())["robot"] == list(robot.statement)
