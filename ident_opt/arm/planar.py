"""The two-link planar arm: M(q), C(q, dq), G(q), F(dq) and the regressor Y with τ = Y(q, dq, ddq) π.

One source of truth, two evaluations:

- the symbolic model (CasADi SX), written as physics (M ddq + C dq + G + F); its regressor is the
  Jacobian of τ with respect to π, so Y is derived, not typed twice. NLPs, derivatives and generated C
  use it.
- a vectorised NumPy regressor for N samples at once (the paper's printed Y, column by column), which the
  tests check against the symbolic one to 1e-12. Identification uses it.

Conventions: q1 from the horizontal, q2 relative to link 1, counter-clockwise positive, gravity along −y;
β in N·m (the regressor's gravity columns are cos q1, cos(q1 + q2) without g). C is the Christoffel
form, so Ṁ − 2C is skew-symmetric; C dq equals the paper's printed C dq.

Extensions (added or replaced columns): the causes of `ident_opt.effects` that are linear in their
parameters (armature, asymmetric_coulomb, stribeck, joint_offset; see `docs/effects.md`) declare their
parameters, NumPy columns and CasADi terms in their own module; this one adds them, in catalogue order.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np

from ident_opt import effects as catalogue
from ident_opt.arm.base import casadi_function, symbol_table
from ident_opt.parameters import Parameter

#: What q means for this arm, for READMEs and reports (`docs/conventions.md`).
ANGLE_CONVENTION = (
    "q1 is link 1's angle from the horizontal, q2 is link 2's angle relative to link 1 (0 when the links are in "
    "line), both counter-clockwise positive, gravity along −y. An arm whose zero hangs straight down must pass "
    "q1 = its angle − π/2 (the same conversion as its problem file's `[data.columns]` offset); a joint that counts "
    "clockwise flips the sign of its q, dq, ddq and tau."
)
#: The paper's grouped parameters, in its order (β in N·m, friction joint-side).
PI_NAMES = ("a1", "a2", "a3", "b1", "b2", "fv1", "fv2", "fc1", "fc2")

#: The paper's grouped parameters π, declared once (names in `PI_NAMES` order).
RIGID_PARAMETERS = (
    Parameter(
        "a1", "kg m^2", "I1 + m1 lc1² + m2 l1² + a3 (+ joint-1 armature under the physical convention)", "inertia"
    ),
    Parameter("a2", "kg m^2", "m2 l1 lc2: the inertial coupling of the two links", "coupling"),
    Parameter("a3", "kg m^2", "I2 + m2 lc2²", "inertia"),
    Parameter("b1", "N m", "g (m1 lc1 + m2 l1)", "gravity"),
    Parameter("b2", "N m", "g m2 lc2", "gravity"),
    Parameter("fv1", "N m s/rad", "joint-1 viscous friction", "friction", 1),
    Parameter("fv2", "N m s/rad", "joint-2 viscous friction", "friction", 2),
    Parameter("fc1", "N m", "joint-1 Coulomb friction", "friction", 1),
    Parameter("fc2", "N m", "joint-2 Coulomb friction", "friction", 2),
)
assert tuple(p.name for p in RIGID_PARAMETERS) == PI_NAMES

#: Extension name -> the names of the parameters it adds (in column order).
EXTENSIONS = {name: tuple(p.name for p in e.parameters) for name, e in catalogue.EXTENSIONS.items()}


@dataclass(frozen=True)
class PlanarArm:
    """A rigid two-link arm model: which parameters it has and how τ depends on them (an `Arm`).

    `gravity="paper"` gives the paper's printed G1 = (β1 + β2) c1 + β2 c12, kept only to reproduce its
    Model 2; identification uses the physically correct G1 = β1 c1 + β2 c12.
    """

    extensions: tuple[str, ...] = ()
    gravity: str = "physical"
    stribeck_velocity: tuple[float, float] = (0.05, 0.05)  # rad/s

    def __post_init__(self):
        try:  # an alias (e.g. "offset") stands for its extension's own name
            object.__setattr__(self, "extensions", tuple(catalogue.extension(e).name for e in self.extensions))
        except KeyError:
            unknown = [e for e in self.extensions if not catalogue.is_extension(e)]
            raise ValueError(f"unknown model extension(s) {unknown}; known: {sorted(EXTENSIONS)}") from None
        if self.gravity not in ("physical", "paper"):
            raise ValueError("gravity must be 'physical' or 'paper'")
        for effect in self._effects:
            effect.check_model(self)

    @cached_property
    def _effects(self) -> tuple[catalogue.Effect, ...]:
        """The extensions' effects, in catalogue order (the order their terms are added in)."""
        return tuple(e for name, e in catalogue.EXTENSIONS.items() if name in self.extensions)

    # ------------------------------------------------------------------ parameters
    @cached_property
    def names(self) -> tuple[str, ...]:
        """Parameter names, in the order of π and of Y's columns."""
        replaced = {name for e in self._effects for name in e.replaces}
        names = [n for n in PI_NAMES if n not in replaced]
        for ext in self.extensions:
            names += EXTENSIONS[ext]
        return tuple(names)

    @cached_property
    def parameters(self) -> tuple[Parameter, ...]:
        """Each parameter's declaration (unit, meaning, kind), in the order of π."""
        declared = {p.name: p for p in RIGID_PARAMETERS}
        for effect in self._effects:
            declared.update({p.name: p for p in effect.parameters})
        return tuple(declared[n] for n in self.names)

    @property
    def n_params(self) -> int:
        """P, the number of parameters."""
        return len(self.names)

    @property
    def n_joints(self) -> int:
        """n = 2 joints."""
        return 2

    @property
    def drive_matrix(self) -> np.ndarray:
        """C = I (2, 2): each joint has a drive of its own."""
        return np.eye(2)

    def vector(self, pi: dict[str, float]) -> np.ndarray:
        """π as a vector in this model's order; names absent from `pi` are 0 (an extension's parameter may
        default to a rigid one when that is given, e.g. the asymmetric fc1p to the symmetric fc1)."""
        fallback = {name: rigid for e in self._effects for name, rigid in e.fallback.items()}
        out = []
        for name in self.names:
            if name in pi:
                out.append(pi[name])
            elif fallback.get(name) in pi:
                out.append(pi[fallback[name]])
            else:
                out.append(0.0)
        return np.asarray(out, dtype=float)

    def as_dict(self, pi: np.ndarray) -> dict[str, float]:
        """π vector to a name → value dict."""
        return {name: float(v) for name, v in zip(self.names, pi)}

    # ------------------------------------------------------------------ symbolic (CasADi) model
    def _terms(self, q, dq, pi) -> tuple:
        """M(q), C(q, dq), G(q), F(dq) as CasADi expressions of the parameter vector `pi`."""
        p = {name: pi[i] for i, name in enumerate(self.names)}
        zero = 0
        c1, c2, s2 = ca.cos(q[0]), ca.cos(q[1]), ca.sin(q[1])
        c12 = ca.cos(q[0] + q[1])
        a1, a2, a3 = p["a1"], p["a2"], p["a3"]
        M = [[a1 + 2 * a2 * c2, a3 + a2 * c2], [a3 + a2 * c2, a3]]
        C = ca.vertcat(
            ca.horzcat(-a2 * s2 * dq[1], -a2 * s2 * (dq[0] + dq[1])),
            ca.horzcat(a2 * s2 * dq[0], zero),
        )
        g1 = p["b1"] * c1 + p["b2"] * c12
        if self.gravity == "paper":
            g1 += p["b2"] * c1
        G = [g1, p["b2"] * c12]
        F = []
        for j in range(2):
            k = str(j + 1)
            f = p["fv" + k] * dq[j]
            if "fc" + k in p:  # unless an extension replaces the symmetric Coulomb term
                f += p["fc" + k] * ca.sign(dq[j])
            F.append(f)
        for effect in self._effects:
            effect.add_terms(self, q, dq, p, M, G, F)
        return ca.vertcat(ca.horzcat(*M[0]), ca.horzcat(*M[1])), C, ca.vertcat(*G), ca.vertcat(*F)

    @cached_property
    def symbols(self) -> dict[str, ca.SX]:
        """The CasADi symbols q, dq, ddq (2×1) and pi (P×1) and the expressions built from them."""
        n = self.n_joints
        q, dq, ddq = ca.SX.sym("q", n), ca.SX.sym("dq", n), ca.SX.sym("ddq", n)
        pi = ca.SX.sym("pi", self.n_params)
        M, C, G, F = self._terms(q, dq, pi)
        return symbol_table(q, dq, ddq, pi, M, C, G, F)

    def function(self, what: str) -> ca.Function:
        """A CasADi Function for one of M, C, G, F, tau, Y, with inputs (q, dq, ddq, pi)."""
        return casadi_function(self.symbols, what)

    def tau_expression(self, q, dq, ddq, pi):
        """τ as a CasADi expression of any (symbolic or numeric) q, dq, ddq and π."""
        M, C, G, F = self._terms(q, dq, pi)
        return M @ ddq + C @ dq + G + F

    # ------------------------------------------------------------------ numeric (NumPy) model
    def regressor(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Y for N samples: array (N, 2, P) with τ[k] = Y[k] @ π. Inputs (N, 2) in rad, rad/s, rad/s²."""
        q, dq, ddq = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (q, dq, ddq))
        Y = np.empty((q.shape[0], self.n_joints, self.n_params))
        for i, name in enumerate(self.names):
            for j, row in enumerate(self._columns[name](q, dq, ddq)):
                Y[:, j, i] = row
        return Y

    def predict(self, pi: np.ndarray, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Predicted joint torques (N, 2) [N m] for parameters π."""
        return self.regressor(q, dq, ddq) @ np.asarray(pi, dtype=float)

    def link_side(self, pi: np.ndarray, armature) -> np.ndarray:
        """π of the link side: friction zeroed and the rotors' reflected inertia (`armature` [kg m²] per joint)
        removed, so that τ = Y π is the link-side rigid-body torque (inertial, Coriolis/centrifugal, gravity)."""
        out = np.where([p.kind == "friction" for p in self.parameters], 0.0, np.asarray(pi, dtype=float))
        names = list(self.names)
        out[names.index("a1")] -= armature[0]
        if "ia2" in names:
            out[names.index("ia2")] -= armature[1]
        return out

    def friction_of(self, pi: np.ndarray, joint: int) -> np.ndarray:
        """π with everything zeroed except the friction parameters (`Parameter.kind`) of `joint` (0-based): those
        on which τ_joint depends (a structural non-zero of the symbolic Y's row)."""
        acts = self.symbols["Y"].sparsity()
        kept = [p.kind == "friction" and acts.has_nz(joint, i) for i, p in enumerate(self.parameters)]
        return np.where(kept, pi, 0.0)

    @cached_property
    def _columns(self) -> dict[str, Callable]:
        """The paper's printed regressor, one function per column: (q, dq, ddq) -> (row 1, row 2)."""
        zero = np.zeros_like

        def c(a):
            return np.cos(a)

        def s(a):
            return np.sin(a)

        cols = {
            "a1": lambda q, dq, a: (a[:, 0], zero(a[:, 0])),
            "a2": lambda q, dq, a: (
                c(q[:, 1]) * (2 * a[:, 0] + a[:, 1]) - s(q[:, 1]) * (2 * dq[:, 0] * dq[:, 1] + dq[:, 1] ** 2),
                c(q[:, 1]) * a[:, 0] + s(q[:, 1]) * dq[:, 0] ** 2,
            ),
            "a3": lambda q, dq, a: (a[:, 1], a[:, 0] + a[:, 1]),
            "b1": lambda q, dq, a: (c(q[:, 0]), zero(q[:, 0])),
            "b2": lambda q, dq, a: (
                c(q[:, 0] + q[:, 1]) + (c(q[:, 0]) if self.gravity == "paper" else 0.0),
                c(q[:, 0] + q[:, 1]),
            ),
            "fv1": lambda q, dq, a: (dq[:, 0], zero(dq[:, 0])),
            "fv2": lambda q, dq, a: (zero(dq[:, 1]), dq[:, 1]),
            "fc1": lambda q, dq, a: (np.sign(dq[:, 0]), zero(dq[:, 0])),
            "fc2": lambda q, dq, a: (zero(dq[:, 1]), np.sign(dq[:, 1])),
        }
        for effect in self._effects:
            cols.update(effect.columns(self))
        return {name: cols[name] for name in self.names}

    # ------------------------------------------------------------------ structure for constraints
    @cached_property
    def mass_matrix_maps(self) -> tuple[np.ndarray, np.ndarray]:
        """(A0, A1), each (P, 2, 2): M(q) = Σ_p π_p (A0[p] + A1[p] cos q2) for every q.

        M is affine in π and depends on q only through cos q2, so M(q) ≻ 0 for all q exactly when
        M0 + M1 ≻ 0 and M0 − M1 ≻ 0 (the constrained fits use this).
        """
        s = self.symbols
        fM = ca.Function("M", [s["q"], s["pi"]], [s["M"]])
        P = self.n_params
        A0, A1 = np.zeros((P, 2, 2)), np.zeros((P, 2, 2))
        for p in range(P):
            e = np.zeros(P)
            e[p] = 1.0
            m_quarter = np.array(fM([0.0, np.pi / 2], e))  # cos q2 = 0
            m_zero = np.array(fM([0.0, 0.0], e))  # cos q2 = 1
            A0[p], A1[p] = m_quarter, m_zero - m_quarter
        return A0, A1

    def mass_matrix(self, pi: np.ndarray, q2: np.ndarray | float) -> np.ndarray:
        """M at joint-2 angles `q2` (any shape S) for parameters π: array (*S, 2, 2) [kg m²]."""
        A0, A1 = self.mass_matrix_maps
        M0, M1 = np.tensordot(pi, A0, 1), np.tensordot(pi, A1, 1)
        c2 = np.cos(np.asarray(q2, dtype=float))[..., None, None]
        return M0 + M1 * c2

    def mass_matrices(self, pi: np.ndarray, q: np.ndarray) -> np.ndarray:
        """M(q) (N, 2, 2) [kg m²] at configurations q (N, 2) [rad] (the `Arm` form of `mass_matrix`)."""
        return self.mass_matrix(pi, np.asarray(q, dtype=float)[..., 1])

    def mass_lmis(self) -> dict[str, np.ndarray]:
        """The two exact LMIs of M(q) ≻ 0 ∀q, as maps A (P, 2, 2) with Σ_p π_p A_p = M at cos q2 = +1
        ("mass_pd_q2_0") and at cos q2 = −1 ("mass_pd_q2_pi"): λ_min(M0 + c M1) is concave in c = cos q2,
        so its minimum over c ∈ [−1, 1] lies at an end."""
        A0, A1 = self.mass_matrix_maps
        return {"mass_pd_q2_0": A0 + A1, "mass_pd_q2_pi": A0 - A1}

    #: What `min_mass_eigenvalue` measures, as a table heading.
    consistency_measure = "min eig M(q) [kg m²]"

    def settings(self) -> dict:
        """The gravity vector's reading and the Stribeck velocities [rad/s]."""
        return {"gravity": self.gravity, "stribeck_velocity": list(self.stribeck_velocity)}

    def link_masses(self, pi: np.ndarray) -> dict[str, float]:
        """{}: the grouped π do not hold the links' masses (only their combinations with lengths and inertias)."""
        return {}

    def min_mass_eigenvalue(self, pi: np.ndarray) -> float:
        """min over all q of the smallest eigenvalue of M(q) [kg m²]: > 0 means physically consistent."""
        A0, A1 = self.mass_matrix_maps
        M0, M1 = np.tensordot(pi, A0, 1), np.tensordot(pi, A1, 1)
        # λ_min(M0 + c M1) is concave in c, so its minimum over c ∈ [−1, 1] lies at an end.
        return float(min(np.linalg.eigvalsh(M0 + M1)[0], np.linalg.eigvalsh(M0 - M1)[0]))


#: The paper's identification model (physically correct gravity vector).
RIGID = PlanarArm()
#: The nominal physical-convention structure: the datasheet read physically has a joint-2 armature ia2
#: (joint 1's is folded into a1). The simulator's truth, the physical datasheet model and the diagnosis'
#: nominal model all use it.
PHYSICAL = PlanarArm(("armature",))
#: The paper's printed gravity vector G1 = (β1 + β2) c1 + β2 c12, only to reproduce its Model 2.
PAPER = PlanarArm(gravity="paper")
