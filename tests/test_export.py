"""`ident-opt export`'s layer below the command: π realised as rigid bodies (`ident_opt.arm.realise`) and written as a
URDF with its JSON sidecar and as a MuJoCo MJCF (`ident_opt.shipping`). Pinocchio loads the URDF and MuJoCo the
MJCF, and their inverse dynamics reproduce the model's predicted torques `arm.predict(π, q, dq, ddq)` to 1e-9
relative, at random states with |dq| away from 0 (Coulomb friction's sign is the model's there), for the three
shipped n-joint arms and the planar two-link arms."""

from __future__ import annotations

import functools
import json
import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from ident_opt.arm.bodies import RobotDescription
from ident_opt.arm.chain_robot import ChainRobot
from ident_opt.arm.datasheet import datasheet_pi
from ident_opt.arm.planar import PAPER, RIGID, PlanarArm
from ident_opt.arm.realise import IMPOSSIBLE, chain_bodies
from ident_opt.arm.realise_planar import planar_bodies
from ident_opt.arm.rnea import N_LINK
from ident_opt.errors import InputError
from ident_opt.problem import load_problem
from ident_opt.shipping import identified, write_mjcf, write_urdf
from tests.conftest import PROBLEMS

#: Worst per-sample error allowed, relative to the sample's largest |τ|.
TOLERANCE = 1e-9
#: States per round trip, and the smallest |dq| [rad/s] they have (Coulomb friction is sign(dq) only away from 0).
N_STATES, MIN_SPEED = 50, 0.3
CHAINS = ("kuka_lwr4", "franka_panda", "staubli_tx40")


@functools.cache
def _robot(name: str):
    return load_problem(PROBLEMS / f"{name}.toml").robot


def _strict_json(text: str) -> dict:
    """The sidecar read as strict JSON: NaN or Infinity in it fails the test."""

    def refuse(constant: str):
        raise AssertionError(f"the sidecar holds {constant}, which strict JSON has not")

    return json.loads(text, parse_constant=refuse)


# ------------------------------------------------------------------------------------------------ parameters
def _point_mass(mass: float, r: np.ndarray) -> np.ndarray:
    """The 10 standard parameters of a point mass [kg] at r (3,) [m]: adding them to a link keeps it physical."""
    x, y, z = r
    return mass * np.array([1, x, y, z, y * y + z * z, -x * y, x * x + z * z, -x * z, -y * z, x * x + y * y])


def _chain_pi(robot: ChainRobot, perturbed: bool, seed: int = 0) -> np.ndarray:
    """A consistent π: the URDF's inertials (perturbed: each link made denser or lighter by a factor and given an
    extra point mass, still a body), positive friction and armature, offsets of either sign."""
    arm, rng = robot.arm, np.random.default_rng(seed)
    pi = arm.cad_parameters()
    if perturbed:
        for i in range(arm.n_joints):
            link = slice(N_LINK * i, N_LINK * (i + 1))
            pi[link] = rng.uniform(0.8, 1.3) * pi[link] + _point_mass(rng.uniform(0.1, 0.5), rng.uniform(-0.1, 0.1, 3))
    n, start = arm.n_joints, arm.n_link_params
    ranges = {"fv": (0.1, 2.0), "fc": (0.1, 2.0), "ia": (0.01, 0.5), "off": (-1.0, 1.0)}
    for k, term in enumerate(arm.joint_terms):
        pi[start + k * n : start + (k + 1) * n] = rng.uniform(*ranges[term], n)
    return pi


def _planar_pi(name: str, convention: str | None = None) -> tuple[PlanarArm, np.ndarray]:
    """The datasheet's π and its model: with the armature ia2 when the datasheet has one, the paper's gravity
    vector under its convention."""
    values = datasheet_pi(_robot(name), convention)
    if convention == "paper":
        return PAPER, PAPER.vector(values)
    arm = PlanarArm(("armature",)) if "ia2" in values else RIGID
    return arm, arm.vector(values)


def _planar_fit(name: str) -> tuple[PlanarArm, np.ndarray]:
    """A consistent fit that is not the datasheet's: a2 5 % off (joint 2 moves away from l1), direction-dependent
    Coulomb friction, a Stribeck term and link 1's centre of mass off its line (joint_offset's b1s)."""
    arm = PlanarArm(("armature", "asymmetric_coulomb", "stribeck", "joint_offset"))
    values = dict(zip(arm.names, arm.vector(datasheet_pi(_robot(name)))))
    values.update(a2=1.05 * values["a2"], fc1p=1.3 * values["fc1p"], fc2n=0.6 * values["fc2n"], fs1=0.2, b1s=0.05)
    return arm, arm.vector(values)


# ------------------------------------------------------------------------------------------------ the round trip
def _states(description: RobotDescription, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """N_STATES states (q within the joints' ranges, else (−π, π); MIN_SPEED ≤ |dq| ≤ 2 rad/s; |ddq| ≤ 3 rad/s²)."""
    rng = np.random.default_rng(seed)
    low = np.array([j.lower if j.limited else -np.pi for j in description.joints])
    high = np.array([j.upper if j.limited else np.pi for j in description.joints])
    shape = (N_STATES, len(description.joints))
    q = rng.uniform(low, high, shape)
    dq = rng.uniform(MIN_SPEED, 2.0, shape) * rng.choice([-1.0, 1.0], shape)
    return q, dq, rng.uniform(-3.0, 3.0, shape)


def _drive_torques(drives: list[dict], joints: list[str], dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """The coupled drives' torques (N, n) from the sidecar: damping v + friction sign v + armature dv/dt along
    v = c · dq, reaching the joints as c."""
    out = np.zeros_like(dq)
    for drive in drives:
        c = np.array([dict(zip(drive["joints"], drive["coefficients"])).get(j, 0.0) for j in joints])
        v, a = dq @ c, ddq @ c
        out += np.outer(drive["damping"] * v + drive["friction"] * np.sign(v) + drive["armature"] * a, c)
    return out


def _pinocchio_torques(urdf: str, sidecar: dict, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """τ (N, n) of the URDF as Pinocchio reads it: RNEA under the sidecar's gravity (a URDF cannot say it), plus
    <dynamics> damping dq and friction sign(dq) as Pinocchio parsed them, plus what only the sidecar holds:
    armature ddq, offsets, coupled drives."""
    model = pin.buildModelFromUrdf(urdf)
    data = model.createData()
    robot = sidecar["robot"]
    model.gravity = pin.Motion(np.array(robot["gravity"]), np.zeros(3))
    names = [j["name"] for j in robot["joints"]]
    assert list(model.names[1:]) == names
    armature = np.array([j["armature"] for j in robot["joints"]])
    offset = np.array([j["offset"] for j in robot["joints"]])
    out = np.empty_like(q)
    for k in range(len(q)):
        config = []  # a continuous joint (no range) is a unit circle in Pinocchio: (cos q, sin q)
        for joint, angle in zip(model.joints[1:], q[k]):
            config += [np.cos(angle), np.sin(angle)] if joint.nq == 2 else [angle]
        out[k] = pin.rnea(model, data, np.array(config), dq[k], ddq[k])
    out += model.damping * dq + model.friction * np.sign(dq) + armature * ddq + offset
    return out + _drive_torques(robot["drives"], names, dq, ddq)


def _mujoco_torques(xml: str, sidecar: dict, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """τ (N, n) of the MJCF as MuJoCo reads it, plus the offsets only the sidecar holds.

    MuJoCo's frictionloss is a soft constraint: `mj_inverse` computes its force from the acceleration residual
    J qacc − aref (aref = −b J qvel, b ≈ 100/s under the default solref), clamped to ±frictionloss. Its sign is
    sign(dq) only while |J qacc| < b |J qvel| (at 30 times these accelerations it flips on every arm), and where
    friction constraints share a dof (the TX40's wrist tendon over joints 5 and 6) it need not reach the clamp: a
    sample of the perturbed TX40 is 21 % off. So `mj_inverse` runs with friction loss disabled, which is exact for
    the rigid bodies, damping and armature (joints' and tendons'), and the friction loss is added by the exact
    route: the compiled model's dof_frictionloss × sign(dq) and each fixed tendon's frictionloss × sign(v) along
    its coefficients (read from the compiled wraps). That the soft constraint's force stays within those
    bounds is checked too."""
    model = mujoco.MjModel.from_xml_path(xml)
    data = mujoco.MjData(model)
    names = [j["name"] for j in sidecar["robot"]["joints"]]
    dofs = [model.jnt_dofadr[model.joint(n).id] for n in names]
    positions = [model.jnt_qposadr[model.joint(n).id] for n in names]
    tendons = np.zeros((model.ntendon, model.nv))  # each fixed tendon's coefficients, per dof
    for t in range(model.ntendon):
        for w in range(model.tendon_adr[t], model.tendon_adr[t] + model.tendon_num[t]):
            assert model.wrap_type[w] == mujoco.mjtWrap.mjWRAP_JOINT
            tendons[t, model.jnt_dofadr[model.wrap_objid[w]]] = model.wrap_prm[w]
    tendons = tendons[:, dofs]
    bound = model.dof_frictionloss[dofs] + np.abs(tendons).T @ model.tendon_frictionloss
    out, soft = np.empty_like(q), np.empty_like(q)
    without = int(mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS)
    for k in range(len(q)):
        data.qpos[positions], data.qvel[dofs], data.qacc[dofs] = q[k], dq[k], ddq[k]
        inverse = {}
        for flags in (0, without):
            model.opt.disableflags = flags
            mujoco.mj_inverse(model, data)
            inverse[flags] = data.qfrc_inverse[dofs].copy()
        out[k], soft[k] = inverse[without], inverse[0] - inverse[without]
    assert np.all(np.abs(soft) <= bound * (1 + 1e-12) + 1e-12), "MuJoCo's friction loss exceeds frictionloss"
    out += model.dof_frictionloss[dofs] * np.sign(dq)
    out += (model.tendon_frictionloss * np.sign(dq @ tendons.T)) @ tendons
    return out + np.array([j["offset"] for j in sidecar["robot"]["joints"]])


def _worst(tau: np.ndarray, expected: np.ndarray) -> float:
    """The worst per-sample error relative to the sample's largest |τ|."""
    return float((np.abs(tau - expected).max(axis=1) / np.abs(expected).max(axis=1)).max())


def _round_trip(description: RobotDescription, sidecar: dict, tmp_path, expected) -> tuple[float, float]:
    """Write both files, check they are valid XML and strict JSON, load them in Pinocchio and MuJoCo and return
    each one's worst relative error against `expected(q, dq, ddq)` (the model's τ in the file's convention)."""
    urdf, side = write_urdf(description, tmp_path / "arm.urdf", sidecar)
    (xml,) = write_mjcf(description, tmp_path / "arm.xml")
    for path in (urdf, xml):
        ET.parse(path)
    record = _strict_json(side.read_text(encoding="utf-8"))
    assert record["estimator"] == sidecar["estimator"] and record["notes"]
    q, dq, ddq = _states(description, seed=len(description.joints))
    tau = expected(q, dq, ddq)
    return (
        _worst(_pinocchio_torques(str(urdf), record, q, dq, ddq), tau),
        _worst(_mujoco_torques(str(xml), record, q, dq, ddq), tau),
    )


# ------------------------------------------------------------------------------------------------ n-joint chains
@pytest.mark.parametrize("perturbed", [False, True], ids=["urdf", "perturbed"])
@pytest.mark.parametrize("name", CHAINS)
def test_chain_round_trip(name, perturbed, tmp_path):
    robot = _robot(name)
    arm = robot.arm
    pi = _chain_pi(robot, perturbed)
    description = chain_bodies(robot, pi)
    assert description == robot.bodies(arm, pi)
    assert description.violations() == []
    assert [j.name for j in description.joints] == list(arm.joints)
    sidecar = identified(arm.names, pi, np.full(len(pi), 0.01), "test")
    errors = _round_trip(description, sidecar, tmp_path, lambda q, dq, ddq: arm.predict(pi, q, dq, ddq))
    assert max(errors) < TOLERANCE, f"Pinocchio, MuJoCo: {errors}"


def test_chain_frames_and_coupled_drive():
    """The Panda's flange stays as a massless frame; the TX40's coupled wrist drive is a drive, not joint 6's."""
    panda = chain_bodies(_robot("franka_panda"), _chain_pi(_robot("franka_panda"), False))
    assert [(f.name, f.parent) for f in panda.frames] == [("panda_link8", "panda_link7")]
    tx40 = chain_bodies(_robot("staubli_tx40"), _chain_pi(_robot("staubli_tx40"), False))
    (drive,) = tx40.drives
    assert drive.joints == ("joint_5", "joint_6") and drive.coefficients == (1.0, 1.0)
    assert tx40.joints[-1].damping == tx40.joints[-1].friction == tx40.joints[-1].armature == 0.0


# ------------------------------------------------------------------------------------------------ planar arms
PLANAR_CASES = {
    "tudor_2dof": lambda: _planar_pi("tudor_2dof"),
    "tudor_2dof-paper": lambda: _planar_pi("tudor_2dof", "paper"),
    "dfki_c0": lambda: _planar_pi("dfki_c0"),
    "dfki_c0_urdf": lambda: _planar_pi("dfki_c0_urdf"),
    "tudor_2dof-fit": lambda: _planar_fit("tudor_2dof"),
    "dfki_c0_urdf-fit": lambda: _planar_fit("dfki_c0_urdf"),
}


@pytest.mark.parametrize("case", PLANAR_CASES)
def test_planar_round_trip(case, tmp_path):
    robot = _robot(case.split("-")[0])
    arm, pi = PLANAR_CASES[case]()
    description = planar_bodies(robot, arm, pi)
    assert description == robot.bodies(arm, pi)
    assert description.violations() == []
    # A URDF robot's file keeps that URDF's angles: q_tool = s q + θ, τ_file = s τ_tool.
    s = np.array(getattr(robot, "angle_signs", (1.0, 1.0)))
    theta = np.array(getattr(robot, "angle_offsets", (0.0, 0.0)))

    def expected(q, dq, ddq):
        return s * arm.predict(pi, s * q + theta, s * dq, s * ddq)

    errors = _round_trip(description, identified(arm.names, pi, None, "datasheet"), tmp_path, expected)
    assert max(errors) < TOLERANCE, f"Pinocchio, MuJoCo: {errors}"


def test_planar_notes_name_what_the_data_did_not_determine():
    arm, pi = _planar_fit("tudor_2dof")
    notes = "\n".join(planar_bodies(_robot("tudor_2dof"), arm, pi).notes)
    assert "not determined by the data: the masses m1 and m2" in notes
    assert "joint 1's armature" in notes and "joint 2 sits L = g a2/b2" in notes
    assert "direction-dependent Coulomb friction" in notes and "Stribeck term fs1" in notes
    datasheet = "\n".join(planar_bodies(_robot("tudor_2dof"), *_planar_pi("tudor_2dof")).notes)
    assert "joint 2 sits" not in datasheet  # the datasheet is a rigid arm: joint 2 at l1


def test_planar_mass_inside_its_interval():
    """DFKI's datasheet link 2 has no inertia about its centre of mass (m2 at the interval's end): the realisation
    takes a mass inside, so MuJoCo gets a positive moment, and says so."""
    description = planar_bodies(_robot("dfki_c0"), *_planar_pi("dfki_c0"))
    assert description.bodies[1].principal_moments[0] > 0
    assert "the nearest mass 1% inside" in "\n".join(description.notes)


# ------------------------------------------------------------------------------------------------ bad input
def test_impossible_chain_is_refused_or_flagged(tmp_path):
    robot = _robot("franka_panda")
    pi = _chain_pi(robot, False)
    pi[2 * N_LINK] = -1.0  # panda_link3's mass
    with pytest.raises(InputError, match=r"link 'panda_link3': mass -1 kg ≤ 0"):
        chain_bodies(robot, pi)
    flagged = chain_bodies(robot, pi, strict=False)
    assert f"{IMPOSSIBLE}: link 'panda_link3': mass -1 kg ≤ 0" in flagged.notes
    urdf, _ = write_urdf(flagged, tmp_path / "ols.urdf", identified(robot.arm.names, pi, None, "ols"))
    assert IMPOSSIBLE in urdf.read_text(encoding="utf-8")
    with pytest.raises(InputError, match="MuJoCo has no body"):
        write_mjcf(flagged, tmp_path / "ols.xml")
    assert not (tmp_path / "ols.xml").exists()


def test_impossible_planar_is_refused_or_flagged():
    robot = _robot("tudor_2dof")
    arm, pi = _planar_pi("tudor_2dof")
    values = arm.as_dict(pi)
    values["a3"] = 0.9999 * values["a1"]  # a3 (a1 − a3) < a2²: no two bodies have these
    with pytest.raises(InputError, match=r"a3 \(a1 − a3\)"):
        planar_bodies(robot, arm, arm.vector(values))
    flagged = planar_bodies(robot, arm, arm.vector(values), strict=False)
    assert any(note.startswith(IMPOSSIBLE) for note in flagged.notes) and flagged.violations()
    # With a joint-2 armature, M(q) ≻ 0 for every q (the planar fits' consistency) does not make two rigid bodies.
    armature = PlanarArm(("armature",))
    pi = armature.vector({**values, "a1": 1.0, "a2": 0.35, "a3": 0.1, "ia2": 1.0})
    assert armature.min_mass_eigenvalue(pi) > 0
    with pytest.raises(InputError, match=r"a3 \(a1 − a3\) = 0.09 > a2² = 0.1225"):
        planar_bodies(robot, armature, pi)


def test_unsayable_input_is_an_input_error():
    robot, (arm, pi) = _robot("tudor_2dof"), _planar_pi("tudor_2dof")
    values = arm.as_dict(pi)
    with pytest.raises(InputError, match="b2 = 0 N m"):
        planar_bodies(robot, arm, arm.vector({**values, "b2": 0.0}))
    offset = PlanarArm(("joint_offset",))
    with pytest.raises(InputError, match="b2s"):
        planar_bodies(robot, offset, offset.vector({**values, "b2s": 0.1}))
    with pytest.raises(InputError, match=f"π has {len(pi) - 1} values"):
        planar_bodies(robot, arm, pi[:-1])
    chain = _robot("kuka_lwr4")
    with pytest.raises(InputError, match="not a finite number"):
        chain_bodies(chain, np.full(chain.arm.n_params, np.nan))


def test_sidecar_is_strict_json_with_standard_errors(tmp_path):
    robot = _robot("kuka_lwr4")
    pi = _chain_pi(robot, False)
    errors = np.full(len(pi), 0.02)
    errors[:3] = (np.nan, np.inf, -np.inf)  # not determined by the data
    _, side = write_urdf(
        chain_bodies(robot, pi), tmp_path / "kuka.urdf", identified(robot.arm.names, pi, errors, "ols")
    )
    record = _strict_json(side.read_text(encoding="utf-8"))
    parameters = record["parameters"]
    assert [parameters[n]["standard_error"] for n in robot.arm.names[:4]] == [None, None, None, 0.02]
    assert parameters["m_lwr_1_link"]["value"] == pi[0] and record["estimator"] == "ols"
