"""A flexible link: link j cut at mid-length into two rigid halves joined by a torsional spring.

The arm becomes a planar chain of three rigid segments with generalised coordinates z = [q1, q2, φ] (φ the
bending angle at the middle of link j). Its equations of motion come from the Lagrangian L = T − V,
written once for any planar chain:
    T = Σ_s ½ m_s |v_s|² + ½ I_s ω_s² + ½ B1 dq1² + ½ B2 dq2²   (segments, plus the rotors on the diagonal),
    V = Σ_s m_s g y_s,
    M(z) ddz + ∂/∂z(∂T/∂dz) dz − ∇_z T + ∇_z V = Q,   M = ∂²T/∂dz²,
    Q = [τ1 − F1(dq1), τ2 − F2(dq2), −k φ − d dφ].
With φ = 0 the two halves are exactly the datasheet's bar (same mass, centre and inertia), so the rigid
part of the truth is still `datasheet_pi(robot, "physical")`; the joint angles q (collocated with the
motors) are what the encoders log. k = J (2π f)² with J = M_φφ: everything beyond the cut, about the cut,
with the joints held (for link 1 at q2 = 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ident_opt.arm.datasheet import Link, PlanarRobot, bar_inertia, cylinder_inertia, rigid_body


@dataclass(frozen=True)
class Segment:
    """A rigid segment of a planar chain: length to the next joint [m], mass [kg], centre of mass along the
    segment [m], inertia about the centre [kg m²], and which coordinate of z rotates it (relative)."""

    length: float
    mass: float
    com: float
    inertia: float
    coordinate: int


def _lump(parts: list[tuple[float, float, float]]) -> tuple[float, float, float]:
    """(mass, centre, inertia about the centre) of parts given as (mass, position, own inertia)."""
    m = sum(p[0] for p in parts)
    c = sum(p[0] * p[1] for p in parts) / m
    return m, c, sum(i + mass * (x - c) ** 2 for mass, x, i in parts)


def _half(link: Link) -> tuple[float, float]:
    """Mass and own inertia of half a uniform bar [kg, kg m²] (the bar cut at mid-length)."""
    half = Link(link.length / 2, link.width, link.height, link.density)
    return half.mass, bar_inertia(half)


def segments(robot: PlanarRobot, flexible: int) -> list[Segment]:
    """The chain for a flexible link `flexible` (0 or 1): link 1 carries joint 2's actuator at its far end
    (the physical convention); a payload sits at the tip of link 2. z = [q1, q2, φ]."""
    l1, l2 = robot.link1.length, robot.link2.length
    motor = (
        robot.joint2.actuator_mass,
        None,
        cylinder_inertia(robot.joint2.actuator_mass, robot.joint2.motor_diameter),
    )
    payload = [(robot.payload_mass, None, 0.0)] if robot.payload_mass > 0 else []

    def body(length, parts, coordinate):
        m, c, i = _lump([(mass, length if x is None else x, inertia) for mass, x, inertia in parts])
        return Segment(length, m, c, i, coordinate)

    if flexible == 0:
        m, i = _half(robot.link1)
        return [
            body(l1 / 2, [(m, l1 / 4, i)], 0),
            body(l1 / 2, [(m, l1 / 4, i), motor], 2),
            body(l2, [(robot.link2.mass, l2 / 2, bar_inertia(robot.link2)), *payload], 1),
        ]
    m, i = _half(robot.link2)
    return [
        body(l1, [(robot.link1.mass, l1 / 2, bar_inertia(robot.link1)), motor], 0),
        body(l2 / 2, [(m, l2 / 4, i)], 1),
        body(l2 / 2, [(m, l2 / 4, i), *payload], 2),
    ]


def lagrangian_terms(robot: PlanarRobot, flexible: int, armature: tuple[float, float]):
    """CasADi (z, dz) and the expressions M(z) (3×3) and h(z, dz) (3×1) with M ddz + h = Q."""
    z, dz = ca.SX.sym("z", 3), ca.SX.sym("dz", 3)
    g = robot.gravity
    T, V = 0.5 * armature[0] * dz[0] ** 2 + 0.5 * armature[1] * dz[1] ** 2, 0
    x = y = angle = omega = 0
    vx = vy = 0
    for s in segments(robot, flexible):
        angle = angle + z[s.coordinate]
        omega = omega + dz[s.coordinate]
        c, sn = ca.cos(angle), ca.sin(angle)
        cy = y + s.com * sn  # height of the segment's centre of mass
        cvx, cvy = vx - s.com * sn * omega, vy + s.com * c * omega
        T += 0.5 * s.mass * (cvx**2 + cvy**2) + 0.5 * s.inertia * omega**2
        V += s.mass * g * cy
        x, y = x + s.length * c, y + s.length * sn
        vx, vy = vx - s.length * sn * omega, vy + s.length * c * omega
    dT = ca.gradient(T, dz)
    M = ca.jacobian(dT, dz)
    h = ca.jacobian(dT, z) @ dz - ca.gradient(T, z) + ca.gradient(V, z)
    return z, dz, M, h


def mode_inertia(robot: PlanarRobot, flexible: int, armature: tuple[float, float], q2: float) -> float:
    """M_φφ at joint-2 angle q2 [kg m²]: everything beyond the cut, about the cut, joints held."""
    z, _, M, _ = lagrangian_terms(robot, flexible, armature)
    return float(ca.Function("M", [z], [M])([0.0, q2, 0.0])[2, 2])


def free_rate(robot: PlanarRobot, flexible: int, armature: tuple[float, float], k: float) -> float:
    """An upper bound of the mode's angular frequency with free joints [rad/s]: √(k (M⁻¹)_φφ), max over q2."""
    z, _, M, _ = lagrangian_terms(robot, flexible, armature)
    f = ca.Function("M", [z], [M])
    return max(math.sqrt(k * np.linalg.inv(np.array(f([0.0, q2, 0.0])))[2, 2]) for q2 in (0.0, 0.7, 1.4))


def datasheet_armature(robot: PlanarRobot) -> tuple[float, float]:
    """Reflected rotor inertia per joint, N² J [kg m²] (physical convention)."""
    return tuple(rigid_body(robot, "physical").armature)
