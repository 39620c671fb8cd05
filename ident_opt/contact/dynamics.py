"""What a momentum observer needs of the identified arm: the generalized momentum p and the bias β.

The arm's model (`Arm.tau_expression`, CasADi) is τ = M(q) ddq + C(q, dq) dq + g(q) + τ_f(dq). With τ_ext the
torque something outside the arm applies at its joints,

    M(q) ddq + C(q, dq) dq + g(q) + τ_f(dq) = τ + τ_ext,

and the momentum p = M(q) dq changes as ṗ = M ddq + Ṁ dq, so

    ṗ = τ + τ_ext − β(q, dq),      β = C(q, dq) dq + g + τ_f − Ṁ(q, dq) dq   (= g + τ_f − Cᵀ dq),

which needs no acceleration. Everything is read off the one expression of τ, for any arm:

    M v = (∂τ/∂ddq) v,   h(q, dq) = τ(q, dq, 0) = C dq + g + τ_f,   Ṁ dq = (∂(M(q) v)/∂q · dq) at v = dq,

both products by forward-mode directional derivatives (`casadi.jtimes`: M itself is never formed, which makes the
generated `observer_step` of a 7-joint arm three times faster than through the full Jacobians), so the planar arm
and an n-joint chain (and each model extension, e.g. armature, asymmetric Coulomb) give their own p and β with no
case made here. Units: q [rad], dq [rad/s], p [N m s], β and τ [N m].
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np

from ident_opt.arm.base import Arm


def momentum_expressions(arm: Arm, q: ca.SX, dq: ca.SX, pi) -> tuple[ca.SX, ca.SX]:
    """(p, β) as CasADi expressions of q, dq (n×1) for parameters π (numeric or symbolic): p = M(q) dq [N m s],
    β = τ(q, dq, 0) − Ṁ(q, dq) dq [N m] (module doc)."""
    n = arm.n_joints
    ddq, v = ca.SX.sym("ddq", n), ca.SX.sym("v", n)
    tau = arm.tau_expression(q, dq, ddq, pi)
    zero = ca.SX.zeros(n)
    M_v = ca.substitute(ca.jtimes(tau, ddq, v), ddq, zero)  # M(q) v: τ is linear in ddq (forward mode, no M formed)
    h = ca.substitute(tau, ddq, zero)
    M_dot_dq = ca.substitute(ca.jtimes(M_v, q, dq), v, dq)  # (∂(M v)/∂q) dq at v = dq
    return ca.substitute(M_v, v, dq), h - M_dot_dq


@dataclass(frozen=True)
class Momentum:
    """p(q, dq) and β(q, dq) of `arm` at the fitted `pi` (P,), evaluated on whole trials (`of`)."""

    arm: Arm
    pi: np.ndarray

    @cached_property
    def function(self) -> ca.Function:
        """CasADi Function (q, dq) -> (p, beta), each n×1, π baked in."""
        n = self.arm.n_joints
        q, dq = ca.SX.sym("q", n), ca.SX.sym("dq", n)
        p, beta = momentum_expressions(self.arm, q, dq, ca.DM(np.asarray(self.pi, dtype=float)))
        return ca.Function("momentum", [q, dq], [p, beta], ["q", "dq"], ["p", "beta"])

    def of(self, q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """p (N, n) [N m s] and β (N, n) [N m] at the samples q, dq (N, n) [rad, rad/s]."""
        q, dq = np.atleast_2d(np.asarray(q, dtype=float)), np.atleast_2d(np.asarray(dq, dtype=float))
        if len(q) == 0:
            return np.zeros_like(q), np.zeros_like(q)
        p, beta = self.function.map(len(q))(q.T, dq.T)
        return np.asarray(p).T, np.asarray(beta).T
