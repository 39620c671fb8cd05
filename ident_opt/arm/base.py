"""What the estimators, GMR, online identification, code generation and reports need from an arm.

An arm is a rigid-body torque model that is linear in its parameters π (P,):

    τ = M(q) ddq + C(q, dq) dq + G(q) + F(dq) = Y(q, dq, ddq) π          q, dq, ddq, τ ∈ Rⁿ (n joints)

`Arm` is that contract. The two-link closed form (`ident_opt.arm.planar.PlanarArm`, alias `TwoLinkArm`) is one
implementation; the rest of the package depends on this interface only, so another arm plugs in without
touching the estimators (`ident_opt.fitting`), GMR, online identification, code generation or reports.

How an n-joint arm from a URDF would implement it (a sketch for whoever adds it, e.g. with Pinocchio):

- `parameters`: the standard 10 per link, m, m c (3) and the inertia about the joint frame (6), each a
  `Parameter` with its kind (mass and principal moments "inertia"; first moments "gravity" and products
  of inertia "coupling", whose signs follow the geometry), plus per joint viscous and Coulomb friction
  ("friction") and a rotor armature ("armature"). The kinds decide the sign constraints
  (`ident_opt.consistency`); no name is matched.
- `regressor`: `pinocchio.computeJointTorqueRegressor(model, data, q, dq, ddq)` per sample (n, 10·links),
  with the friction and armature columns appended (dq_j, sign dq_j, ddq_j on row j).
- `symbols`, `function`, `tau_expression`: the same dynamics in CasADi (`pinocchio.casadi`), τ as an SX
  expression of q, dq, ddq and π, and Y its Jacobian with respect to π.
- `mass_lmis`: one 4×4 pseudo-inertia matrix per link, J(π_link) = [[½ tr(Ī) I − Ī, h], [hᵀ, m]] with
  Ī the inertia about the link frame and h = m c: J ≻ 0 for every link is the physical consistency of
  its 10 parameters, and makes M(q) positive definite for every q (sufficient there, where the two-link
  arm's two 2×2 LMIs are necessary and sufficient). Each is an affine map A (P, 4, 4), J = Σ_p π_p A_p.
- `min_mass_eigenvalue`: min over the LMIs of λ_min (or over sampled q of λ_min M(q)).
- `n_joints` = model.nv; arrays are (N, n) per sample, Y is (N, n, P), statistics G are (n, P, P).

Units: q [rad], dq [rad/s], ddq [rad/s²], τ [N m]; π in each parameter's own unit (`Parameter.unit`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol, runtime_checkable

import casadi as ca
import numpy as np

from ident_opt.parameters import Parameter


@runtime_checkable
class Arm(Protocol):
    """A rigid arm whose joint torques are linear in π: τ = Y(q, dq, ddq) π (module doc).

    Implementations are immutable and hashable (estimators cache per arm, e.g. the constrained fit's
    constraint matrix). Every array argument holds N samples: q, dq, ddq (N, n) [rad, rad/s, rad/s²].
    """

    @property
    def n_joints(self) -> int:
        """n, the number of joints (rows of Y per sample)."""
        ...

    @property
    def names(self) -> tuple[str, ...]:
        """Parameter names, in the order of π and of Y's columns."""
        ...

    @property
    def parameters(self) -> tuple[Parameter, ...]:
        """Each parameter's declaration (name, unit, meaning, kind), in the order of π."""
        ...

    @property
    def n_params(self) -> int:
        """P, the number of parameters."""
        ...

    @property
    def symbols(self) -> dict[str, ca.SX]:
        """CasADi symbols q, dq, ddq (n×1), pi (P×1) and the expressions M, C, G, F, tau, Y built from them."""
        ...

    def vector(self, pi: Mapping[str, float]) -> np.ndarray:
        """π (P,) in this arm's order from a name → value mapping (missing names: the arm's default, 0)."""
        ...

    def as_dict(self, pi: np.ndarray) -> dict[str, float]:
        """π (P,) to a name → value dict."""
        ...

    def regressor(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Y (N, n, P) with τ[k] = Y[k] @ π [N m]."""
        ...

    @property
    def drive_matrix(self) -> np.ndarray:
        """C (n, n): drive m turns at C[m] · dq [rad/s, joint side] and its friction reaches joint j as C[m, j] × it;
        the identity where each drive turns its own joint only (a coupled wrist's motor adds off-diagonal terms)."""
        ...

    def predict(self, pi: np.ndarray, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """τ (N, n) [N m] for parameters π."""
        ...

    def function(self, what: str) -> ca.Function:
        """A CasADi Function of (q, dq, ddq, pi) for one of "M", "C", "G", "F", "tau", "Y"."""
        ...

    def tau_expression(self, q, dq, ddq, pi):
        """τ (n×1) as a CasADi expression of any (symbolic or numeric) q, dq, ddq (n×1) and π (P×1)."""
        ...

    def mass_lmis(self) -> dict[str, np.ndarray]:
        """Named affine matrix maps A (P, k, k): Σ_p π_p A_p ⪰ margin·I for each of them is the arm's
        statement that M(q) ≻ 0 (two-link: two exact 2×2 LMIs at cos q2 = ±1; URDF: one 4×4 pseudo-inertia
        per link). The names are the constraints' names in every output."""
        ...

    def mass_matrices(self, pi: np.ndarray, q: np.ndarray) -> np.ndarray:
        """M(q) (N, n, n) [kg m²] at configurations q (N, n) for parameters π."""
        ...

    def min_mass_eigenvalue(self, pi: np.ndarray) -> float:
        """min over all q of λ_min(M(q)) [kg m²] (or the arm's best lower bound): > 0 means consistent."""
        ...

    #: What `min_mass_eigenvalue` measures, as a table heading.
    consistency_measure: str

    @property
    def extensions(self) -> tuple[str, ...]:
        """The model extensions (`ident_opt.effects`) this model has, in catalogue order."""
        ...

    def link_masses(self, pi: np.ndarray) -> dict[str, float]:
        """Each link's mass [kg] at π, by name, where π holds them ({} for grouped parameters, which do not)."""
        ...

    def settings(self) -> dict:
        """What defines the model besides π and its extensions, JSON-ready (saved with generated code)."""
        ...


def symbol_table(q, dq, ddq, pi, M, C, G, F, tau=None) -> dict[str, ca.SX]:
    """An arm's `symbols`: the inputs q, dq, ddq (n×1) and pi (P×1), M, C, G, F, tau (default
    M ddq + C dq + G + F; an arm with its own expression of τ passes it) and the regressor Y = ∂τ/∂π —
    one home for what every implementation returns."""
    tau = M @ ddq + C @ dq + G + F if tau is None else tau
    return {
        "q": q,
        "dq": dq,
        "ddq": ddq,
        "pi": pi,
        "M": M,
        "C": C,
        "G": G,
        "F": F,
        "tau": tau,
        "Y": ca.jacobian(tau, pi),
    }


def casadi_function(symbols: Mapping[str, ca.SX], what: str) -> ca.Function:
    """A CasADi Function of (q, dq, ddq, pi) for one of an arm's symbols (M, C, G, F, tau, Y)."""
    s = symbols
    return ca.Function(what, [s["q"], s["dq"], s["ddq"], s["pi"]], [s[what]], ["q", "dq", "ddq", "pi"], [what])


#: The subcommands of `ident-opt`, each of which an arm serves or not (`Robot.serves`).
ALL_COMMANDS = (
    "identify",
    "compare",
    "diagnose",
    "simulate",
    "codegen",
    "online",
    "check",
    "audit",
    "excite",
    "calibrate",
    "export",
    "fleet",
    "detect",
)


@runtime_checkable
class Robot(Protocol):
    """An arm as a problem's `[robot]` describes it: its joints and their nominal drive values, the model it is
    identified with (`model`, an `Arm`), its nominal parameters (`datasheets`), and what it serves.

    Implementations: `ident_opt.arm.datasheet.PlanarRobot` (the planar two-link arm: a datasheet of bars and
    motors or measured inertials; `ident_opt.arm.planar_urdf.UrdfPlanarRobot` from a URDF) and
    `ident_opt.arm.chain.ChainRobot` (an n-joint chain from a URDF). Nothing outside `ident_opt.arm` asks which
    one it has: it asks the robot.
    """

    @property
    def n_joints(self) -> int:
        """n, the number of joints."""
        ...

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The joints' names, base to tip (the URDF's, or joint1, joint2)."""
        ...

    @property
    def joints(self) -> tuple:
        """Each joint's nominal drive values (friction, rotor inertia, `current_to_torque`), base to tip."""
        ...

    @property
    def joint_tables(self) -> tuple[str, ...]:
        """The problem file's table of each joint's values: [robot.<this>] (joint1, …, or the URDF's names)."""
        ...

    #: The `ident-opt` commands that serve this arm (a subset of `ALL_COMMANDS`).
    serves: frozenset[str]
    #: The fits `compare` runs for it, in report order (names of `ident_opt.fitting.estimators`).
    estimators: tuple[str, ...]
    #: The fit used downstream (`identify`'s consistent model, `codegen`, `export`) unless told otherwise.
    default_estimator: str
    #: What q, dq, ddq, τ mean for this arm (zero, sign, order), in a paragraph for READMEs and reports.
    angle_convention: str
    #: The arm in a few words, for sentences ("a 7-joint URDF arm").
    described_as: str
    #: Whether the paper's own views apply (its shuffled protocol, its tables): the planar two-link arm's.
    paper_views: bool
    #: Which kind of arm it is, for the features with one implementation per kind (the simulator's plant, the
    #: diagnosis's engine): "planar" (the two-link closed form, tuned on the MERIt trials: grouped π, flexible
    #: links, the paper's trajectories) or "chain" (n joints from a URDF, through `Arm` and `Robot` alone). Read by
    #: `arm.kinds.ByKind.of` only: nothing else asks.
    kind: str

    @property
    def column_map(self) -> Mapping[str, tuple[float, float]]:
        """Data column → (scale, offset) from the data's convention to the tool's (empty when they agree)."""
        ...

    @property
    def statement(self) -> tuple[str, ...]:
        """Lines saying what the tool applied to read this robot (offsets, signs, defaults it took); may be ()."""
        ...

    @property
    def datasheet(self) -> str:
        """The key of `datasheets()` that is this problem's own nominal model."""
        ...

    @property
    def model_note(self) -> str | None:
        """Why the default model (`model()`) adds terms to the plain rigid one, or None."""
        ...

    #: The model extensions (`ident_opt.effects`) `model` can add for this arm.
    extensions: tuple[str, ...]

    def fit_options(self, estimator: str) -> dict:
        """What estimator `estimator` takes from this description (a datasheet, a prior), as keyword options."""
        ...

    def model(self, extensions: tuple[str, ...] | None = None) -> Arm:
        """The identification model, with `extensions` (`ident_opt.effects`) or by default the robot's own."""
        ...

    def datasheets(self) -> dict[str, tuple[Arm, np.ndarray]]:
        """The nominal parameter sets (datasheet, URDF/CAD) by name, each with the arm it is evaluated with."""
        ...

    def bodies(self, arm: Arm, pi: np.ndarray, **options):
        """π of `arm` realised as rigid bodies (`ident_opt.arm.bodies.RobotDescription`, `ident_opt.arm.realise`):
        what `ident-opt export` writes."""
        ...

    def reference(self, parameters: Mapping[str, float]) -> tuple[Arm, np.ndarray]:
        """A published identification's parameters by name as (arm, π); an unknown name is an InputError."""
        ...

    def reference_urdf(self, urdf) -> dict[str, float]:
        """A published identification given as a URDF of the same arm, as this arm's parameters by name
        (InputError when the arm's parameters cannot be read from one)."""
        ...

    def limits(self) -> dict[str, tuple[float | None, ...]]:
        """Defaults for `[limits]` from the description (a URDF's <limit>): key → one value per joint."""
        ...

    def tool_directions(self, arm: Arm) -> np.ndarray:
        """(P, r): the directions π of `arm` moves along when a rigid body (a tool, a payload) is fixed to the last
        link: any such body changes π by a combination of these columns (`ident-opt fleet` names a payload so)."""
        ...

    def payload(self, arm: Arm, mass: float, at: tuple[float, ...] | None = None) -> np.ndarray:
        """Δπ (P,) of `arm` for a point mass `mass` [kg] fixed to the last link at `at` [m] in that link's frame
        (None: the arm's own tool point); a combination of `tool_directions`."""
        ...

    def summary(self) -> dict:
        """A JSON-ready description (`ident-opt check --json`, key "robot")."""
        ...

    @property
    def headline(self) -> str:
        """The arm in one line ("7-joint arm from the URDF …")."""
        ...

    def describe(self) -> list[str]:
        """Lines for people: the joints, gravity, the model's parameters, what the tool applied (`statement`)."""
        ...
