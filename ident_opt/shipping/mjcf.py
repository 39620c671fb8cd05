"""A `RobotDescription` as a MuJoCo MJCF (`write_mjcf`): dynamics only, no meshes, no geoms.

Per joint a <body> at the joint's origin (pos, quat w x y z), with its <inertial mass pos fullinertia> (inertia
about the centre of mass, "ixx iyy izz ixy ixz iyz") and a hinge <joint> with axis, range where known, damping
(viscous), frictionloss (Coulomb) and armature; massless frames as <site>s; each coupled drive as a fixed
<tendon> over its joints (coef = the coupling), which carries its damping, frictionloss and armature on the
drive's velocity exactly; <option gravity>; <compiler angle="radian">. Constant offsets, which MuJoCo has no
attribute for, and the description's notes stand in a comment at the top.

MuJoCo's frictionloss is a soft constraint: its force is clamped to ±frictionloss, with the sign of the
constraint's acceleration residual; in inverse dynamics (`mj_inverse`) that is sign(dq) only at accelerations
small next to the velocity (|ddq| ≪ 100/s × |dq| under the default solref), so the tests compare MuJoCo with
friction loss disabled and add frictionloss × sign(dq) read from the compiled model.

MuJoCo needs each body's principal moments of inertia > 0: a physically possible link with a zero one (a point
mass, a thin rod) gets `<compiler boundinertia>` of 1e-15 kg m², and the comment says so. The written text is
compiled by MuJoCo first, so a file MuJoCo cannot load is never written (InputError with MuJoCo's message).
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path

from ident_opt.arm.bodies import ABSOLUTE_TOLERANCE, RELATIVE_TOLERANCE, Body, Origin, RobotDescription
from ident_opt.errors import InputError
from ident_opt.outputs import write_text
from ident_opt.shipping.urdf import comment, jsonable, number, numbers, xml_text

#: The lower bound MuJoCo's compiler puts on principal moments when a link has a zero one [kg m²] (its mjMINVAL).
BOUND_INERTIA = 1e-15


def _pose(origin: Origin) -> dict[str, str]:
    """pos and quat (w x y z) attributes of a placement."""
    return {"pos": numbers(origin.xyz), "quat": numbers(origin.quaternion)}


def _add_children(element: ET.Element, link: str, description: RobotDescription, bodies: dict[str, Body]) -> None:
    """The sites fixed to `link` and the bodies its joints carry (`bodies` by name), recursively."""
    for frame in description.frames:
        body, placement = description.placement_in_body(frame.name)
        if body == link:
            ET.SubElement(element, "site", name=frame.name, **_pose(Origin.of(placement)))
    for joint in description.joints:
        if joint.parent != link:
            continue
        body = bodies[joint.child]
        child = ET.SubElement(element, "body", name=body.name, **_pose(joint.origin))
        (xx, xy, xz), (_, yy, yz), (_, _, zz) = body.inertia
        ET.SubElement(
            child,
            "inertial",
            mass=number(body.mass),
            pos=numbers(body.com),
            fullinertia=numbers((xx, yy, zz, xy, xz, yz)),
        )
        attributes = {
            "name": joint.name,
            "type": "hinge",
            "axis": numbers(joint.axis),
            "damping": number(joint.damping),
            "frictionloss": number(joint.friction),
            "armature": number(joint.armature),
        }
        if joint.limited:
            attributes["range"] = numbers((joint.lower, joint.upper))
        ET.SubElement(child, "joint", attributes)
        _add_children(child, body.name, description, bodies)


def _degenerate(description: RobotDescription) -> list[str]:
    """The links with a principal moment of inertia MuJoCo would refuse (≤ 0 up to rounding)."""
    out = []
    for body in description.bodies:
        low, _, high = body.principal_moments
        if low <= RELATIVE_TOLERANCE * abs(high) + ABSOLUTE_TOLERANCE:
            out.append(body.name)
    return out


def mjcf_text(description: RobotDescription) -> str:
    """The MJCF of `description` (module doc)."""
    root = ET.Element("mujoco", model=description.name)
    compiler = ET.SubElement(root, "compiler", angle="radian", autolimits="true")
    degenerate = _degenerate(description)
    if degenerate:
        compiler.set("boundinertia", number(BOUND_INERTIA))
    ET.SubElement(root, "option", gravity=numbers(description.gravity))
    bodies = {b.name: b for b in description.bodies}
    _add_children(ET.SubElement(root, "worldbody"), description.base, description, bodies)
    if description.drives:
        tendons = ET.SubElement(root, "tendon")
        for drive in description.drives:
            fixed = ET.SubElement(
                tendons,
                "fixed",
                name=drive.name,
                damping=number(drive.damping),
                frictionloss=number(drive.friction),
                armature=number(drive.armature),
            )
            for joint, coefficient in zip(drive.joints, drive.coefficients):
                ET.SubElement(fixed, "joint", joint=joint, coef=number(coefficient))
    lines = [
        f"ident-opt export: {description.name}, the identified arm as a MuJoCo MJCF (dynamics only: no meshes, "
        "no geoms)",
        "joint torque = MuJoCo's inverse dynamics with damping and armature + frictionloss sign(dq) (a soft constraint "
        "in MuJoCo: ±frictionloss while sliding) + the terms below",
        *(f"MuJoCo has no attribute for: {line}" for line in description.joint_lines(armature=False, drives=False)),
        *(f"coupled drive {d.name}: the fixed tendon {d.name} (v = {d.velocity_text()})" for d in description.drives),
        *(
            f"MuJoCo needs principal moments of inertia > 0: those of {name} below {BOUND_INERTIA:g} kg m² are "
            "raised to it (boundinertia)"
            for name in degenerate
        ),
        *description.notes,
    ]
    return xml_text(root, comment(lines))


def write_mjcf(
    description: RobotDescription, path: str | Path, sidecar: Mapping[str, object] | None = None
) -> list[Path]:
    """Write `description` as a MuJoCo MJCF to `path` and, given the caller's record of the fit (`sidecar`), its
    sidecar to `path` + ".json" (every identified value with its standard error: what `diagnose --nominal` reads
    back), atomically through `ident_opt.outputs` (module doc). InputError when a link is not physically possible or
    MuJoCo cannot compile the model; returns the paths written."""
    path = Path(path)
    violations = description.violations()
    if violations:
        raise InputError(f"{path}: MuJoCo has no body for: {'; '.join(violations)}")
    text = mjcf_text(description)
    import mujoco  # only this writer needs MuJoCo: a URDF export works without it

    try:
        mujoco.MjModel.from_xml_string(text)
    except ValueError as exc:
        raise InputError(f"{path}: MuJoCo cannot load the exported model ({exc})") from None
    written = [path]
    if sidecar is not None:
        robot = description.as_dict()
        payload = {"format": "ident-opt export sidecar", "mjcf": path.name, **sidecar, "robot": robot}
        payload["notes"] = robot.pop("notes")
        data = json.dumps(jsonable(payload), indent=1, ensure_ascii=False, allow_nan=False)
    write_text(path, text)
    if sidecar is not None:
        written.append(Path(f"{path}.json"))
        write_text(written[-1], data + "\n")
    return written
