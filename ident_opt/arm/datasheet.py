"""From a datasheet (`[robot]`) to rigid-body parameters and the paper's grouped parameters π.

Both conventions model each link as a uniform bar (I = m (h² + l²)/12 about its centre, centre at
mid-length), lump an actuator as a solid cylinder (I = m r²/2) at the distal end of link 1, and move
inertias to the combined centre of mass with the parallel-axis theorem. They differ in what a
mechanical engineer would call right (see `docs/problem-files.md`, "From the datasheet to π: the two
conventions"):

- ``paper``: joint 1's actuator on link 1, motor-side friction averaged and used as is, no rotor inertia.
- ``physical``: joint 2's actuator on link 1 (joint 1's motor sits on the base); friction reflected to the
  joint (viscous × N², Coulomb × N); rotor inertia reflected as armature N² J on the diagonal of M.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ident_opt.arm.base import ALL_COMMANDS
from ident_opt.arm.bodies import RobotDescription
from ident_opt.arm.joints import Friction, JointSide
from ident_opt.arm.planar import ANGLE_CONVENTION, EXTENSIONS, PAPER, PHYSICAL, RIGID, PlanarArm
from ident_opt.arm.realise_planar import planar_bodies
from ident_opt.errors import InputError


@dataclass(frozen=True)
class Link:
    """A link modelled as a uniform rectangular bar [m, kg/m^3]."""

    length: float
    width: float
    height: float
    density: float

    @property
    def mass(self) -> float:
        """Bar mass [kg]."""
        return self.density * self.length * self.width * self.height


@dataclass(frozen=True)
class Joint:
    """One actuator's datasheet: motor-side friction and rotor inertia, gear ratio N, torque constant."""

    torque_constant: float  # N m / A, motor side
    gear_ratio: float
    rotor_inertia: float  # kg m^2, motor side
    viscous_friction: Friction  # N m s / rad, motor side
    coulomb_friction: Friction  # N m, motor side
    motor_diameter: float  # m
    actuator_mass: float  # kg

    @property
    def current_to_torque(self) -> float:
        """Joint-side torque per ampere of motor current [N m / A]: torque constant × gear ratio."""
        return self.torque_constant * self.gear_ratio


@dataclass(frozen=True)
class InertialLink:
    """A link given by its measured or CAD inertials: `length` [m] (joint axis to the next axis or the tip),
    `mass` [kg] (everything it carries included), `com` [m] (along the link from its own joint axis) and
    `inertia` [kg m²] (about the centre of mass, around the joint axis)."""

    length: float
    mass: float
    com: float
    inertia: float


@dataclass(frozen=True)
class PlanarRobot:
    """The `[robot]` section: a two-link planar arm under gravity, as bars and cylinders (`description`
    "bars": a datasheet, motor-side friction and rotor inertia) or as measured inertials ("inertials":
    joint-side values)."""

    gravity: float
    convention: str  # "physical" or "paper"
    link1: Link | InertialLink
    link2: Link | InertialLink
    joint1: Joint | JointSide
    joint2: Joint | JointSide
    payload_mass: float = 0.0
    description: str = "bars"
    #: The most the arm is specified to carry [kg] (`[robot] rated_payload`); None: not given.
    rated_payload: float | None = None

    @property
    def joints(self) -> tuple[Joint | JointSide, ...]:
        """The joints, in order."""
        return (self.joint1, self.joint2)

    @property
    def n_joints(self) -> int:
        """n = 2 joints."""
        return 2

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The joints' names in reports: joint1, joint2."""
        return ("joint1", "joint2")

    #: Each joint's values are in [robot.joint1] and [robot.joint2] (also for an arm from a URDF).
    joint_tables = ("joint1", "joint2")
    #: The URDF the robot was read from (`ident_opt.arm.planar_urdf.UrdfPlanarRobot`), or None for a datasheet.
    urdf = None
    #: The map from the data's angles to the tool's, q_tool = sign · q + offset [rad] per joint: none here.
    angle_signs = (1.0, 1.0)
    angle_offsets = (0.0, 0.0)

    @property
    def nominal_masses(self) -> tuple[float, float]:
        """(m1, m2) [kg]: the links' masses the datasheet gives (`rigid_body`), which the grouped π do not."""
        body = rigid_body(self)
        return body.m1, body.m2

    def bodies(self, arm: PlanarArm, pi: np.ndarray, **options) -> RobotDescription:
        """The grouped π of `arm` realised exactly as rigid bodies (`ident_opt.arm.realise.planar_bodies`)."""
        return planar_bodies(self, arm, pi, **options)

    # ------------------------------------------------------------------ the `Robot` interface
    #: Every command serves the planar two-link arm (the paper's own views included).
    serves = frozenset(ALL_COMMANDS)
    #: The fits `compare` runs, in report order (`ident_opt.fitting.estimators`).
    estimators = ("ols", "constrained", "nlp_physical", "robust")
    #: The fit used downstream unless told otherwise.
    default_estimator = "constrained"
    #: The simulator and the diagnosis that serve it: the planar two-link arm's own, tuned on the MERIt trials
    #: (its datasheet conventions, flexible links, trajectories and candidate models in grouped parameters).
    kind = "planar"
    angle_convention = ANGLE_CONVENTION
    described_as = "a planar two-link arm"
    paper_views = True

    @property
    def column_map(self) -> dict[str, tuple[float, float]]:
        """Data column → (scale, offset) to the tool's convention: none (the data are in it already)."""
        return {}

    @property
    def statement(self) -> tuple[str, ...]:
        """What the tool applied to read this robot: nothing."""
        return ()

    @property
    def datasheet(self) -> str:
        """The key of `datasheets()` that is this problem's own reading (its `convention`)."""
        return self.convention

    #: The model extensions `model` can add: every one of the catalogue's.
    extensions = tuple(EXTENSIONS)

    def fit_options(self, estimator: str) -> dict:
        """The NLP on physical parameters starts from, and is pulled toward, this datasheet."""
        return {"robot": self} if estimator == "nlp_physical" else {}

    def model(self, extensions: tuple[str, ...] | None = None) -> PlanarArm:
        """The identification model: the grouped π with `extensions` (`ident_opt.effects`), by default the
        rigid model, plus `armature` for a robot given by its inertials with a rotor inertia behind a gear
        (`model_note` says why)."""
        if extensions is not None:
            return PlanarArm(tuple(extensions))
        return PlanarArm(("armature",)) if self.model_note else RIGID

    @property
    def model_note(self) -> str | None:
        """Why the default model is not the plain rigid one, or None: a robot described by its inertials with a
        reflected rotor inertia on a joint carries it on the diagonal of M, so the model frees it (armature,
        ia2 apart from α1) instead of folding a wrong fixed value into the other parameters."""
        if self.description == "inertials" and any(j.rotor_inertia > 0 for j in self.joints):
            return "armature, as the robot states a rotor inertia behind a gear"
        return None

    def rigid_body(self, convention: str | None = None) -> RigidBody:
        """The rigid body the datasheet describes, read under `convention` ("paper" or "physical"; `rigid_body`)."""
        return rigid_body(self, convention)

    def grouped(self, convention: str | None = None) -> dict[str, float]:
        """The datasheet's grouped π by name under `convention` (`datasheet_pi`)."""
        return datasheet_pi(self, convention)

    def datasheets(self) -> dict[str, tuple[PlanarArm, np.ndarray]]:
        """The datasheet read both ways, each with the arm it is evaluated with: "paper" (its printed gravity
        vector, the paper's Model 2) and "physical" (a joint-2 armature, reflected friction)."""
        return {
            convention: (arm, arm.vector(datasheet_pi(self, convention)))
            for convention, arm in (("paper", PAPER), ("physical", PHYSICAL))
        }

    def reference(self, parameters: dict[str, float]) -> tuple[PlanarArm, np.ndarray]:
        """A published identification in the grouped parameters as (arm, π): the armature extension when it
        names ia2; an unknown name is an InputError naming it."""
        arm = PlanarArm(("armature",)) if "ia2" in parameters else RIGID
        unknown = [k for k in parameters if k not in arm.names]
        if unknown:
            raise InputError(f"[reference.parameters]: unknown parameter '{unknown[0]}'; known: {', '.join(arm.names)}")
        return arm, arm.vector(parameters)

    def reference_urdf(self, urdf) -> dict[str, float]:
        """A URDF reference: refused, the planar arm's parameters are grouped (a1, a2, …), not per link."""
        raise InputError(
            "a URDF reference needs an arm with n joints from a URDF, and this problem's robot is "
            f"{self.described_as}, whose parameters are grouped (a1, a2, …); give them by name in "
            "[reference.parameters]"
        )

    def limits(self) -> dict[str, tuple[float, ...]]:
        """Defaults of `[limits]` the description gives: none."""
        return {}

    def tool_directions(self, arm: PlanarArm) -> np.ndarray:
        """(P, 3): how the grouped π of `arm` moves per unit of a rigid body fixed to link 2 — its mass m [kg], its
        first moment m x along the link about joint 2 [kg m] and its inertia J about joint 2 [kg m²]: α1 gains
        m l1² + J, α2 gains l1 m x, α3 gains J, β1 gains g l1 m, β2 gains g m x (`grouped`; under the paper's
        printed gravity, β1 = its physical value − β2)."""
        l1, g = self.link1.length, self.gravity
        paper = -g if arm.gravity == "paper" else 0.0
        per_unit = ({"a1": l1**2, "b1": g * l1}, {"a2": l1, "b2": g, "b1": paper}, {"a1": 1.0, "a3": 1.0})
        return np.column_stack([arm.vector(d) for d in per_unit])

    def payload(self, arm: PlanarArm, mass: float, at: tuple[float, ...] | None = None) -> np.ndarray:
        """Δπ (P,) for a point mass `mass` [kg] on link 2 at `at` = (x,) [m] along the link from joint 2 (None: its
        tip, where `[robot.payload]` puts one); the grouped model has no offset across the link."""
        x, *across = at if at is not None else (self.link2.length,)
        if any(across):
            raise ValueError("a planar two-link arm's payload sits on the line of link 2: give at = (x,)")
        return self.tool_directions(arm) @ np.array([mass, mass * x, mass * x**2])

    def summary(self) -> dict:
        """What `ident-opt check --json` says of the robot (key "robot")."""
        return {"form": "planar two-link", "description": self.description, "convention": self.convention}

    @property
    def headline(self) -> str:
        """The arm in one line."""
        how = {"bars": "bars and motors", "inertials": "measured inertials"}.get(self.description, self.description)
        return f"planar two-link arm ({how}), datasheet convention {self.convention!r}"

    def describe(self) -> list[str]:
        """The model's parameters and what the tool applied to read the robot."""
        arm = self.model()
        lines = [f"  parameters: {arm.n_params} grouped ({', '.join(arm.names)})"]
        if self.model_note:
            lines.append(f"  model: rigid + {self.model_note}")
        return lines + [f"  {line}" for line in self.statement]


@dataclass(frozen=True)
class RigidBody:
    """Joint-side rigid-body parameters of the two-link arm [kg, m, kg m², N m s/rad, N m]."""

    m1: float
    m2: float
    l1: float
    l2: float
    lc1: float
    lc2: float
    Ic1: float
    Ic2: float
    gravity: float
    armature: tuple[float, float]  # reflected rotor inertia N² J per joint (0 under the paper convention)
    fv: tuple[float, float]  # viscous friction, averaged over directions
    fc: tuple[float, float]  # Coulomb friction, averaged over directions
    fc_positive: tuple[float, float]
    fc_negative: tuple[float, float]


def bar_inertia(link: Link) -> float:
    """Moment of inertia of a uniform bar about its centre, for rotation in the plane of motion [kg m²]."""
    return link.mass * (link.height**2 + link.length**2) / 12.0


def cylinder_inertia(mass: float, diameter: float) -> float:
    """Moment of inertia of a solid cylinder about its axis [kg m²]."""
    return 0.5 * mass * (diameter / 2.0) ** 2


def combine(parts: list[tuple[float, float, float]]) -> tuple[float, float, float]:
    """Lump point-like parts (mass, position along the link, inertia about own centre) into one body.

    Returns (mass, centre of mass, inertia about that centre) by the parallel-axis theorem.
    """
    mass = sum(m for m, _, _ in parts)
    com = sum(m * x for m, x, _ in parts) / mass
    inertia = sum(i + m * (x - com) ** 2 for m, x, i in parts)
    return mass, com, inertia


def rigid_body(robot: PlanarRobot, convention: str | None = None) -> RigidBody:
    """Rigid-body parameters from the datasheet under `convention` (default: the robot's own); a robot
    given by measured inertials is read as it is (joint-side values; the conventions concern bars)."""
    convention = convention or robot.convention
    if convention not in ("paper", "physical"):
        raise ValueError(f"unknown convention {convention!r}")
    if robot.description == "inertials":
        return _from_inertials(robot)
    l1, l2 = robot.link1.length, robot.link2.length
    # Which actuator rides at the distal end of link 1 is the paper's main slip (see module docstring).
    rider = robot.joint1 if convention == "paper" else robot.joint2
    m1, lc1, Ic1 = combine(
        [
            (robot.link1.mass, l1 / 2, bar_inertia(robot.link1)),
            (rider.actuator_mass, l1, cylinder_inertia(rider.actuator_mass, rider.motor_diameter)),
        ]
    )
    link2 = [(robot.link2.mass, l2 / 2, bar_inertia(robot.link2))]
    if robot.payload_mass > 0:
        link2.append((robot.payload_mass, l2, 0.0))
    m2, lc2, Ic2 = combine(link2)

    joints = robot.joints
    if convention == "paper":
        armature = (0.0, 0.0)
        fv = tuple(j.viscous_friction.mean for j in joints)
        fc_pos = tuple(j.coulomb_friction.positive for j in joints)
        fc_neg = tuple(j.coulomb_friction.negative for j in joints)
    else:
        armature = tuple(j.gear_ratio**2 * j.rotor_inertia for j in joints)
        fv = tuple(j.gear_ratio**2 * j.viscous_friction.mean for j in joints)
        fc_pos = tuple(j.gear_ratio * j.coulomb_friction.positive for j in joints)
        fc_neg = tuple(j.gear_ratio * j.coulomb_friction.negative for j in joints)
    fc = tuple(0.5 * (p + n) for p, n in zip(fc_pos, fc_neg))
    return RigidBody(m1, m2, l1, l2, lc1, lc2, Ic1, Ic2, robot.gravity, armature, fv, fc, fc_pos, fc_neg)


def _from_inertials(robot: PlanarRobot) -> RigidBody:
    """Rigid-body parameters of a robot given by measured inertials (`[robot.linkN]` mass, com, inertia about
    the centre of mass; `[robot.jointN]` joint-side friction and reflected rotor inertia); a payload is a point
    mass at the tip of link 2."""
    l1, l2 = robot.link1.length, robot.link2.length
    m1, lc1, Ic1 = robot.link1.mass, robot.link1.com, robot.link1.inertia
    m2, lc2, Ic2 = robot.link2.mass, robot.link2.com, robot.link2.inertia
    if robot.payload_mass > 0:
        m2, lc2, Ic2 = combine([(m2, lc2, Ic2), (robot.payload_mass, l2, 0.0)])
    joints = robot.joints
    fc_pos = tuple(j.coulomb_friction.positive for j in joints)
    fc_neg = tuple(j.coulomb_friction.negative for j in joints)
    return RigidBody(
        m1,
        m2,
        l1,
        l2,
        lc1,
        lc2,
        Ic1,
        Ic2,
        robot.gravity,
        tuple(j.rotor_inertia for j in joints),
        tuple(j.viscous_friction.mean for j in joints),
        tuple(0.5 * (p + n) for p, n in zip(fc_pos, fc_neg)),
        fc_pos,
        fc_neg,
    )


def grouped(m1, m2, l1, lc1, lc2, Ic1, Ic2, g):
    """The paper's grouped inertial and gravity parameters (α1, α2, α3, β1, β2), β in N·m.

    Plain arithmetic, so it also works on CasADi symbols (used by the physical-parameter NLP).
    """
    a1 = Ic1 + Ic2 + m1 * lc1**2 + m2 * (l1**2 + lc2**2)
    a2 = m2 * l1 * lc2
    a3 = Ic2 + m2 * lc2**2
    b1 = (m1 * lc1 + m2 * l1) * g
    b2 = m2 * lc2 * g
    return a1, a2, a3, b1, b2


def datasheet_pi(robot: PlanarRobot, convention: str | None = None) -> dict[str, float]:
    """The datasheet's π by name. Under ``physical`` the joint-1 armature is folded into ``a1``
    (it cannot be told apart from it) and the joint-2 armature is reported as ``ia2``."""
    convention = convention or robot.convention
    body = rigid_body(robot, convention)
    a1, a2, a3, b1, b2 = grouped(body.m1, body.m2, body.l1, body.lc1, body.lc2, body.Ic1, body.Ic2, body.gravity)
    pi = {
        "a1": a1 + body.armature[0],
        "a2": a2,
        "a3": a3,
        "b1": b1,
        "b2": b2,
        "fv1": body.fv[0],
        "fv2": body.fv[1],
        "fc1": body.fc[0],
        "fc2": body.fc[1],
    }
    if convention == "physical":
        pi["ia2"] = body.armature[1]
    return pi


def pi_vector(pi: dict[str, float], names: tuple[str, ...]) -> np.ndarray:
    """π as a vector in the order `names`; names the dict lacks (extensions) are 0."""
    return np.array([pi.get(name, 0.0) for name in names], dtype=float)
