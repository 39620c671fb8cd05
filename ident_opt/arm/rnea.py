"""The recursive Newton–Euler algorithm in CasADi: τ of a serial chain of revolute joints, linear in the
standard inertial parameters of its links.

The installable Pinocchio has no CasADi bindings, so NLPs and generated C need the same model written
once in CasADi; `ident_opt.arm.chain.ChainArm` checks it against Pinocchio's RNEA and torque regressor.

Conventions (Pinocchio's, so the two agree to rounding): spatial vectors (linear; angular), every
quantity of link i expressed in its own frame (the frame of joint i), spatial (not classical)
accelerations, the base accelerating at −g. Link i's parameters π_i = [m, m cx, m cy, m cz, Ixx, Ixy, Iyy,
Ixz, Iyz, Izz] with the inertia Ī about the frame's origin (Pinocchio's `Inertia.toDynamicParameters`
order), so the spatial force of link i is

    f_lin = m a + α × h + ω × (m v + ω × h)
    f_ang = h × a + Ī α + ω × (Ī ω) + v × (ω × h) + ω × (h × v)          h = m c,  (v; ω), (a; α)

and τ_i = sᵢ · f_ang,i with sᵢ the unit joint axis. Units: m, kg, kg m, kg m², rad, N m.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

#: Standard inertial parameters per link, in Pinocchio's order.
N_LINK = 10


@dataclass(frozen=True)
class ChainJoint:
    """One revolute joint: its parent joint (−1 for the base), its placement in the parent joint's frame
    (rotation (3, 3) and translation (3,) [m]) and its unit axis (3,) in its own frame."""

    parent: int
    rotation: np.ndarray
    translation: np.ndarray
    axis: np.ndarray


def _rotation(axis: np.ndarray, angle) -> ca.SX:
    """Rodrigues' rotation by `angle` [rad] about the unit `axis` (numeric): I + sin θ [a]× + (1 − cos θ)[a]×²."""
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]], dtype=float)
    return ca.DM(np.eye(3)) + ca.sin(angle) * ca.DM(K) + (1 - ca.cos(angle)) * ca.DM(K @ K)


def link_inertia(p) -> tuple:
    """(m, h (3×1), Ī (3×3)) from one link's 10 standard parameters (module doc order)."""
    inertia = ca.vertcat(
        ca.horzcat(p[4], p[5], p[7]),
        ca.horzcat(p[5], p[6], p[8]),
        ca.horzcat(p[7], p[8], p[9]),
    )
    return p[0], ca.vertcat(p[1], p[2], p[3]), inertia


def rnea(chain: tuple[ChainJoint, ...], q, dq, ddq, links, gravity: np.ndarray) -> ca.SX:
    """τ (n×1) [N m] of the rigid chain for joint positions, velocities, accelerations q, dq, ddq (n×1) and
    link parameters `links` (10n×1, module doc order); `gravity` (3,) [m/s²] in the base frame."""
    n = len(chain)
    zero = ca.SX.zeros(3, 1)
    base_a = ca.DM(-np.asarray(gravity, dtype=float).reshape(3, 1))
    v, w, a, al = [], [], [], []
    rot = []
    for i, jnt in enumerate(chain):
        R = ca.DM(jnt.rotation) @ _rotation(jnt.axis, q[i])  # parent ← child
        p = ca.DM(np.asarray(jnt.translation, dtype=float).reshape(3, 1))
        s = ca.DM(np.asarray(jnt.axis, dtype=float).reshape(3, 1))
        if jnt.parent < 0:
            vp, wp, ap, alp = zero, zero, base_a, zero
        else:
            vp, wp, ap, alp = v[jnt.parent], w[jnt.parent], a[jnt.parent], al[jnt.parent]
        Rt = R.T
        wi = Rt @ wp + s * dq[i]
        vi = Rt @ (vp + ca.cross(wp, p))
        # spatial acceleration: X a_parent + S ddq + v_i × S dq
        ai = Rt @ (ap + ca.cross(alp, p)) + ca.cross(vi, s * dq[i])
        ali = Rt @ alp + s * ddq[i] + ca.cross(wi, s * dq[i])
        v.append(vi)
        w.append(wi)
        a.append(ai)
        al.append(ali)
        rot.append((R, p, s))
    f_lin, f_ang = [None] * n, [None] * n
    for i in range(n):
        m, h, inertia = link_inertia(links[N_LINK * i : N_LINK * (i + 1)])
        vi, wi, ai, ali = v[i], w[i], a[i], al[i]
        f_lin[i] = m * ai + ca.cross(ali, h) + ca.cross(wi, m * vi + ca.cross(wi, h))
        f_ang[i] = (
            ca.cross(h, ai)
            + inertia @ ali
            + ca.cross(wi, inertia @ wi)
            + ca.cross(vi, ca.cross(wi, h))
            + ca.cross(wi, ca.cross(h, vi))
        )
    tau = [None] * n
    for i in reversed(range(n)):
        R, p, s = rot[i]
        tau[i] = ca.dot(s, f_ang[i])
        parent = chain[i].parent
        if parent >= 0:
            fl = R @ f_lin[i]
            f_lin[parent] = f_lin[parent] + fl
            f_ang[parent] = f_ang[parent] + R @ f_ang[i] + ca.cross(p, fl)
    return ca.vertcat(*tau)
