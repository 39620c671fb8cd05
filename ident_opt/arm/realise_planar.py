"""A planar two-link arm's grouped π realised as rigid bodies (`planar_bodies`): one physically consistent set of link
masses, centres of mass and inertias, chosen next to the datasheet's where the grouped parameters leave them free, with
what the data did not determine named."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ident_opt.arm.bodies import Body, Joint, Origin, RobotDescription, matrix3, vector3
from ident_opt.arm.planar import PlanarArm
from ident_opt.arm.realise import LENGTH_TOLERANCE, MASS_MARGIN, _checked, _finish, _root_link
from ident_opt.arm.urdf import SANE, parse_urdf
from ident_opt.errors import InputError

#: The planar export's joint axis (before each joint's sign): counter-clockwise in the x–z plane, seen from −y.
PLANAR_AXIS = (0.0, -1.0, 0.0)

if TYPE_CHECKING:  # the robot imports this module: a type, not a dependency
    from ident_opt.arm.datasheet import PlanarRobot


# ---------------------------------------------------------------------------------------------- planar arm
@dataclass(frozen=True)
class _PlanarShape:
    """The planar arm's realised rigid part: joint 2 at L [m]; masses m [kg], centres of mass (x, z) [m] in the
    link frames, moments about the axis through them I [kg m²], per link; the free masses' intervals [kg]."""

    L: float
    masses: tuple[float, float]
    coms: tuple[tuple[float, float], tuple[float, float]]
    moments: tuple[float, float]
    intervals: tuple[tuple[float, float], tuple[float, float]]
    feasible: bool
    nominal: tuple[float, float]


def _inside(preferred: float, low: float, high: float) -> float:
    """`preferred` when in the inner part of (low, high) (`MASS_MARGIN` off each end; high may be inf), else the
    nearest end of that part."""
    if math.isinf(high):
        return max(preferred, low * (1 + MASS_MARGIN))
    pad = MASS_MARGIN * (high - low)
    return min(max(preferred, low + pad), high - pad)


def _joint2_distance(a2: float, b2: float, g: float, l1: float) -> float:
    """L = g a2/b2 [m] (module doc); l1 when a2 = b2 = 0; InputError when no finite distance says a2 and b2."""
    if b2 == 0 and a2 == 0:
        return l1
    L = g * a2 / b2 if b2 != 0 else math.inf
    if not abs(L) <= SANE["length"]:
        raise InputError(
            f"planar arm: a2 = {a2:.6g} kg m² and b2 = {b2:.6g} N m put joint 2 at g a2/b2 = {L:.6g} m from joint 1: "
            f"no robot description says them (a rigid arm has a2 g = l1 b2, with l1 = {l1:.6g} m)"
        )
    return L


def _planar_shape(robot: PlanarRobot, p: dict[str, float], b1: float) -> _PlanarShape:
    """The rigid part of the planar realisation (module doc) from the grouped parameters `p`; `b1` is the physical
    g (m1 lc1 + m2 l1) [N m] (the paper's gravity vector has another)."""
    g, a1, a2, a3, b2 = robot.gravity, p["a1"], p["a2"], p["a3"], p["b2"]
    L = _joint2_distance(a2, b2, g, robot.link1.length)
    h2 = b2 / g
    nominal = robot.nominal_masses
    low2 = h2**2 / a3 if a3 > 0 else math.inf
    high2 = (a1 - a3) / L**2 if L != 0 else (math.inf if a1 > a3 else -math.inf)
    feasible = low2 < high2
    m2 = _inside(nominal[1], low2, high2) if feasible else nominal[1]
    J1 = a1 - a3 - m2 * L**2
    h1 = np.array([b1 / g - m2 * L, -p.get("b1s", 0.0) / g])  # b1s sin q1: the centre of mass off link 1's line
    low1 = float(h1 @ h1) / J1 if J1 > 0 else math.inf
    m1 = _inside(nominal[0], low1, math.inf) if feasible else nominal[0]
    return _PlanarShape(
        L=L,
        masses=(m1, m2),
        coms=(tuple(h1 / m1), (h2 / m2, 0.0)),
        moments=(J1 - float(h1 @ h1) / m1, a3 - h2**2 / m2),
        intervals=((low1, math.inf), (low2, high2)),
        feasible=feasible,
        nominal=nominal,
    )


def _about_axis(angle: float) -> np.ndarray:
    """Rotation by `angle` [rad] about `PLANAR_AXIS`: x̂ turns toward +z."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def _planar_friction(arm: PlanarArm, p: dict[str, float], j: int) -> tuple[float, float, list[str]]:
    """Joint j's (0 or 1) Coulomb friction [N m], constant offset [N m] and notes on what the file cannot say:
    asymmetric Coulomb levels are their mean plus a constant offset (p − n)/2 (exact at dq ≠ 0); a Stribeck term
    is left out."""
    k = str(j + 1)
    if f"fc{k}" in p:
        return p[f"fc{k}"], 0.0, _stribeck_note(arm, p, j)
    up, down = p[f"fc{k}p"], p[f"fc{k}n"]
    fc, offset = 0.5 * (up + down), 0.5 * (up - down)
    notes = []
    if offset:
        notes.append(
            f"joint {k}: direction-dependent Coulomb friction (fc{k}p = {up:.6g}, fc{k}n = {down:.6g} N m) is said as "
            f"their mean {fc:.6g} N m × sign(dq) plus a constant offset {offset:.6g} N m (equal at dq ≠ 0; neither "
            "format has direction-dependent friction)"
        )
    return fc, offset, notes + _stribeck_note(arm, p, j)


def _stribeck_note(arm: PlanarArm, p: dict[str, float], j: int) -> list[str]:
    """The note that joint j's Stribeck term, if the model has a non-zero one, is left out."""
    k = str(j + 1)
    if not p.get(f"fs{k}", 0.0):
        return []
    vs = arm.stribeck_velocity[j]
    quiet = vs * math.sqrt(math.log(1e9))  # |dq| beyond which exp(−(dq/vs)²) < 1e-9
    return [
        f"joint {k}: the Stribeck term fs{k} sign(dq) exp(−(dq/{vs:g})²), fs{k} = {p[f'fs{k}']:.6g} N m, is "
        f"left out (neither format has it; below 1e-9 of fs{k} for |dq| > {quiet:.3g} rad/s)"
    ]


def _planar_names(robot: PlanarRobot) -> tuple[str, str, tuple[str, str], tuple[str, str]]:
    """(robot, base link, link and joint names): a URDF robot's own, else planar_two_link_arm, base_link, link1,
    link2, joint1, joint2."""
    if robot.urdf is not None:  # read from a URDF: its own names
        text, joints, _ = parse_urdf(robot.urdf)
        first, second = robot.joint_names
        base = _root_link(joints, joints[first].parent)
        name = ET.fromstring(text).get("name") or "planar_two_link_arm"
        return name, base, (joints[first].child, joints[second].child), (first, second)
    return "planar_two_link_arm", "base_link", ("link1", "link2"), tuple(robot.joint_names)


def planar_bodies(robot: PlanarRobot, arm: PlanarArm, pi: np.ndarray, **options) -> RobotDescription:
    """The planar two-link `robot` with the grouped parameters π of `arm` (`arm.names`) as rigid bodies (module
    doc: the exact realisation, its free choices and what it says it could not determine). `options` (`_finish`):
    `name` (default: its URDF's, else "planar_two_link_arm"); `undetermined`, parameter names the data did not
    determine, said in the notes; `strict`, refuse a π no physical arm has."""
    p = arm.as_dict(_checked(pi, arm.names, "planar arm"))
    if p.get("b2s", 0.0) != 0:
        raise InputError(
            f"planar arm: the joint_offset term b2s = {p['b2s']:.6g} N m (link 2's gravity × sin(q1 + q2)) has no "
            "rigid-body equivalent in the grouped model (link 2's centre of mass off its line would add inertial terms "
            "the model lacks); export a fit without it"
        )
    # The paper's printed gravity vector has G1 = (b1 + b2) c1 + b2 c12: its b1 + b2 is the physical one.
    b1 = p["b1"] + (p["b2"] if arm.gravity == "paper" else 0.0)
    shape = _planar_shape(robot, p, b1)
    own_name, base, links, joint_names = _planar_names(robot)
    signs = tuple(robot.angle_signs)
    offsets = tuple(robot.angle_offsets)
    bodies = tuple(
        Body(link, float(m), vector3((x, 0.0, z)), matrix3(moment * np.eye(3)))
        for link, m, (x, z), moment in zip(links, shape.masses, shape.coms, shape.moments)
    )
    joints, friction_notes = [], []
    for j in range(2):
        fc, offset, lines = _planar_friction(arm, p, j)
        friction_notes += lines
        joints.append(
            Joint(
                joint_names[j],
                (base, links[0])[j],
                links[j],
                Origin((shape.L if j else 0.0, 0.0, 0.0), matrix3(_about_axis(offsets[j]))),
                vector3(signs[j] * np.array(PLANAR_AXIS)),
                damping=p[f"fv{j + 1}"],
                friction=fc,
                armature=p.get("ia2", 0.0) if j else 0.0,
                offset=signs[j] * offset,  # τ_file = s τ_tool
            )
        )
    notes = [
        *_planar_convention(robot, joint_names, signs, offsets),
        *_planar_choices(robot, arm, p, shape),
        *friction_notes,
    ]
    description = RobotDescription(
        own_name,
        base,
        bodies,
        tuple(joints),
        (0.0, 0.0, -robot.gravity),
        notes=tuple(notes),
    )
    problems = [] if shape.feasible else [_infeasible(p)]
    return _finish(description, problems, **options)


def _infeasible(p: dict[str, float]) -> str:
    a1, a2, a3 = p["a1"], p["a2"], p["a3"]
    return (
        f"a1 = {a1:.6g}, a2 = {a2:.6g}, a3 = {a3:.6g} kg m² are not those of any two-link arm of rigid bodies: "
        f"that needs a3 > 0 and a3 (a1 − a3) = {a3 * (a1 - a3):.6g} > a2² = {a2**2:.6g} (kg m²)²"
    )


def _planar_convention(
    robot: PlanarRobot, joints: tuple[str, str], signs: tuple[float, ...], offsets: tuple[float, ...]
) -> list[str]:
    """The notes on the file's geometry and angles."""
    lines = [
        f"a planar two-link arm: it moves in the base's x–z plane, gravity (0, 0, −{robot.gravity:g}) m/s² along −z; "
        "each joint turns about (0, −1, 0) × its sign, counter-clockwise seen from −y (x right, z up) positive; link 1 "
        "runs along its frame's x axis to joint 2, link 2's centre of mass lies on its frame's x axis"
    ]
    if robot.urdf is not None:  # read from a URDF: written in its angles
        maps = "; ".join(
            f"q{j + 1} = {s:+g} q({name}) {'+' if off >= 0 else '−'} {abs(off)!r} rad, τ{j + 1} = {s:+g} τ({name})"
            for j, (name, s, off) in enumerate(zip(joints, signs, offsets))
        )
        lines.append(
            f"angles and torques are those of {robot.urdf.name} (as its data are logged), not ident-opt's: {maps} "
            "(ident-opt's q1 from the horizontal, q2 relative to link 1); the geometry is the planar model's, not that "
            "file's 3-D layout"
        )
    else:
        lines.append(
            "q1 is link 1's angle from the horizontal (+x), q2 link 2's relative to link 1, as ident-opt's (0 with the "
            "links in line); τ about each joint's axis"
        )
    return lines


def _mass_choice(label: str, mass: float, nominal: float, interval: tuple[float, float], feasible: bool) -> str:
    """ "m2 = … kg (why; which masses give the same torques)" for the notes."""
    low, high = interval
    if not feasible:
        return f"{label} = {mass:.6g} kg (the datasheet's: no mass makes these parameters a physical arm)"
    same = f"any {label} > {low:.6g} kg" if math.isinf(high) else f"any {label} in ({low:.6g}, {high:.6g}) kg"
    why = (
        "the datasheet's"
        if mass == nominal
        else f"the datasheet's {nominal:.6g} kg is outside that range or within {MASS_MARGIN:.0%} of its end: the "
        f"nearest mass {MASS_MARGIN:.0%} inside"
    )
    return f"{label} = {mass:.6g} kg ({why}; the same torques for {same})"


def _planar_choices(robot: PlanarRobot, arm: PlanarArm, p: dict[str, float], shape: _PlanarShape) -> list[str]:
    """The notes on what the data did not determine and what the realisation chose for it."""
    l1, L = robot.link1.length, shape.L
    choices = "; ".join(
        _mass_choice(f"m{j + 1}", shape.masses[j], shape.nominal[j], shape.intervals[j], shape.feasible) for j in (1, 0)
    )
    lines = [
        "not determined by the data: the masses m1 and m2 (the torques fix only m2 lc2, I2 + m2 lc2², m1 lc1 + m2 l1 "
        f"and I1 + m1 lc1² + m2 l1²): {choices}; each link's centre of mass and moment of inertia follow from its mass",
        "not determined by the data: joint 1's armature apart from link 1's inertia (both add to M11 only): it is in "
        "link 1's inertia, joint 1's armature is 0; the moments of inertia about axes other than the joint axis (set "
        "equal to it) and the centres of mass along the joint axis (0): a planar motion does not feel them",
    ]
    if abs(L - l1) > LENGTH_TOLERANCE * abs(l1):
        lines.append(
            f"joint 2 sits L = g a2/b2 = {L:.9g} m from joint 1, not at the robot's l1 = {l1:.9g} m: the fit's "
            f"a2 = {p['a2']:.6g} kg m² and b2 = {p['b2']:.6g} N m both fix link 2's m2 lc2 (a2 = l1 m2 lc2, "
            f"b2 = g m2 lc2) and disagree by {100 * (L / l1 - 1):.3g} %; this L keeps both exact"
            + ("; L < 0: joint 2 lies behind joint 1 along link 1's x axis" if L < 0 else "")
        )
    if arm.gravity == "paper":
        lines.append(
            "the fit used the paper's printed gravity vector G1 = (b1 + b2) c1 + b2 c12: here b1 + b2 is link 1's"
        )
    if p.get("b1s", 0.0):
        lines.append(
            f"the joint_offset term b1s = {p['b1s']:.6g} N m (× sin q1) is link 1's centre of mass off its line "
            "(z in its frame)"
        )
    return lines
