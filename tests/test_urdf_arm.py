"""The URDF arm: its CasADi RNEA and regressor against Pinocchio's, its pseudo-inertia LMIs, bad URDFs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from ident_opt.arm.chain import ChainArm
from ident_opt.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
KUKA = ROOT / "data" / "kuka_lwr4" / "kuka_lwr4.urdf"
KUKA_JOINTS = tuple(f"lwr_{i}_joint" for i in range(7))

#: A chain with everything the CasADi RNEA must get right: rotated origins, an unaligned axis, a fixed link
#: merged into its parent, gravity off the z axis, products of inertia.
TWISTED = """<?xml version="1.0"?>
<robot name="twisted">
  <link name="world"/>
  <joint name="mount" type="fixed"><origin xyz="0.1 0 0.2" rpy="0.3 0 0"/><parent link="world"/>
    <child link="base"/></joint>
  <link name="base"/>
  <joint name="a" type="revolute"><origin xyz="0 0 0.1"/><axis xyz="0 0 1"/><parent link="base"/>
    <child link="l1"/><limit effort="1" lower="-3" upper="3" velocity="1"/></joint>
  <link name="l1"><inertial><mass value="2.0"/><origin xyz="0.01 -0.05 0.1" rpy="0.2 0.1 0"/>
    <inertia ixx="0.02" ixy="0.001" ixz="-0.002" iyy="0.015" iyz="0.003" izz="0.01"/></inertial></link>
  <joint name="b" type="continuous"><origin xyz="0.05 0.02 0.3" rpy="0.1 -0.4 0.7"/><axis xyz="1 2 -0.5"/>
    <parent link="l1"/><child link="l2"/></joint>
  <link name="l2"><inertial><mass value="1.2"/><origin xyz="0.2 0.01 0"/>
    <inertia ixx="0.004" ixy="0" ixz="0" iyy="0.03" iyz="0" izz="0.03"/></inertial></link>
  <joint name="tool" type="fixed"><origin xyz="0.4 0 0"/><parent link="l2"/><child link="l3"/></joint>
  <link name="l3"><inertial><mass value="0.5"/><origin xyz="0 0 0.02"/>
    <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial></link>
  <joint name="c" type="revolute"><origin xyz="0.4 0 0" rpy="0 1.2 0"/><axis xyz="0 -1 0"/><parent link="l2"/>
    <child link="l4"/><limit effort="1" lower="-3" upper="3" velocity="1"/></joint>
  <link name="l4"><inertial><mass value="0.8"/><origin xyz="0 0.1 0.05"/>
    <inertia ixx="0.002" ixy="0.0001" ixz="0" iyy="0.001" iyz="0" izz="0.002"/></inertial></link>
</robot>
"""


@pytest.fixture(scope="module")
def twisted(tmp_path_factory) -> ChainArm:
    path = tmp_path_factory.mktemp("urdf") / "twisted.urdf"
    path.write_text(TWISTED)
    return ChainArm(str(path), ("a", "b", "c"), gravity=(0.5, -1.0, -9.7), offsets=True)


@pytest.fixture(scope="module")
def kuka() -> ChainArm:
    return ChainArm(str(KUKA), KUKA_JOINTS, offsets=True)


@pytest.fixture(scope="module")
def panda() -> ChainArm:
    path = ROOT / "data" / "franka_panda" / "panda.urdf"
    return ChainArm(str(path), tuple(f"panda_joint{i}" for i in range(1, 8)), offsets=True)


@pytest.fixture(scope="module")
def tx40() -> ChainArm:
    path = ROOT / "data" / "staubli_tx40" / "tx40.urdf"
    joints = tuple(f"joint_{i}" for i in range(1, 7))
    return ChainArm(str(path), joints, offsets=True, couplings=(("joint_6", "joint_5", 1.0),))


def _states(arm: ChainArm, n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    size = (n, arm.n_joints)
    return rng.uniform(-np.pi, np.pi, size), rng.uniform(-2, 2, size), rng.uniform(-5, 5, size)


def _random_pi(arm: ChainArm, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    pi = arm.cad_parameters()
    pi[: arm.n_link_params] *= rng.uniform(0.5, 1.5, arm.n_link_params)
    pi[arm.n_link_params :] = rng.uniform(0.1, 2.0, arm.n_params - arm.n_link_params)
    return pi


@pytest.mark.parametrize("which", ["twisted", "kuka", "panda", "tx40"])
def test_casadi_rnea_matches_pinocchio(which, request):
    arm = request.getfixturevalue(which)
    pi = _random_pi(arm)
    model = arm._pinocchio_with(pi)
    data = model.createData()
    tau = arm.function("tau")
    q, dq, ddq = _states(arm, 50)
    Yj = arm.regressor(q, dq, ddq)[:, :, arm.n_link_params :]
    for k in range(len(q)):
        rigid = pin.rnea(model, data, q[k], dq[k], ddq[k])
        expected = rigid + Yj[k] @ pi[arm.n_link_params :]
        got = np.asarray(tau(q[k], dq[k], ddq[k], pi)).ravel()
        assert np.abs(got - expected).max() <= 1e-10


@pytest.mark.parametrize("which", ["twisted", "kuka"])
def test_regressor_is_pinocchios_plus_joint_columns(which, request):
    arm = request.getfixturevalue(which)
    q, dq, ddq = _states(arm, 20, seed=3)
    Y = arm.regressor(q, dq, ddq)
    model, data = arm._model, arm._model.createData()
    n, L = arm.n_joints, arm.n_link_params
    fY = arm.function("Y")
    for k in range(len(q)):
        ref = pin.computeJointTorqueRegressor(model, data, q[k], dq[k], ddq[k])
        np.testing.assert_allclose(Y[k, :, :L], ref, rtol=0, atol=1e-10)  # the two models round differently
        np.testing.assert_allclose(Y[k], np.asarray(fY(q[k], dq[k], ddq[k], np.zeros(arm.n_params))), atol=1e-10)
        for j in range(n):  # fv, fc, ia, off columns on row j only
            row = Y[k, j, L:].reshape(len(arm.joint_terms), n)
            np.testing.assert_array_equal(row[:, j], [dq[k, j], np.sign(dq[k, j]), ddq[k, j], 1.0])
            assert np.count_nonzero(np.delete(row, j, axis=1)) == 0


def test_parameter_names_and_pinocchio_order(kuka):
    assert kuka.names[:10] == tuple(
        f"{p}_lwr_1_link" for p in ("m", "mx", "my", "mz", "ixx", "ixy", "iyy", "ixz", "iyz", "izz")
    )
    assert kuka.names[-1] == "off_lwr_6_joint" and "fv_lwr_0_joint" in kuka.names
    cad = kuka.as_dict(kuka.cad_parameters())
    # Link 1 of the URDF: 2.7 kg at c = (0, −0.06, 0.13): first moments m c and Ixx about the origin.
    assert cad["m_lwr_1_link"] == pytest.approx(2.7)
    assert cad["my_lwr_1_link"] == pytest.approx(-0.162) and cad["mz_lwr_1_link"] == pytest.approx(0.351)
    assert cad["ixx_lwr_1_link"] == pytest.approx(0.01845 + 2.7 * (0.06**2 + 0.13**2))
    assert cad["iyz_lwr_1_link"] == pytest.approx(2.7 * 0.06 * 0.13)
    assert sum(kuka.link_masses(kuka.cad_parameters()).values()) == pytest.approx(14.4)  # 4 × 2.7 + 1.7 + 1.6 + 0.3


def test_pseudo_inertia_lmis(kuka):
    pi = kuka.cad_parameters()
    lmis = kuka.mass_lmis()
    assert list(lmis) == [f"pseudo_inertia_{link}" for link in kuka.links]
    J = np.tensordot(pi, lmis["pseudo_inertia_lwr_1_link"], 1)
    assert J[3, 3] == pytest.approx(2.7) and J[1, 3] == pytest.approx(-0.162)
    # J's upper block is Σ = ∫ r rᵀ dm: its trace is ½ tr(Ī) (≥ 0 for a real body)
    assert np.trace(J[:3, :3]) == pytest.approx(0.5 * (pi[4] + pi[6] + pi[9]))
    assert kuka.min_mass_eigenvalue(pi) > 0
    bad = pi.copy()
    bad[kuka.names.index("ixx_lwr_3_link")] = 0.5 * bad[kuka.names.index("iyy_lwr_3_link")]  # triangle inequality
    assert kuka.min_mass_eigenvalue(bad) < 0
    M = kuka.mass_matrices(pi, np.zeros((1, 7)))[0]
    assert np.all(np.linalg.eigvalsh(M) > 0)


def _write(tmp_path: Path, text: str) -> str:
    path = tmp_path / "bad.urdf"
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize(
    ("text", "joints", "names"),
    [
        ("<robot><link name='a'></robot>", ("a",), ["bad.urdf", "XML"]),
        ("<robots/>", ("a",), ["bad.urdf", "<robots>"]),
        (TWISTED, ("a", "nope"), ["bad.urdf", "'nope'"]),
        (TWISTED.replace('name="b" type="continuous"', 'name="b" type="prismatic"'), ("a", "b"), ["'b'", "prismatic"]),
        (TWISTED, ("a", "c"), ["bad.urdf", "<joint name='c'>", "serial chain"]),
        (TWISTED, ("b", "c"), ["<joint name='b'>", "serial chain"]),
    ],
)
def test_bad_urdf_names_file_and_element(tmp_path, text, joints, names):
    with pytest.raises(InputError) as info:
        ChainArm(_write(tmp_path, text), joints)
    for name in names:
        assert name in str(info.value)


def test_missing_inertial_is_named_when_a_prior_is_needed(tmp_path):
    text = TWISTED.replace(
        '<link name="l4"><inertial><mass value="0.8"/><origin xyz="0 0.1 0.05"/>\n'
        '    <inertia ixx="0.002" ixy="0.0001" ixz="0" iyy="0.001" iyz="0" izz="0.002"/></inertial></link>',
        '<link name="l4"/>',
    )
    arm = ChainArm(_write(tmp_path, text), ("a", "b", "c"))
    with pytest.raises(InputError, match="l4"):
        arm.cad_parameters()


def test_coupled_drive_terms(tmp_path):
    """A coupled wrist: drive c also turns with joint b (ratio 0.7), so its friction and armature act on
    both joints' rows, in the NumPy regressor, the CasADi model and M(q) alike."""
    path = tmp_path / "twisted.urdf"
    path.write_text(TWISTED)
    arm = ChainArm(str(path), ("a", "b", "c"), offsets=True, couplings=(("c", "b", 0.7),))
    pi = _random_pi(arm)
    q, dq, ddq = _states(arm, 10, seed=5)
    Y = arm.regressor(q, dq, ddq)
    fY, fM = arm.function("Y"), arm.function("M")
    col = arm.names.index("fv_c")
    np.testing.assert_allclose(Y[:, 1, col], 0.7 * (dq[:, 2] + 0.7 * dq[:, 1]))
    np.testing.assert_allclose(Y[:, 2, col], dq[:, 2] + 0.7 * dq[:, 1])
    M = arm.mass_matrices(pi, q)
    for k in range(len(q)):
        np.testing.assert_allclose(Y[k], np.asarray(fY(q[k], dq[k], ddq[k], pi)), atol=1e-10)
        np.testing.assert_allclose(M[k], np.asarray(fM(q[k], dq[k], ddq[k], pi)), atol=1e-10)
    with pytest.raises(InputError, match="'z'"):
        ChainArm(str(path), ("a", "b", "c"), couplings=(("c", "z", 1.0),))
