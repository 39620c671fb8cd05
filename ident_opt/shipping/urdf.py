"""A `RobotDescription` as a URDF, with a JSON sidecar `FILE.json` (`write_urdf`).

The URDF is a fresh kinematic tree: the base link, per joint a <joint> (origin, axis, <limit> where known,
<dynamics damping="viscous" friction="Coulomb"/>) and its child <link> with the <inertial> (mass, centre of mass,
inertia about it in the link's axes), per massless frame a fixed joint and an empty link; no meshes. What a URDF
cannot say stands in a comment block at the top: gravity, armature, constant offsets, coupled drives and the
description's notes (what the data did not determine, the angle convention, what was left out). The sidecar is
strict JSON (no NaN or Infinity): the caller's identified values (`identified`: each with its standard error,
null where the data did not determine it, and the estimator), the exported description and the notes.

Numbers are written with Python's shortest round-trip repr, so a reader gets the very floats that were realised.
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from ident_opt.arm.bodies import Body, Joint, Origin, RobotDescription
from ident_opt.outputs import write_text

#: What a <limit> gets for an unknown effort [N m] or velocity [rad/s]: the URDF format needs both, and the
#: tool's own reading of a continuous joint (`ident_opt.arm.urdf`) uses the same stand-in.
UNKNOWN_LIMIT = 1e6


def number(value: float) -> str:
    """A float as the shortest text that reads back as the same float."""
    return repr(float(value))


def numbers(values: Iterable[float]) -> str:
    """Floats separated by spaces, each as `number`."""
    return " ".join(number(v) for v in values)


def comment(lines: Sequence[str]) -> ET.Element:
    """An XML comment of `lines` (one per line); "--", which XML comments may not hold, is spaced apart until none
    is left (a name holding "--->" cannot close the comment)."""

    def spaced(text: str) -> str:
        while "--" in text:
            text = text.replace("--", "- -")
        return text

    body = "\n".join(spaced(f"  {line}") for line in lines)
    return ET.Comment(f"\n{spaced(body)}\n")


def xml_text(root: ET.Element, header: ET.Element) -> str:
    """An XML document: the declaration, the `header` comment and the indented `root`."""
    ET.indent(root)
    return (
        '<?xml version="1.0" encoding="utf-8"?>\n'
        + ET.tostring(header, encoding="unicode")
        + "\n"
        + ET.tostring(root, encoding="unicode")
        + "\n"
    )


def jsonable(value: object) -> object:
    """`value` as strict-JSON-ready data: mappings, sequences and arrays as dicts and lists, numbers as Python
    numbers, a number that is not finite (NaN, ±inf: nothing determined) as None, paths as text."""
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [jsonable(v) for v in value]
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if value is None or isinstance(value, str):
        return value
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON data: {type(value).__name__}")


def identified(
    names: Sequence[str],
    values: np.ndarray,
    standard_errors: np.ndarray | None = None,
    estimator: str | None = None,
) -> dict:
    """The sidecar's record of a fit: the estimator and, per parameter name (in the model's unit), its value and
    standard error; a standard error that is absent or not finite (the data did not determine it) is None."""
    errors = [None] * len(names) if standard_errors is None else list(standard_errors)
    if not len(names) == len(values) == len(errors):
        raise ValueError(f"{len(names)} names, {len(values)} values and {len(errors)} standard errors")
    return {
        "estimator": estimator,
        "parameters": {
            n: {"value": v, "standard_error": None if e is None or not math.isfinite(e) else float(e)}
            for n, v, e in zip(names, np.asarray(values, dtype=float), errors)
        },
    }


def _origin(parent: ET.Element, origin: Origin) -> None:
    ET.SubElement(parent, "origin", xyz=numbers(origin.xyz), rpy=numbers(origin.rpy))


def _joint(robot: ET.Element, joint: Joint) -> list[str]:
    """One revolute joint (continuous without a range); returns notes on the <limit> values it had to make up."""
    element = ET.SubElement(robot, "joint", name=joint.name, type="revolute" if joint.limited else "continuous")
    _origin(element, joint.origin)
    ET.SubElement(element, "parent", link=joint.parent)
    ET.SubElement(element, "child", link=joint.child)
    ET.SubElement(element, "axis", xyz=numbers(joint.axis))
    notes = []
    if joint.limited or joint.effort is not None or joint.velocity is not None:
        limit = {"lower": joint.lower, "upper": joint.upper} if joint.limited else {}
        for key in ("effort", "velocity"):
            value = getattr(joint, key)
            if value is None:
                notes.append(f"joint {joint.name}: <limit {key}> not known: written as {UNKNOWN_LIMIT:g}")
            limit[key] = UNKNOWN_LIMIT if value is None else value
        ET.SubElement(element, "limit", {k: number(v) for k, v in limit.items()})
    ET.SubElement(element, "dynamics", damping=number(joint.damping), friction=number(joint.friction))
    return notes


def _link(robot: ET.Element, body: Body) -> None:
    inertial = ET.SubElement(ET.SubElement(robot, "link", name=body.name), "inertial")
    ET.SubElement(inertial, "origin", xyz=numbers(body.com), rpy="0 0 0")
    ET.SubElement(inertial, "mass", value=number(body.mass))
    (xx, xy, xz), (_, yy, yz), (_, _, zz) = body.inertia
    ET.SubElement(
        inertial,
        "inertia",
        ixx=number(xx),
        ixy=number(xy),
        ixz=number(xz),
        iyy=number(yy),
        iyz=number(yz),
        izz=number(zz),
    )


def _header(description: RobotDescription, sidecar: str, notes: list[str]) -> list[str]:
    gravity = ", ".join(number(g) for g in description.gravity)
    return [
        f"ident-opt export: {description.name}, the identified arm as a URDF; every identified value with its standard "
        f"error, and these notes: {sidecar}",
        f"joint torque = inverse dynamics of this file under gravity ({gravity}) m/s² in the base frame + damping dq + "
        "friction sign(dq) (<dynamics>) + the terms below",
        "a URDF cannot state gravity: load the model with the gravity above",
        *(f"a URDF cannot say: {line}" for line in description.joint_lines(armature=True)),
        *description.notes,
        *notes,
    ]


def urdf_text(description: RobotDescription, sidecar: str = "") -> tuple[str, list[str]]:
    """(the URDF of `description`, the notes its writing added); `sidecar` names the sidecar in the comment."""
    robot = ET.Element("robot", name=description.name)
    ET.SubElement(robot, "link", name=description.base)
    bodies = {b.name: b for b in description.bodies}
    notes = []
    for joint in description.joints:
        notes += _joint(robot, joint)
        _link(robot, bodies[joint.child])
    for frame in description.frames:
        element = ET.SubElement(robot, "joint", name=frame.joint, type="fixed")
        _origin(element, frame.origin)
        ET.SubElement(element, "parent", link=frame.parent)
        ET.SubElement(element, "child", link=frame.name)
        ET.SubElement(robot, "link", name=frame.name)
    return xml_text(robot, comment(_header(description, sidecar, notes))), notes


def write_urdf(
    description: RobotDescription, path: str | Path, sidecar: Mapping[str, object] | None = None
) -> tuple[Path, Path]:
    """Write `description` as a URDF to `path` and its sidecar to `path` + ".json" (module doc), atomically through
    `ident_opt.outputs`; `sidecar`: the caller's record of the fit (`identified`, and anything JSON-ready).
    Returns (the URDF's path, the sidecar's)."""
    path = Path(path)
    side = Path(f"{path}.json")
    text, notes = urdf_text(description, side.name)
    robot = description.as_dict()
    payload = {
        "format": "ident-opt export sidecar",
        "urdf": path.name,
        **(sidecar or {}),
        "joint_torque": (
            "inverse dynamics of the URDF under `robot.gravity` + per joint damping dq + friction sign(dq) + armature "
            "ddq + offset + each coupled drive's terms on its velocity (robot.drives)"
        ),
        "robot": robot,
        "notes": [*robot.pop("notes"), *notes],
    }
    data = json.dumps(jsonable(payload), indent=1, ensure_ascii=False, allow_nan=False)
    write_text(path, text)
    write_text(side, data + "\n")
    return path, side
