"""Reading a URDF: its joints, links and inertials, checked, and Pinocchio's model of a chain of its joints.

Every fault is an `InputError` naming the file and the element: a path that is not a regular file (a named pipe
would block the read, /dev/zero would fill the memory) or is larger than `MAX_URDF_BYTES`, a file that does not
parse, a joint that is not in it or not revolute, joints that are not one serial chain from the base, and
(`chain_model`) anything Pinocchio cannot read. Both arm implementations read URDFs through this module: the
n-joint chain (`ident_opt.arm.chain`) and the planar two-link arm (`ident_opt.arm.planar_urdf`).
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from ident_opt import outputs
from ident_opt.errors import InputError

#: Revolute joint types of the URDF format.
REVOLUTE = ("revolute", "continuous")
#: Every joint type of the URDF format; those that need a <limit effort velocity> (lower and upper too).
JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")
LIMITED = ("revolute", "prismatic")


#: Largest URDF the tool reads [bytes], 64 MiB: it is read whole into memory and parsed; real arms' URDFs are a few
#: kB to a few MB (meshes are separate files), so a larger one is a mistake (a log, a mesh, /dev/zero through a
#: link), refused before it is read.
MAX_URDF_BYTES = 64 * 2**20

#: Largest magnitude of a URDF number the tool accepts, per kind: a mass [kg], a length [m], an inertia [kg m²],
#: a friction [N m s/rad or N m]; beyond, the value is a unit mistake or a typo and overflows the arithmetic.
SANE = {"mass": 1e4, "length": 100.0, "inertia": 1e3, "friction": 1e4}


@dataclass(frozen=True)
class UrdfJoint:
    """One URDF <joint>: type, parent and child link, origin (xyz [m], rpy [rad]) and axis; its <dynamics>
    damping [N m s/rad] and friction [N m] (0 where absent); its <limit> lower, upper [rad], velocity [rad/s]
    and effort [N m] (None where absent)."""

    name: str
    type: str
    parent: str
    child: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    axis: tuple[float, float, float]
    damping: float = 0.0
    friction: float = 0.0
    limit: dict[str, float] = field(default_factory=dict)


def _number(element: ET.Element, key: str, where: str, low: float, high: float) -> float | None:
    """Attribute `key` of `element` as a finite number in [low, high] (None when absent); InputError naming it."""
    text = element.get(key)
    if text is None:
        return None
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and low <= value <= high):
        raise InputError(f"{where} <{element.tag} {key}={text!r}>: must be a finite number in [{low:g}, {high:g}]")
    return value


def _floats(
    element: ET.Element | None, key: str, default: str, where: str, bound: float = 1e6
) -> tuple[float, float, float]:
    """Three floats from attribute `key` of `element` (default when absent), each of magnitude at most `bound`
    (an origin's xyz: `SANE["length"]` m); InputError naming `where`."""
    text = default if element is None else element.get(key, default)
    try:
        values = tuple(float(v) for v in text.split())
    except ValueError:
        values = ()
    if len(values) != 3 or not all(np.isfinite(values)):
        raise InputError(f"{where}: {key}={text!r} must be three finite numbers")
    if max(map(abs, values)) > bound:
        raise InputError(f"{where}: {key}={text!r} must be three numbers of magnitude at most {bound:g}")
    return values  # type: ignore[return-value]


def _check_inertial(path: Path, link: ET.Element) -> None:
    """A link's <inertial>, when it has one: a mass that is a number in [0, 10⁴] kg, a finite origin, and an
    inertia (about the centre of mass) that is finite and positive semi-definite; InputError naming the link."""
    inertial = link.find("inertial")
    if inertial is None:
        return
    where = f"{path}: <link name={link.get('name')!r}>"
    mass = inertial.find("mass")
    if mass is None or mass.get("value") is None:
        raise InputError(f"{where} <inertial> has no <mass value=…>")
    _number(mass, "value", where, 0.0, SANE["mass"])
    _floats(inertial.find("origin"), "xyz", "0 0 0", f"{where} <inertial><origin>", SANE["length"])
    _floats(inertial.find("origin"), "rpy", "0 0 0", f"{where} <inertial><origin>")
    element = inertial.find("inertia")
    if element is None:
        raise InputError(f"{where} <inertial> has no <inertia ixx=… iyy=… izz=…/>")
    keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    v = {k: _number(element, k, where, -SANE["inertia"], SANE["inertia"]) or 0.0 for k in keys}
    inertia = np.array([[v["ixx"], v["ixy"], v["ixz"]], [v["ixy"], v["iyy"], v["iyz"]], [v["ixz"], v["iyz"], v["izz"]]])
    moments = np.linalg.eigvalsh(inertia)  # principal moments, ascending
    tolerance = 1e-9 * max(1.0, float(np.abs(inertia).max()))
    if moments[0] < -tolerance:
        raise InputError(
            f"{where} <inertia>: not physically possible (its smallest principal moment is "
            f"{float(moments[0]):.3g} kg m², below 0)"
        )
    if moments[2] > moments[0] + moments[1] + tolerance:  # a rigid body's moments obey the triangle inequality
        raise InputError(
            f"{where} <inertia>: not physically possible: its largest principal moment ({float(moments[2]):.3g} "
            f"kg m²) exceeds the sum of the other two ({float(moments[0]):.3g} + {float(moments[1]):.3g}); no "
            "distribution of mass has it (the triangle inequality of principal moments)"
        )


def _joint(path: Path, j: ET.Element, links: dict[str, ET.Element]) -> UrdfJoint:
    """One <joint> element, checked (module doc)."""
    name = j.get("name")
    where = f"{path}: <joint name={name!r}>"
    parent, child = j.find("parent"), j.find("child")
    if not name or parent is None or child is None or j.get("type") is None:
        raise InputError(f"{where}: needs a name, a type, <parent link=…> and <child link=…>")
    for end in (parent.get("link"), child.get("link")):
        if end not in links:
            raise InputError(f"{where}: refers to link {end!r}, which the file does not define")
    if j.get("type") not in JOINT_TYPES:
        raise InputError(f"{where}: type={j.get('type')!r} is not a URDF joint type ({', '.join(JOINT_TYPES)})")
    if j.get("type") in LIMITED and (
        j.find("limit") is None or None in (j.find("limit").get(k) for k in ("effort", "velocity"))
    ):
        raise InputError(f"{where}: a {j.get('type')} joint needs <limit effort=… velocity=…> (the URDF format's rule)")
    axis = _floats(j.find("axis"), "xyz", "1 0 0", where)
    if j.get("type") in REVOLUTE and not np.linalg.norm(axis) > 0:
        raise InputError(f"{where} <axis xyz={j.find('axis').get('xyz')!r}>: a revolute joint needs a non-zero axis")
    dynamics = j.find("dynamics")
    damping = friction = 0.0
    if dynamics is not None:
        damping = _number(dynamics, "damping", where, 0.0, SANE["friction"]) or 0.0
        friction = _number(dynamics, "friction", where, 0.0, SANE["friction"]) or 0.0
    limit = {}
    element = j.find("limit")
    if element is not None:
        for key in ("lower", "upper", "velocity", "effort"):  # velocity and effort are magnitudes
            value = _number(element, key, where, -1e6 if key in ("lower", "upper") else 0.0, 1e6)
            if value is not None:
                limit[key] = value
        if limit.get("lower", -math.inf) > limit.get("upper", math.inf):
            raise InputError(f"{where} <limit>: lower {limit['lower']:g} is above upper {limit['upper']:g}")
    origin = j.find("origin")
    return UrdfJoint(
        name,
        j.get("type"),
        parent.get("link"),
        child.get("link"),
        _floats(origin, "xyz", "0 0 0", f"{where} <origin>", SANE["length"]),
        _floats(origin, "rpy", "0 0 0", f"{where} <origin>"),
        axis,
        damping,
        friction,
        limit,
    )


def parse_urdf(path: Path) -> tuple[str, dict[str, UrdfJoint], dict[str, ET.Element]]:
    """(the file's text, joints by name, links by name) of a URDF, every <joint> and <inertial> checked;
    InputError naming the file and the element on any fault (module doc)."""
    text = read_urdf_text(path)
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise InputError(f"{path}: not a valid URDF (XML error: {exc})") from None
    if root.tag != "robot":
        raise InputError(f"{path}: not a URDF: the root element is <{root.tag}>, not <robot>")
    outputs.declare_inputs([path, *meshes(path, root)])
    links = {}
    for link in root.findall("link"):
        if not link.get("name"):
            raise InputError(f"{path}: a <link> without a name")
        links[link.get("name")] = link
        _check_inertial(path, link)
    joints = {}
    for element in root.findall("joint"):
        joint = _joint(path, element, links)
        if joint.name in links and joint.type != "fixed":  # Pinocchio finds a moving joint's frame by its name
            raise InputError(
                f"{path}: <joint name={joint.name!r}> has the name of a <link>; a moving joint and a link need "
                "distinct names (Pinocchio and most URDF tools find frames by name)"
            )
        if joint.name in joints:
            raise InputError(f"{path}: two <joint> elements are named {joint.name!r}")
        joints[joint.name] = joint
    _check_tree(path, joints)
    return text, joints, links


def read_urdf_text(path: Path) -> str:
    """The text of the URDF at `path` (UTF-8, newlines as `Path.read_text` gives them): a regular file of at most
    `MAX_URDF_BYTES`, checked by `os.stat` before it is opened and again on the open file; InputError naming the
    file otherwise (not found, a named pipe, a device, a socket, a folder, too large, unreadable, not UTF-8)."""
    path = Path(path)
    try:
        _regular_urdf(path, os.stat(path))
        # O_NONBLOCK: should a pipe replace the file after the check, the open returns instead of waiting for a
        # writer, and the check of the open file refuses it. It changes nothing for a regular file.
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
        with os.fdopen(fd, "rb") as file:
            _regular_urdf(path, os.fstat(file.fileno()))
            data = file.read(MAX_URDF_BYTES + 1)
    except FileNotFoundError:
        raise InputError(f"{path}: URDF file not found") from None
    except (OSError, ValueError) as exc:  # ValueError: a NUL byte in the name
        raise InputError(f"{path}: cannot read the URDF ({getattr(exc, 'strerror', None) or exc})") from None
    if len(data) > MAX_URDF_BYTES:  # it grew after the check
        _regular_urdf(path, None, len(data))
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a valid URDF (not UTF-8 text: {exc})") from None
    return text.replace("\r\n", "\n").replace("\r", "\n")  # universal newlines, as `Path.read_text` reads


def _regular_urdf(path: Path, status: os.stat_result | None, size: int | None = None) -> None:
    """InputError naming the URDF `path` when `status` is not a regular file's, or its size (or `size`) is above
    `MAX_URDF_BYTES`."""
    kind = outputs.mode_kind(status.st_mode) if status is not None else None
    if kind is not None:
        raise InputError(
            f"{path}: the URDF is {kind}, not a regular file; give the path of the .urdf file itself (a named pipe "
            "or a device is never read)"
        )
    size = status.st_size if size is None else size
    if size > MAX_URDF_BYTES:
        raise InputError(
            f"{path}: the URDF is {size / 2**20:.1f} MiB, larger than the {MAX_URDF_BYTES // 2**20} MiB ident-opt "
            "reads (real URDFs are a few MB at most; meshes are separate files)"
        )


def _check_tree(path: Path, joints: dict[str, UrdfJoint]) -> None:
    """The joints make a tree of links (what urdfdom and Pinocchio assume: on a loop they recurse without end):
    no joint from a link to itself, no link the child of two joints, no cycle; InputError naming the culprit."""
    parent_of: dict[str, UrdfJoint] = {}
    for joint in joints.values():
        if joint.parent == joint.child:
            raise InputError(
                f"{path}: <joint name={joint.name!r}>: its parent and child are the same link {joint.child!r}"
            )
        if joint.child in parent_of:
            raise InputError(
                f"{path}: link {joint.child!r} is the child of two joints ({parent_of[joint.child].name!r} and "
                f"{joint.name!r}); a URDF is a tree: each link has one parent"
            )
        parent_of[joint.child] = joint
    done: set[str] = set()  # links known to reach a root
    for start in parent_of:
        seen, link = [], start
        while link in parent_of and link not in done:
            if link in seen:
                raise InputError(
                    f"{path}: the joints above link {link!r} form a cycle ({' -> '.join(seen[seen.index(link) :])} -> "
                    f"{link}); a URDF is a tree"
                )
            seen.append(link)
            link = parent_of[link].parent
        done.update(seen)


def meshes(path: Path, root: ET.Element) -> list[Path]:
    """The mesh files the URDF at `path` references that exist here (relative or file:// names; a package://
    name needs ROS to resolve and is left out): inputs of the run, like the URDF itself."""
    found = []
    for mesh in root.iter("mesh"):
        name = mesh.get("filename") or ""
        name = name.removeprefix("file://")
        if name and "://" not in name:
            candidate = path.parent / name
            if candidate.is_file():
                found.append(candidate)
    return found


def check_chain(path: Path, joints: dict[str, UrdfJoint], names: tuple[str, ...], base: str | None) -> str:
    """Check that `names` are revolute joints of the file forming one serial chain from `base` (default: the
    root link) through fixed joints only; return the base link. InputError naming the element otherwise."""
    if not names:
        raise InputError(f"{path}: [robot] joints must name at least one joint")
    for name in names:
        if name not in joints:
            close = ", ".join(sorted(joints)) or "none"
            raise InputError(f"{path}: joint {name!r} is not in the URDF (its joints: {close})")
        if joints[name].type not in REVOLUTE:
            raise InputError(
                f"{path}: <joint name={name!r}> is of type {joints[name].type!r}; only revolute joints are supported"
            )
    by_child = {j.child: j for j in joints.values()}
    children = set(by_child)
    roots = sorted({j.parent for j in joints.values()} - children)
    if base is None:
        if len(roots) != 1:
            raise InputError(f"{path}: the URDF has {len(roots)} root links ({', '.join(roots)}), not one")
        base = roots[0]

    def ancestor_through_fixed(link: str) -> str:
        """Walk up from `link` through fixed joints; the first link reached by a non-fixed joint's child."""
        seen = {link}
        while link in by_child and by_child[link].type == "fixed" and link != base:
            link = by_child[link].parent
            if link in seen:
                raise InputError(f"{path}: the fixed joints above link {link!r} form a cycle; a URDF is a tree")
            seen.add(link)
        return link

    expected = base
    for name in names:
        parent = ancestor_through_fixed(joints[name].parent)
        if parent != expected:
            what = f"the base link {base!r}" if expected == base else f"the child of the previous joint ({expected!r})"
            raise InputError(
                f"{path}: <joint name={name!r}>: not a serial chain: its parent link {joints[name].parent!r} is not "
                f"{what} or attached to it by fixed joints"
            )
        expected = joints[name].child
    return base


def _as_revolute(text: str) -> str:
    """The URDF with every continuous joint made revolute with wide limits: Pinocchio would read a continuous
    joint as a unit-circle joint (two configuration entries for one velocity); the dynamics are the same."""
    root = ET.fromstring(text)
    for joint in root.findall("joint"):
        if joint.get("type") == "continuous":
            joint.set("type", "revolute")
            if joint.find("limit") is None:
                ET.SubElement(joint, "limit", effort="1e6", lower="-1e6", upper="1e6", velocity="1e6")
    return ET.tostring(root, encoding="unicode")


def chain_model(path: str | Path, text: str, joints: tuple[str, ...]) -> pin.Model:
    """Pinocchio's model of the URDF `text` (read from `path`) reduced to `joints`, base to tip: every other
    movable joint of the file locked at 0; InputError naming the file when Pinocchio cannot read it or the
    joints are not its chain in this order."""
    try:
        full = pin.buildModelFromXML(_as_revolute(text))
    except (RuntimeError, ValueError) as exc:
        raise InputError(f"{path}: Pinocchio cannot read this URDF ({exc})") from None
    lock = [full.getJointId(n) for n in full.names[1:] if n not in joints]
    model = pin.buildReducedModel(full, lock, pin.neutral(full)) if lock else full
    if tuple(model.names[1:]) != tuple(joints) or model.nv != len(joints):
        raise InputError(
            f"{path}: the joints {list(joints)} are not the file's chain in this order "
            f"(Pinocchio reads {list(model.names[1:])})"
        )
    return model
