"""A two-link planar arm from a URDF: two revolute joints with parallel axes, as the measured-inertials robot.

    [robot]
    urdf = "arm.urdf"                 # relative to the problem file
    joints = ["shoulder", "elbow"]    # two revolute joints of a serial chain, base to tip
    gravity = 9.81                    # m/s² along −z of the URDF's base, or [gx, gy, gz]
    form = "planar"                   # optional: "auto" (default), "planar" (refuse if not) or "n-joint"
    [robot.joint2]                    # optional, what a URDF cannot say (joint side, as the inertials form)
    rotor_inertia = 0.0036            # kg m², reflected: N² J
    gear_ratio = 6.0
    torque_constant = 0.091           # N m/A, motor side

The geometry, read with Pinocchio at the URDF's zero (q_urdf = 0), every other movable joint of the file
locked at 0 and fixed children merged into their parent (as Pinocchio does):

- n = joint 1's axis in the base frame (unit). The plane of motion is perpendicular to n; "up" is
  ŷ = −g⊥/|g⊥| with g⊥ = g − (g·n) n, the horizontal x̂ = ŷ × n, so (x̂, ŷ, n) is right-handed and
  counter-clockwise in the plane is positive about n. The tool's gravity is |g⊥| [m/s²]; g·n only loads the
  bearings.
- Joint 2's axis a2 must be ±n (within `PARALLEL_TOLERANCE` rad): s2 = sign(a2·n), s1 = +1.
- p1, p2 are points on the two axes (the joint frames' origins), d⊥ the in-plane part of p2 − p1:
  link 1's length l1 = |d⊥| [m], its direction u = d⊥/l1, v = n × u.
- Each joint's body is everything it carries up to the next named joint (joint 2: everything after it),
  lumped by Pinocchio into one rigid body: mass m [kg], centre of mass c (base frame), inertia I_c about c
  (3×3, base axes). In the plane: link 1's com = (c1 − p1)·u [m] (its part along v must be 0 within
  `COM_TOLERANCE` m: the two-link model's gravity has no sin q1 term), link 2's lc2 = |(c2 − p2)⊥| [m]
  at the angle φ2 = atan2((c2 − p2)·v, (c2 − p2)·u) from link 1's direction; each inertia about the axis
  through its centre of mass is nᵀ I_c n [kg m²]. Link 2's length is the in-plane distance of its farthest
  link frame from axis 2 (the tip; lc2 when all its frames sit on the axis).

Angles and torques: the tool's q1 is link 1's direction from the horizontal, q2 the direction of link 2's
centre of mass relative to link 1 (`ident_opt.arm.planar`), so

    q1 = q1_urdf + θ1,   θ1 = atan2(d⊥·ŷ, d⊥·x̂)
    q2 = s2 q2_urdf + φ2

and dq, ddq, τ (and currents) of joint j are multiplied by s_j. The data are read in the URDF's convention
and mapped by the tool (`column_map`, applied by `ident_opt.data.loader.load_dataset`); `statement` says which
offsets and signs it applied. Joint friction comes from <dynamics damping=".." friction=".."/> (joint side,
N m s/rad and N m), unless [robot.jointN] gives it.

With these, M(q), the gravity torque and τ = M ddq + C dq + G + F of the two-link closed form equal
Pinocchio's RNEA on the URDF (`tests/test_urdf_planar.py`). A URDF that is not such an arm raises
`NotPlanar` (the n-joint path `ident_opt.arm.chain.ChainRobot` is then taken, unless form = "planar").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from ident_opt.arm.datasheet import InertialLink, PlanarRobot
from ident_opt.arm.joints import JointSide
from ident_opt.arm.urdf import chain_model, check_chain, parse_urdf
from ident_opt.errors import InputError
from ident_opt.outputs import shown

if TYPE_CHECKING:  # only a type here: pandas is a heavy import that loading a problem does not need
    pass

#: Largest angle between the two joint axes [rad] still read as parallel (a URDF's rounded rpy, e.g.
#: 1.5708 for π/2, is off by 4e-6 rad).
PARALLEL_TOLERANCE = 1e-5
#: Largest distance of link 1's centre of mass from the line between the axes [m] (and smallest l1).
COM_TOLERANCE = 1e-6
#: The signals of a data file that turn with each joint's sign (torque from currents included).
_SIGNED = ("dq", "ddq", "tau", "i")


class NotPlanar(InputError):
    """The URDF's two joints are not a planar two-link arm (the message says why)."""


@dataclass(frozen=True)
class Lumped:
    """One joint's body in the plane of motion: mass [kg], centre of mass [m] along link 1's line from its own
    axis (link 1) or its distance from axis 2 (link 2), inertia about the axis through it [kg m²]."""

    mass: float
    com: float
    inertia: float
    links: tuple[str, ...]  # the URDF links it lumps


@dataclass(frozen=True)
class PlanarGeometry:
    """What the URDF says about the planar arm (module doc): gravity |g⊥| [m/s²], l1 and link 2's reach [m],
    the two bodies, the signs s and offsets θ [rad] with q_tool = s q_urdf + θ, the joints' <dynamics>."""

    gravity: float
    gravity_along_axis: float
    l1: float
    reach2: float
    bodies: tuple[Lumped, Lumped]
    signs: tuple[float, float]
    offsets: tuple[float, float]
    dynamics: tuple[tuple[float, float], tuple[float, float]]  # (damping, friction) per joint


@dataclass(frozen=True)
class UrdfPlanarRobot(PlanarRobot):
    """The measured-inertials robot (`description` "inertials") built from a URDF, with the map from the URDF's
    angles to the tool's: q_tool = sign · q_urdf + offset [rad] per joint (module doc)."""

    urdf: Path = Path()
    joint_names: tuple[str, ...] = ()
    angle_signs: tuple[float, ...] = (1.0, 1.0)
    angle_offsets: tuple[float, ...] = (0.0, 0.0)
    notes: tuple[str, ...] = field(default=(), compare=False)

    @property
    def column_map(self) -> dict[str, tuple[float, float]]:
        """Data column → (scale, offset) taking the URDF's convention to the tool's: q_j ↦ s_j q_j + θ_j,
        dq_j, ddq_j, tau_j, i_j ↦ s_j × value."""
        out = {}
        for j, (s, off) in enumerate(zip(self.angle_signs, self.angle_offsets)):
            out[f"q{j + 1}"] = (s, off)
            out.update({f"{kind}{j + 1}": (s, 0.0) for kind in _SIGNED})
        return out

    def summary(self) -> dict:
        """The JSON-able description `ident-opt check --json` gives (key "robot"): the URDF, its joints, the
        signs and offsets [rad] applied to its data, and the statement's lines."""
        return {
            "form": "planar two-link from a URDF",
            "urdf": str(self.urdf),
            "joints": list(self.joint_names),
            "angle_signs": list(self.angle_signs),
            "angle_offsets_rad": list(self.angle_offsets),
            "statement": list(self.statement),
        }

    @property
    def statement(self) -> tuple[str, ...]:
        """The lines the tool prints about this robot: the angle offsets and signs it applied, and why."""
        joints = ", ".join(self.joint_names)
        lines = [f"robot from the URDF {shown(self.urdf)} as a planar two-link arm (joints {joints})"]
        for j, (name, s, off) in enumerate(zip(self.joint_names, self.angle_signs, self.angle_offsets)):
            sign = "" if s > 0 else "−"
            flip = "" if s > 0 else f" (the URDF's axis of {name!r} points against joint 1's: angle and torque flipped)"
            lines.append(
                f"  q{j + 1} = {sign}q_urdf({name}) {'+' if off >= 0 else '−'} {abs(off):.6f} rad "
                f"({math.degrees(off):+.2f}°){flip}"
            )
        return (*lines, *(f"  {note}" for note in self.notes))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _wrap(angle: float) -> float:
    """An angle in (−π, π] [rad]."""
    return float(math.pi - (math.pi - angle) % (2 * math.pi))


def _carried(model: pin.Model, joint: int) -> list[pin.Frame]:
    """The body frames (URDF links) a (reduced) model's joint carries."""
    return [f for f in model.frames if f.type == pin.FrameType.BODY and f.parentJoint == joint]


def _plane(axis: np.ndarray, gravity: np.ndarray, path: Path) -> tuple[np.ndarray, np.ndarray, float]:
    """(x̂, ŷ, |g⊥|): the horizontal and the up of the plane perpendicular to `axis` (module doc)."""
    g_perp = gravity - (gravity @ axis) * axis
    if np.linalg.norm(g_perp) <= 1e-9 * max(np.linalg.norm(gravity), 1.0):
        raise NotPlanar(f"{path}: gravity is along the joint axes, so no joint angle is measured from it")
    up = -_unit(g_perp)
    return np.cross(up, axis), up, float(np.linalg.norm(g_perp))


def _axes(model: pin.Model, data: pin.Data, path: Path, names: tuple[str, ...]) -> tuple[np.ndarray, float]:
    """(n, s2): joint 1's axis in the base frame and the sign of joint 2's along it; NotPlanar if not parallel."""
    pin.computeJointJacobians(model, data, pin.neutral(model))
    axes = [
        _unit(pin.getJointJacobian(model, data, j, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[3:, j - 1]) for j in (1, 2)
    ]
    angle = math.asin(min(1.0, float(np.linalg.norm(np.cross(*axes)))))
    if angle > PARALLEL_TOLERANCE:
        raise NotPlanar(
            f"{path}: the axes of <joint name={names[0]!r}> and <joint name={names[1]!r}> are "
            f"{math.degrees(angle):.4g}° apart, not parallel: not a planar two-link arm"
        )
    return axes[0], 1.0 if axes[0] @ axes[1] > 0 else -1.0


def _body(path: Path, model: pin.Model, data: pin.Data, j: int, child: str, links: dict, name: str, uv: tuple) -> tuple:
    """(inertia in base axes about the centre of mass, its centre of mass along u and v from the joint's axis [m],
    the body frames it lumps) of joint j's body; InputError when its own link has no <inertial> or it has no mass."""
    if links[child].find("inertial") is None:
        raise InputError(
            f"{path}: <link name={child!r}> (moved by {name!r}) has no <inertial>; a planar arm needs its mass"
        )
    carried = _carried(model, j)
    inertia = data.oMi[j].act(model.inertias[j])  # base axes, about the centre of mass
    if inertia.mass <= 0:
        raise InputError(f"{path}: the links {[f.name for f in carried]} moved by {name!r} have no mass")
    r = inertia.lever - data.oMi[j].translation
    return inertia, float(r @ uv[0]), float(r @ uv[1]), carried


def planar_geometry(
    path: Path, names: tuple[str, ...], gravity: tuple[float, float, float], base: str | None = None
) -> PlanarGeometry:
    """The planar two-link arm a URDF describes (module doc); `NotPlanar` naming the reason when it is not one,
    `InputError` naming the element for a bad URDF (a joint it lacks, not revolute, not a serial chain, a
    carried link without <inertial>)."""
    text, joints, links = parse_urdf(path)
    check_chain(path, joints, names, base)
    model = chain_model(path, text, names)
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    n, s2 = _axes(model, data, path, names)
    x_hat, y_hat, g_plane = _plane(n, np.asarray(gravity, dtype=float), path)
    p1, p2 = data.oMi[1].translation, data.oMi[2].translation
    d = (p2 - p1) - ((p2 - p1) @ n) * n
    l1 = float(np.linalg.norm(d))
    if l1 <= COM_TOLERANCE:
        raise NotPlanar(f"{path}: the axes of {names[0]!r} and {names[1]!r} coincide: link 1 has no length")
    u = d / l1
    v = np.cross(n, u)  # (u, v, n) right-handed: v is "to the left" of link 1's line, in the plane
    (in1, x1, y1, carried1), (in2, x2, y2, carried2) = (
        _body(path, model, data, j, joints[name].child, links, name, (u, v))
        for j, name in ((1, names[0]), (2, names[1]))
    )
    if abs(y1) > COM_TOLERANCE:
        raise NotPlanar(
            f"{path}: the centre of mass of {[f.name for f in carried1]} lies {y1:.3g} m off the line between the "
            f"axes of {names[0]!r} and {names[1]!r}; the two-link model needs it on that line (no sin q1 gravity term)"
        )
    lc2 = math.hypot(x2, y2)
    # Link 2's length is "axis to the tip": its farthest link frame (the centre of mass may lie beyond it, as
    # in the makers' DFKI model); a URDF whose link-2 frames all sit on the axis gives lc2 instead.
    reach = max(_reach(data, f, n, p2) for f in carried2)
    return PlanarGeometry(
        gravity=g_plane,
        gravity_along_axis=float(np.asarray(gravity) @ n),
        l1=l1,
        reach2=reach if reach > COM_TOLERANCE else (lc2 if lc2 > COM_TOLERANCE else l1),
        bodies=(
            Lumped(in1.mass, x1, float(n @ in1.inertia @ n), tuple(f.name for f in carried1)),
            Lumped(in2.mass, lc2, float(n @ in2.inertia @ n), tuple(f.name for f in carried2)),
        ),
        signs=(1.0, s2),
        offsets=(_wrap(math.atan2(d @ y_hat, d @ x_hat)), _wrap(math.atan2(y2, x2)) if lc2 > COM_TOLERANCE else 0.0),
        dynamics=tuple((joints[name].damping, joints[name].friction) for name in names),
    )


def _reach(data: pin.Data, frame: pin.Frame, n: np.ndarray, axis_point: np.ndarray) -> float:
    """In-plane distance [m] of a link frame's origin from axis 2."""
    offset = data.oMi[frame.parentJoint].act(frame.placement).translation - axis_point
    return float(np.linalg.norm(offset - (offset @ n) * n))


def planar_robot(
    urdf: Path, names: tuple[str, ...], geometry: PlanarGeometry, joints: tuple[JointSide, JointSide], notes=()
) -> UrdfPlanarRobot:
    """The measured-inertials robot of a planar URDF (`planar_geometry`) with its joints' joint-side values
    (friction from the URDF's <dynamics> unless the problem overrides it) and the notes the parser made."""
    body1, body2 = geometry.bodies
    g_note = f"gravity {geometry.gravity:.6g} m/s² in the plane of motion"
    if abs(geometry.gravity_along_axis) > 1e-12:
        g_note += f" ({geometry.gravity_along_axis:+.6g} m/s² along the axes loads only the bearings)"
    return UrdfPlanarRobot(
        gravity=geometry.gravity,
        convention="physical",
        link1=InertialLink(geometry.l1, body1.mass, body1.com, body1.inertia),
        link2=InertialLink(geometry.reach2, body2.mass, body2.com, body2.inertia),
        joint1=joints[0],
        joint2=joints[1],
        description="inertials",
        urdf=urdf,
        joint_names=names,
        angle_signs=geometry.signs,
        angle_offsets=geometry.offsets,
        notes=(g_note, *notes),
    )
