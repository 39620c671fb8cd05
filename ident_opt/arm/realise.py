"""From an identified π to rigid bodies (`ident_opt.arm.bodies.RobotDescription`), what `ident-opt export` writes.

**n-joint chain** (`chain_bodies`): π holds each moving link's standard parameters (m, h = m c, Ī about the link
frame's origin), realised one to one: c = h/m and the inertia about c, Ī − m (|c|² 1 − c cᵀ) (parallel axes).
The kinematic chain is emitted fresh from Pinocchio's model of it (`ChainArm._model`): the URDF's joint names,
origins and axes (so q means the same), each link's frame its joint's frame; the links Pinocchio merged into a
moving link (fixed children) are massless frames, their inertials already in that link's, so nothing counts
twice. Joint terms: fv → damping, fc → friction, ia → armature, off → offset; a coupled drive (a row of
`ChainArm.drive_matrix` other than the joint's own) becomes a `Drive`.

**Planar two-link arm** (`planar_bodies`): the grouped π (a1 a2 a3 b1 b2 …) is realised exactly by one set of
standard parameters. The arm moves in the base's x–z plane with gravity (0, 0, −g); both joint axes are
(0, −1, 0) (× the joint's sign), so that counter-clockwise seen from −y (x right, z up) is positive; link 1 runs
along its frame's x axis to joint 2 at x = L, link 2's centre of mass lies on its frame's x axis. The data fix

    h2 = m2 lc2 = b2/g,   L = g a2/b2   (a rigid arm has L = l1; a fit need not: joint 2 is put where it says),
    a3 = I2 + m2 lc2²,    J1 = I1 + m1 lc1² = a1 − a3 − m2 L²,    h1 = m1 lc1 = b1/g − m2 L,

and nothing else: m1 and m2 are free within I2 = a3 − h2²/m2 > 0 and I1 = J1 − h1²/m1 > 0, i.e. m2 ∈ (h2²/a3, (a1 −
a3)/L²), nonempty exactly when a3 (a1 − a3) > a2² (the planar consistency condition), and m1 > h1²/J1. Each is the
datasheet's (`PlanarRobot.nominal_masses`) when it lies 1 % of its interval's width inside both ends (1 % above the
lower end when there is no upper one), else the nearest such mass: every link keeps a positive moment of inertia,
which MuJoCo needs. Also not determined, and said so: the moments about axes other than the joint axis (set equal to
it) and the centres of mass along the axis (0). With the joint_offset extension, b1s (× sin q1) is link 1's centre
of mass off its line; Coulomb levels per direction are their mean plus a constant offset; a Stribeck term is left
out (each said in the notes). Joint 1's armature cannot be told from link 1's inertia (both only add to M11): it is
in link 1's. A robot read from a URDF (`UrdfPlanarRobot`) is written in that URDF's angles: joint j's origin turns
by θ_j and its axis by s_j, so the file's q_j is the URDF's, q_tool = s_j q_j + θ_j and τ_file = s_j τ_tool.

**Bad input.** A π of the wrong length or with a value that is not a finite number, a link of mass 0, and what
no robot description can say exactly (b2 = 0 with a2 ≠ 0; joint_offset's b2s ≠ 0, an offset of link 2's centre
of mass off its line that the grouped model gives no inertial terms for) are `InputError`s. A realisation that
is not physically possible (`RobotDescription.violations`; for the planar arm also a3 (a1 − a3) ≤ a2²), which an
OLS fit can be, is an `InputError` naming the link and the value with `strict` (the default); with
`strict=False` it is returned exact, the violations as notes headed "NOT PHYSICALLY POSSIBLE" (a URDF can say
it; MuJoCo refuses such a body). The chain's consistent fit (every pseudo-inertia ⪰ a margin) always is
possible, and so is the planar rigid model's (M(q) ≻ 0 for all q is exactly a3 > 0, a3 (a1 − a3) > a2²); with a
joint-2 armature, M22 = a3 + ia2 and M(q) ≻ 0 no longer implies a3 (a1 − a3) > a2², so such a fit can be refused.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from ident_opt.arm.bodies import Body, Drive, Frame, Joint, Origin, RobotDescription, matrix3, vector3
from ident_opt.arm.rnea import N_LINK
from ident_opt.arm.urdf import UrdfJoint
from ident_opt.errors import InputError

if TYPE_CHECKING:  # the arm descriptions call these functions (`Robot.bodies`): named for the type checker only
    from ident_opt.arm.chain import ChainArm
    from ident_opt.arm.chain_robot import ChainRobot

#: Share of a free mass's interval kept off each end (module doc): a link at an end has a zero moment of inertia.
MASS_MARGIN = 0.01
#: Relative difference of L = g a2/b2 from the robot's l1 beyond which the file says joint 2 moved.
LENGTH_TOLERANCE = 1e-9
#: Heading of the notes that list what no physical body has (strict=False).
IMPOSSIBLE = "NOT PHYSICALLY POSSIBLE"


# ---------------------------------------------------------------------------------------------- shared
def _checked(pi: np.ndarray, names: Sequence[str], what: str) -> np.ndarray:
    """π as floats (P,), or an InputError naming what is wrong: its length, a value that is not a number."""
    values = np.asarray(pi, dtype=float)
    if values.shape != (len(names),):
        raise InputError(f"{what}: π has {values.size} values, its model has {len(names)} ({', '.join(names[:4])}, …)")
    for n, v in zip(names, values):
        if not math.isfinite(v):
            raise InputError(f"{what}: parameter {n} = {v} is not a finite number")
    return values


def _root_link(joints: dict[str, UrdfJoint], link: str) -> str:
    """The URDF tree's root above `link` (Pinocchio's universe: the frame gravity and the first origin refer to)."""
    by_child = {j.child: j.parent for j in joints.values()}
    while link in by_child:
        link = by_child[link]
    return link


def _undetermined_note(names: Sequence[str]) -> list[str]:
    if not names:
        return []
    return [
        f"not determined by the data (the fit chose them, e.g. from its prior; the sidecar gives no standard error): "
        f"{', '.join(names)}"
    ]


def _finish(
    description: RobotDescription,
    problems: Sequence[str] = (),
    *,
    name: str | None = None,
    undetermined: Sequence[str] = (),
    strict: bool = True,
) -> RobotDescription:
    """What both realisations end with: the description under `name` (default: its own), the parameters the data
    did not determine (`undetermined`, names) said in its notes; then the description, or (`strict`) an InputError
    listing why no physical robot has it (`problems` and its `violations`); not strict: those reasons as notes
    (module doc)."""
    description = replace(
        description, name=name or description.name, notes=(*description.notes, *_undetermined_note(undetermined))
    )
    reasons = [*problems, *description.violations()]
    if not reasons:
        return description
    if strict:
        raise InputError(
            f"{description.name}: the parameters are not those of any physical robot ({'; '.join(reasons)}); export "
            "a physically consistent fit (the default), or allow an impossible one explicitly"
        )
    return replace(description, notes=(*description.notes, *(f"{IMPOSSIBLE}: {r}" for r in reasons)))


# ---------------------------------------------------------------------------------------------- n-joint chain
def chain_bodies(robot: ChainRobot, pi: np.ndarray, **options) -> RobotDescription:
    """The n-joint arm `robot` with the standard parameters and joint terms π (`robot.arm.names`) as rigid bodies
    (module doc). `options` (`_finish`): `name` (default: the URDF's); `undetermined`, parameter names the data did
    not determine, said in the notes; `strict`, refuse a π no physical robot has (module doc)."""
    arm = robot.arm
    pi = _checked(pi, arm.names, str(robot.urdf))
    model, n = arm._model, arm.n_joints
    links = [link_body(link, pi[N_LINK * i : N_LINK * (i + 1)], str(robot.urdf)) for i, link in enumerate(arm.links)]
    terms = {t: pi[arm.n_link_params + k * n : arm.n_link_params + (k + 1) * n] for k, t in enumerate(arm.joint_terms)}
    zero = np.zeros(n)
    fv, fc, ia, off = (terms.get(t, zero) for t in ("fv", "fc", "ia", "off"))
    C = arm.drive_matrix
    own = [bool(np.array_equal(C[j], np.eye(n)[j])) for j in range(n)]  # the drive turns its own joint only
    base = _root_link(arm.urdf_joints, arm.urdf_joints[arm.joints[0]].parent)
    joints = [
        _chain_joint(arm, i, base, (fv[i], fc[i], ia[i]) if own[i] else (0.0, 0.0, 0.0), off[i]) for i in range(n)
    ]
    drives = tuple(
        Drive(
            f"{arm.joints[m]}_drive",
            tuple(arm.joints[k] for k in np.flatnonzero(C[m])),
            tuple(float(C[m, k]) for k in np.flatnonzero(C[m])),
            float(fv[m]),
            float(fc[m]),
            float(ia[m]),
        )
        for m in range(n)
        if not own[m]
    )
    notes = [
        robot.angle_convention,
        "the links' frames are the URDF joints' frames (Pinocchio's model of the chain); links the chain merged into "
        "a moving link (fixed children) are massless frames here, their inertials counted once, in that link's",
        "joint torques determine only combinations of the standard parameters (the base parameters): these link "
        "values are one set with the fit's combinations, and the fit's own choice (e.g. its prior's) where the data "
        "are silent",
    ]
    description = RobotDescription(
        ET.parse(arm.urdf).getroot().get("name") or "robot",
        base,
        tuple(links),
        tuple(joints),
        vector3(robot.gravity),
        _fixed_frames(model),
        drives,
        tuple(notes),
    )
    return _finish(description, **options)


def _chain_joint(arm: ChainArm, i: int, base: str, drive: tuple[float, float, float], offset: float) -> Joint:
    """Joint i of the chain: its links, origin and axis (Pinocchio's model of the URDF), its URDF <limit>, the
    (damping, friction, armature) of its own drive and its constant offset [N m]."""
    joint, model = arm.joints[i], arm._model
    limit = arm.urdf_joints[joint].limit
    return Joint(
        joint,
        base if i == 0 else arm.links[model.parents[i + 1] - 1],
        arm.links[i],
        Origin.of(model.jointPlacements[i + 1]),
        vector3(arm.chain[i].axis),
        lower=limit.get("lower"),
        upper=limit.get("upper"),
        velocity=limit.get("velocity"),
        effort=limit.get("effort"),
        damping=float(drive[0]),
        friction=float(drive[1]),
        armature=float(drive[2]),
        offset=float(offset),
    )


def link_body(name: str, p: np.ndarray, where: str = "") -> Body:
    """One link from its 10 standard parameters [m, mx, my, mz, ixx, ixy, iyy, ixz, iyz, izz] (Pinocchio's
    `Inertia.toDynamicParameters` order; inertia about the link frame's origin): mass [kg], centre of mass [m]
    and inertia about it [kg m²]. InputError for a mass of 0, which has no centre of mass."""
    m, h = float(p[0]), np.asarray(p[1:4], dtype=float)
    if m == 0:
        raise InputError(
            f"{where}: link {name!r}: mass 0 kg with first moment m c = {h.tolist()} kg m: a link without mass has no "
            "centre of mass, which no robot description can say"
        )
    inertia = np.array([[p[4], p[5], p[7]], [p[5], p[6], p[8]], [p[7], p[8], p[9]]], dtype=float)
    c = h / m
    about_com = inertia - m * ((c @ c) * np.eye(3) - np.outer(c, c))  # parallel-axis theorem, back to c
    return Body(name, m, vector3(c), matrix3(about_com))


def _fixed_frames(model: pin.Model) -> tuple[Frame, ...]:
    """The massless frames of Pinocchio's model: each fixed joint's child link, placed in its parent link."""
    frames = model.frames
    out = []
    for index, joint in enumerate(frames):
        if index == 0 or joint.type != pin.FrameType.FIXED_JOINT:  # 0 is Pinocchio's "universe"
            continue
        child = next((f for f in frames if f.type == pin.FrameType.BODY and f.parentFrame == index), None)
        if child is None:
            continue
        parent = frames[joint.parentFrame]
        out.append(Frame(child.name, joint.name, parent.name, Origin.of(parent.placement.inverse() * child.placement)))
    return tuple(out)
