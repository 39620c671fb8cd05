"""An n-joint arm from a URDF (serial chain of revolute joints, fixed base): the `ident_opt.arm.Arm`
interface, numerically through Pinocchio and symbolically through a CasADi recursive Newton–Euler. The
regressor rows are the CasADi model compiled to C once per machine (cached), Pinocchio's when no C compiler works.

Parameters π, each declared once with its kind (`ident_opt.parameters`), named by the URDF's names:

| name                                   | unit        | kind      | meaning                                   |
|----------------------------------------|-------------|-----------|-------------------------------------------|
| `m_<link>`                             | kg          | inertia   | mass of the moving link                   |
| `mx_<link>`, `my_<link>`, `mz_<link>`  | kg m        | gravity   | mass × centre of mass, in the link frame  |
| `ixx_<link>`, `iyy_<link>`, `izz_<link>` | kg m²     | inertia   | inertia about the link frame's origin     |
| `ixy_<link>`, `ixz_<link>`, `iyz_<link>` | kg m²     | coupling  | products of inertia, same point and frame |
| `fv_<joint>`                           | N m s/rad   | friction  | viscous friction                          |
| `fc_<joint>`                           | N m         | friction  | Coulomb friction (× sign dq)              |
| `ia_<joint>`                           | kg m²       | armature  | rotor inertia reflected to the joint      |
| `off_<joint>`                          | N m         | other     | constant torque(-sensor) offset           |

The link frame is the URDF child link's frame of each joint (fixed children merged into it, as Pinocchio
does); the 10 link parameters are in Pinocchio's `Inertia.toDynamicParameters` order, [m, mx, my, mz,
ixx, ixy, iyy, ixz, iyz, izz]. τ = RNEA(q, dq, ddq; links) + fv dq + fc sign(dq) + ia ddq + off.

Physical consistency (`mass_lmis`): one 4×4 pseudo-inertia per link, J = [[½ tr(Ī) 1 − Ī, h], [hᵀ, m]] ⪰ 0
(Wensing, Kim, Slotine 2017: exactly the (m, h, Ī) some non-negative density realises), named
`pseudo_inertia_<link>`.

Bad input (`InputError`, exit 2, naming the file and the element): a URDF that does not parse, a named
joint the file lacks or that is not revolute, joints that are not one serial chain from the base.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import casadi as ca
import numpy as np
import pinocchio as pin

from ident_opt.arm.base import casadi_function, symbol_table
from ident_opt.arm.rnea import N_LINK, ChainJoint, rnea
from ident_opt.arm.urdf import chain_model, check_chain, parse_urdf
from ident_opt.cbuild import CompiledRows
from ident_opt.errors import InputError
from ident_opt.parameters import Parameter

#: The 10 standard inertial parameters per link: (prefix, unit, kind, meaning), Pinocchio's order.
LINK_PARAMETERS = (
    ("m", "kg", "inertia", "mass"),
    ("mx", "kg m", "gravity", "mass × centre of mass x (link frame)"),
    ("my", "kg m", "gravity", "mass × centre of mass y (link frame)"),
    ("mz", "kg m", "gravity", "mass × centre of mass z (link frame)"),
    ("ixx", "kg m^2", "inertia", "inertia xx about the link frame origin"),
    ("ixy", "kg m^2", "coupling", "inertia xy about the link frame origin"),
    ("iyy", "kg m^2", "inertia", "inertia yy about the link frame origin"),
    ("ixz", "kg m^2", "coupling", "inertia xz about the link frame origin"),
    ("iyz", "kg m^2", "coupling", "inertia yz about the link frame origin"),
    ("izz", "kg m^2", "inertia", "inertia zz about the link frame origin"),
)
#: Per-joint terms: (prefix, unit, kind, meaning, regressor column as a function of (dq_j, ddq_j)).
JOINT_TERMS = {
    "fv": ("N m s/rad", "friction", "viscous friction"),
    "fc": ("N m", "friction", "Coulomb friction"),
    "ia": ("kg m^2", "armature", "rotor inertia (armature) reflected to the joint"),
    "off": ("N m", "other", "constant torque offset"),
}
#: Gravity along −z of the base [m/s²] unless the problem file says otherwise.
STANDARD_GRAVITY = (0.0, 0.0, -9.81)


@dataclass(frozen=True)
class ChainArm:
    """An `Arm` from a URDF: `joints` (the revolute joints, base to tip) of the file `urdf`, gravity (3,)
    [m/s²] in the base frame; per-joint friction (fv, fc), armature (ia) and offset (off) terms as chosen.

    Immutable and hashable on its arguments (the file is read once, at construction).
    """

    urdf: str
    joints: tuple[str, ...]
    gravity: tuple[float, float, float] = STANDARD_GRAVITY
    base: str | None = None
    friction: bool = True
    armature: bool = True
    offsets: bool = False
    couplings: tuple[tuple[str, str, float], ...] = ()
    _parsed: tuple = field(default=(), compare=False, hash=False, repr=False)

    def __post_init__(self):
        object.__setattr__(self, "joints", tuple(self.joints))
        object.__setattr__(self, "gravity", tuple(float(g) for g in self.gravity))
        object.__setattr__(self, "couplings", tuple((str(a), str(b), float(r)) for a, b, r in self.couplings))
        for a, b, _ in self.couplings:
            for name in (a, b):
                if name not in self.joints:
                    raise InputError(
                        f"{self.urdf}: coupling names joint {name!r}, which is not among {list(self.joints)}"
                    )
        path = Path(self.urdf)
        text, joints, links = parse_urdf(path)
        base = check_chain(path, joints, self.joints, self.base)
        object.__setattr__(self, "_parsed", (text, joints, links, base))
        self._model  # noqa: B018  (build Pinocchio's model now, so a fault shows at construction)

    # ------------------------------------------------------------------ structure
    @property
    def urdf_joints(self) -> dict:
        """The URDF's joints as read (`ident_opt.arm.urdf.UrdfJoint`: origin, axis, <dynamics>, <limit>), by name."""
        return self._parsed[1]

    @cached_property
    def _model(self) -> pin.Model:
        """Pinocchio's model of the chain (`chain_model`) under this arm's gravity."""
        model = chain_model(self.urdf, self._parsed[0], self.joints)
        model.gravity = pin.Motion(np.asarray(self.gravity), np.zeros(3))
        return model

    @cached_property
    def links(self) -> tuple[str, ...]:
        """The moving links' URDF names (each joint's child link), base to tip."""
        joints = self._parsed[1]
        return tuple(joints[j].child for j in self.joints)

    @cached_property
    def chain(self) -> tuple[ChainJoint, ...]:
        """The chain as the CasADi RNEA reads it: parent, placement and unit axis of each joint."""
        model, data = self._model, self._model.createData()
        out = []
        for i in range(1, model.njoints):
            v = np.zeros(model.nv)
            v[i - 1] = 1.0
            pin.forwardKinematics(model, data, pin.neutral(model), v)
            placement = model.jointPlacements[i]
            axis = np.array(data.v[i].angular)  # with only dq_i = 1 the joint's velocity is its axis
            out.append(ChainJoint(model.parents[i] - 1, placement.rotation.copy(), placement.translation.copy(), axis))
        return tuple(out)

    @property
    def n_joints(self) -> int:
        """n, the number of joints."""
        return len(self.joints)

    @property
    def extensions(self) -> tuple[str, ...]:
        """Model extensions of `ident_opt.effects`: none (the joint terms are the arm's own)."""
        return ()

    #: What `min_mass_eigenvalue` measures, as a table heading.
    consistency_measure = "min eig of the links' pseudo-inertias [kg m²]"

    def settings(self) -> dict:
        """The URDF, its joints, gravity [m/s²], the joint terms and couplings."""
        return {
            "urdf": str(self.urdf),
            "joints": list(self.joints),
            "gravity": list(self.gravity),
            "joint_terms": list(self.joint_terms),
            "couplings": [list(c) for c in self.couplings],
        }

    @cached_property
    def joint_terms(self) -> tuple[str, ...]:
        """The per-joint term prefixes this arm has, in π's order (of fv, fc, ia, off)."""
        chosen = {"fv": self.friction, "fc": self.friction, "ia": self.armature, "off": self.offsets}
        return tuple(k for k in JOINT_TERMS if chosen[k])

    @cached_property
    def drive_matrix(self) -> np.ndarray:
        """C (n, n): drive m turns at C[m] · dq (joint-side units) and its torque f_m reaches joint j as
        C[m, j] f_m. The identity, plus each coupling (m, j, r): C[m, j] = r (a coupled wrist's motor)."""
        C = np.eye(self.n_joints)
        for a, b, r in self.couplings:
            C[self.joints.index(a), self.joints.index(b)] = r
        return C

    @cached_property
    def parameters(self) -> tuple[Parameter, ...]:
        """The declarations of π (module doc): 10 per link, then each chosen joint term per joint."""
        out = [
            Parameter(f"{prefix}_{link}", unit, f"{link}: {meaning}", kind)
            for link in self.links
            for prefix, unit, kind, meaning in LINK_PARAMETERS
        ]
        for term in self.joint_terms:
            unit, kind, meaning = JOINT_TERMS[term]
            out += [Parameter(f"{term}_{j}", unit, f"{j}: {meaning}", kind, i + 1) for i, j in enumerate(self.joints)]
        return tuple(out)

    @cached_property
    def names(self) -> tuple[str, ...]:
        """Parameter names, in the order of π and of Y's columns."""
        return tuple(p.name for p in self.parameters)

    @property
    def n_params(self) -> int:
        """P = 10 n + (number of joint terms) n."""
        return len(self.parameters)

    @property
    def n_link_params(self) -> int:
        """10 n: the inertial parameters come first in π."""
        return N_LINK * self.n_joints

    def vector(self, pi: Mapping[str, float]) -> np.ndarray:
        """π (P,) from a name → value mapping (missing names: 0)."""
        return np.array([float(pi.get(n, 0.0)) for n in self.names])

    def as_dict(self, pi: np.ndarray) -> dict[str, float]:
        """π (P,) to a name → value dict."""
        return {n: float(v) for n, v in zip(self.names, pi)}

    @cached_property
    def missing_inertials(self) -> tuple[str, ...]:
        """Moving links of the file with no <inertial> element (a CAD prior cannot be formed for them)."""
        links = self._parsed[2]
        return tuple(name for name in self.links if links[name].find("inertial") is None)

    def cad_parameters(self) -> np.ndarray:
        """π0 (P,): the URDF's inertials (as Pinocchio merges them into each link frame), joint terms 0."""
        if self.missing_inertials:
            raise InputError(
                f"{self.urdf}: <link name={self.missing_inertials[0]!r}> has no <inertial>, and the fit needs the "
                "URDF's inertials as a prior"
            )
        pi = np.zeros(self.n_params)
        for i in range(self.n_joints):
            pi[N_LINK * i : N_LINK * (i + 1)] = self._model.inertias[i + 1].toDynamicParameters()
        return pi

    def link_masses(self, pi: np.ndarray) -> dict[str, float]:
        """Each moving link's mass [kg] at π."""
        return {link: float(pi[N_LINK * i]) for i, link in enumerate(self.links)}

    # ------------------------------------------------------------------ numeric (Pinocchio)
    def regressor(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Y (N, n, P) with τ[k] = Y[k] @ π [N m]: the rigid chain's columns (Pinocchio's joint torque
        regressor), then the joint terms (dq_j, sign dq_j, ddq_j, 1 on row j, through the drive couplings).
        Evaluated by the compiled CasADi model (`_compiled_regressor`), else by Pinocchio per sample."""
        q, dq, ddq = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (q, dq, ddq))
        N, n = q.shape
        if n != self.n_joints:
            raise ValueError(f"{n} joint columns given, the arm {self.urdf} has {self.n_joints} joints")
        compiled = self._compiled_regressor
        if compiled is not None:
            return compiled(np.hstack((q, dq, ddq)))
        L = self.n_link_params
        Y = np.empty((N, n, self.n_params))
        Y[:, :, L:] = 0.0
        model, data = self._model, self._model.createData()
        regressor = pin.computeJointTorqueRegressor
        for k in range(N):  # Pinocchio's C++ per sample: the Python loop is most of the cost (~4 µs/sample)
            Y[k, :, :L] = regressor(model, data, q[k], dq[k], ddq[k])
        C = self.drive_matrix
        v, a = dq @ C.T, ddq @ C.T  # each drive's joint-side velocity and acceleration
        columns = {"fv": v, "fc": np.sign(v), "ia": a}
        rows = np.arange(n)
        for t, term in enumerate(self.joint_terms):
            if term == "off":
                Y[:, rows, L + t * n + rows] = 1.0
                continue
            for m, j in zip(*np.nonzero(C)):
                Y[:, j, L + t * n + m] = C[m, j] * columns[term][:, m]
        return Y

    @cached_property
    def _compiled_regressor(self) -> CompiledRows | None:
        """Y = ∂τ/∂π of the CasADi model (`tau_expression`, checked against Pinocchio) as generated C, called on
        chunks of samples (`CompiledRows`): several times faster than Pinocchio's regressor called per sample
        from Python, whose call overhead dominates. None when no C compiler works (`IDENT_OPT_REGRESSOR=pinocchio`
        also asks for that): Y then comes from Pinocchio."""
        if os.environ.get("IDENT_OPT_REGRESSOR", "").strip().lower() == "pinocchio":
            return None
        n = self.n_joints
        q, dq, ddq = ca.SX.sym("q", n), ca.SX.sym("dq", n), ca.SX.sym("ddq", n)
        pi = ca.SX.sym("pi", self.n_params)
        Y = ca.jacobian(self.tau_expression(q, dq, ddq, pi), pi)  # τ is linear in π: Y is free of it
        # Yᵀ, dense: CasADi writes column-major, so each sample's block is Y (n, P) row-major, as NumPy reads it
        rows = ca.Function("urdf_regressor", [ca.vertcat(q, dq, ddq)], [ca.densify(Y).T])
        try:
            return CompiledRows(rows, "regressor")
        except (InputError, OSError):
            return None

    def predict(self, pi: np.ndarray, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """τ (N, n) [N m] for parameters π."""
        return self.regressor(q, dq, ddq) @ np.asarray(pi, dtype=float)

    def _pinocchio_with(self, pi: np.ndarray) -> pin.Model:
        """A copy of the model with the link inertias of π (joint terms are not Pinocchio's)."""
        model = self._model.copy()
        for i in range(self.n_joints):
            model.inertias[i + 1] = pin.Inertia.FromDynamicParameters(np.asarray(pi[N_LINK * i : N_LINK * (i + 1)]))
        return model

    def mass_matrices(self, pi: np.ndarray, q: np.ndarray) -> np.ndarray:
        """M(q) (N, n, n) [kg m²] by Pinocchio's CRBA with π's inertias, plus diag(ia) if the arm has it."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        model = self._pinocchio_with(pi)
        data = model.createData()
        out = np.empty((len(q), self.n_joints, self.n_joints))
        for k in range(len(q)):
            M = pin.crba(model, data, q[k])
            out[k] = np.triu(M) + np.triu(M, 1).T
        if "ia" in self.joint_terms:
            start = self.n_link_params + self.joint_terms.index("ia") * self.n_joints
            C = self.drive_matrix
            out += C.T @ np.diag(pi[start : start + self.n_joints]) @ C
        return out

    # ------------------------------------------------------------------ consistency
    def pseudo_inertia_map(self) -> np.ndarray:
        """A (10, 4, 4): J(π_link) = Σ_p π_p A_p = [[½ tr(Ī) 1 − Ī, h], [hᵀ, m]] for one link's 10 parameters."""
        A = np.zeros((N_LINK, 4, 4))
        A[0, 3, 3] = 1.0
        for axis in range(3):
            A[1 + axis, axis, 3] = A[1 + axis, 3, axis] = 1.0
        # Ī entries: (index in π_link, row, col); ½ tr(Ī) on the diagonal minus Ī.
        entries = {4: (0, 0), 5: (0, 1), 6: (1, 1), 7: (0, 2), 8: (1, 2), 9: (2, 2)}
        for p, (r, c) in entries.items():
            if r == c:
                A[p, :3, :3] += 0.5 * np.eye(3)
                A[p, r, r] -= 1.0
            else:
                A[p, r, c] = A[p, c, r] = -1.0
        return A

    def mass_lmis(self) -> dict[str, np.ndarray]:
        """One pseudo-inertia per link, `pseudo_inertia_<link>`: A (P, 4, 4) with J = Σ_p π_p A_p ⪰ 0."""
        one = self.pseudo_inertia_map()
        out = {}
        for i, link in enumerate(self.links):
            A = np.zeros((self.n_params, 4, 4))
            A[N_LINK * i : N_LINK * (i + 1)] = one
            out[f"pseudo_inertia_{link}"] = A
        return out

    def pseudo_inertias(self, pi: np.ndarray) -> np.ndarray:
        """J (n, 4, 4) of every link at π."""
        links = np.asarray(pi[: self.n_link_params], dtype=float).reshape(self.n_joints, N_LINK)
        return np.einsum("lp,pij->lij", links, self.pseudo_inertia_map())

    def min_mass_eigenvalue(self, pi: np.ndarray) -> float:
        """min over links of λ_min of the pseudo-inertia [kg m²] (and of the armatures, if any): > 0 means
        every link's (m, h, Ī) is realised by a density (which makes M(q) ≻ 0 for every q)."""
        worst = float(np.linalg.eigvalsh(self.pseudo_inertias(np.asarray(pi, dtype=float)))[:, 0].min())
        return worst

    # ------------------------------------------------------------------ symbolic (CasADi)
    def tau_expression(self, q, dq, ddq, pi):
        """τ (n×1) as a CasADi expression of q, dq, ddq (n×1) and π (P×1): RNEA plus the joint terms."""
        n, L = self.n_joints, self.n_link_params
        tau = rnea(self.chain, q, dq, ddq, pi[:L], np.asarray(self.gravity))
        C = self.drive_matrix
        v = [sum(C[m, k] * dq[k] for k in range(n) if C[m, k]) for m in range(n)]
        a = [sum(C[m, k] * ddq[k] for k in range(n) if C[m, k]) for m in range(n)]
        columns = {"fv": lambda m: v[m], "fc": lambda m: ca.sign(v[m]), "ia": lambda m: a[m]}
        terms = []
        for j in range(n):
            extra = 0
            for t, term in enumerate(self.joint_terms):
                if term == "off":
                    extra = extra + pi[L + t * n + j]
                    continue
                for m in range(n):
                    if C[m, j]:
                        extra = extra + C[m, j] * pi[L + t * n + m] * columns[term](m)
            terms.append(tau[j] + extra)
        return ca.vertcat(*terms)

    @cached_property
    def symbols(self) -> dict[str, ca.SX]:
        """q, dq, ddq (n×1), pi (P×1) and tau, Y = ∂τ/∂π, M = ∂τ/∂ddq, G = τ(q, 0, 0) without the joint terms'
        offsets, F the joint terms, C with C dq = τ(q, dq, 0) − G − F (C = ½ ∂(C dq)/∂dq, quadratic in dq)."""
        n = self.n_joints
        q, dq, ddq = ca.SX.sym("q", n), ca.SX.sym("dq", n), ca.SX.sym("ddq", n)
        pi = ca.SX.sym("pi", self.n_params)
        tau = self.tau_expression(q, dq, ddq, pi)
        L = self.n_link_params
        zero = ca.SX.zeros(n)
        rigid_static = rnea(self.chain, q, zero, zero, pi[:L], np.asarray(self.gravity))
        rigid_bias = rnea(self.chain, q, dq, zero, pi[:L], np.asarray(self.gravity))
        M = ca.jacobian(tau, ddq)
        F = tau - M @ ddq - rigid_bias
        coriolis = rigid_bias - rigid_static
        C = 0.5 * ca.jacobian(coriolis, dq)
        return symbol_table(q, dq, ddq, pi, M, C, rigid_static, F, tau=tau)

    def function(self, what: str) -> ca.Function:
        """A CasADi Function of (q, dq, ddq, pi) for one of M, C, G, F, tau, Y."""
        return casadi_function(self.symbols, what)
