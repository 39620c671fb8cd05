"""An arm of n revolute joints from a URDF as a problem's `[robot]` describes it (`ChainRobot`): the file, its joints
and their nominal drive values, gravity, couplings, the plausible fit's prior; its model is a `chain.ChainArm`."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import pinocchio as pin

from ident_opt.arm.bodies import RobotDescription
from ident_opt.arm.chain import ChainArm
from ident_opt.arm.joints import JointSide
from ident_opt.arm.realise import chain_bodies
from ident_opt.arm.rnea import N_LINK
from ident_opt.arm.urdf import parse_urdf
from ident_opt.errors import InputError
from ident_opt.outputs import shown


@dataclass(frozen=True)
class ChainRobot:
    """An n-joint arm from a URDF, as a problem's `[robot]` describes it (`ident_opt.problem.urdf`): the file,
    its revolute joints base to tip (`joint_names`), gravity (3,) [m/s²] in the base frame, the model's joint
    terms, each drive's nominal values (`joints`: joint-side friction, reflected rotor inertia, and the torque
    constant and gear ratio that turn currents into torques), couplings, and the plausible fit's prior (its
    weight, the links' mass range and centre-of-mass box)."""

    urdf: Path
    joint_names: tuple[str, ...]
    gravity: tuple[float, float, float]
    joints: tuple[JointSide, ...]
    base: str | None = None
    friction: bool = True
    armature: bool = True
    offsets: bool = False
    prior_weight: float = 1e-7
    mass_range: float | None = 0.5
    com_box: float | None = 0.1
    couplings: tuple[tuple[str, str, float], ...] = ()
    notes: tuple[str, ...] = field(default=(), compare=False)
    #: The most the arm is specified to carry [kg] (`[robot] rated_payload`); None: not given.
    rated_payload: float | None = None
    description: str = "urdf"

    @property
    def n_joints(self) -> int:
        """n, the number of joints."""
        return len(self.joint_names)

    @property
    def joint_tables(self) -> tuple[str, ...]:
        """Each joint's values are in [robot.<its URDF name>]."""
        return self.joint_names

    # ------------------------------------------------------------------ the `Robot` interface
    #: The commands that serve an n-joint arm.
    serves = frozenset(
        (
            "identify",
            "compare",
            "codegen",
            "check",
            "export",
            "fleet",
            "online",
            "excite",
            "simulate",
            "diagnose",
            "detect",
        )
    )
    #: The fits `compare` runs, in report order: OLS on the base parameters, consistent without and with the
    #: URDF as a prior (`ident_opt.fitting.estimators`).
    estimators = ("ols", "constrained", "consistent", "robust")
    #: The fit used downstream unless told otherwise: consistent and plausible.
    default_estimator = "consistent"
    #: The simulator and the diagnosis that serve it: those of any arm, through the `Arm` interface alone.
    kind = "chain"
    model_note = None
    paper_views = False
    #: The nominal model's key in `datasheets()`.
    datasheet = "urdf"

    @property
    def described_as(self) -> str:
        """ "a 7-joint URDF arm"; a two-joint one says why it is not the planar arm."""
        why = ' on the n-joint path (its axes are not parallel, or form = "n-joint")' if self.n_joints == 2 else ""
        return f"a {self.n_joints}-joint URDF arm{why}"

    @property
    def angle_convention(self) -> str:
        """q_j is the URDF joint's own position, in the `joint_names` order."""
        return (
            f"q1 … q{self.n_joints} are the positions of the URDF's joints {', '.join(self.joint_names)} (in that "
            "order), as the URDF defines them: zero at each joint's <origin>, positive about its <axis>; tau_j is the "
            "torque about that axis; gravity as the problem file gives it, in the base frame."
        )

    @property
    def column_map(self) -> dict[str, tuple[float, float]]:
        """Data column → (scale, offset) to the tool's convention: none (a URDF arm's data are in its own)."""
        return {}

    @property
    def statement(self) -> tuple[str, ...]:
        """What the tool read from the URDF and the problem file, and what the nominal model lacks."""
        lines = [
            f"robot from the URDF {shown(self.urdf)}: {self.n_joints} joints ({', '.join(self.joint_names)})",
            *(f"  {note}" for note in self.notes),
        ]
        bare = [
            name
            for name, j in zip(self.joint_names, self.joints)
            if not (j.viscous_friction.mean or j.coulomb_friction.mean)
        ]
        if bare:
            lines.append(
                f"  no nominal friction for {', '.join(bare)} (no <dynamics> and no [robot.<joint>] values): the "
                "nominal model has none there"
            )
        return tuple(lines)

    #: Model extensions: none yet on an n-joint arm (its joint terms are set in [robot]).
    extensions = ()

    def fit_options(self, estimator: str) -> dict:
        """The plausible consistent fit's prior: its weight, the links' mass range and centre-of-mass box."""
        if estimator != "consistent":
            return {}
        return {"prior_weight": self.prior_weight, "mass_range": self.mass_range, "com_box": self.com_box}

    def model(self, extensions: tuple[str, ...] | None = None) -> ChainArm:
        """The identification model: the chain with its joint terms. Model extensions are the planar arm's
        only, for now: asking for one is an InputError naming it."""
        if extensions:
            raise InputError(
                f"{shown(self.urdf)}: model extensions ({', '.join(extensions)}) are available for the planar "
                "two-link arm only; an n-joint arm's model has its joint terms (friction, armature, offsets in [robot])"
            )
        return self.arm

    def bodies(self, arm: ChainArm, pi: np.ndarray, **options) -> RobotDescription:
        """π of the arm realised as rigid bodies, one per link (`ident_opt.arm.realise.chain_bodies`)."""
        if arm != self.arm:
            raise ValueError("an n-joint arm is realised with its own model, robot.arm")
        return chain_bodies(self, pi, **options)

    def datasheets(self) -> dict[str, tuple[ChainArm, np.ndarray]]:
        """The nominal model: the URDF's inertials with each joint's nominal friction and armature."""
        return {"urdf": (self.arm, self.nominal_parameters())}

    def reference(self, parameters: Mapping[str, float]) -> tuple[ChainArm, np.ndarray]:
        """A published identification in the standard parameters by name (`m_<link>`, `fv_<joint>`, …) as
        (arm, π); names it lacks are 0; an unknown name is an InputError naming it."""
        unknown = [k for k in parameters if k not in self.arm.names]
        if unknown:
            raise InputError(
                f"[reference.parameters]: unknown parameter '{unknown[0]}' for the arm of {shown(self.urdf)} "
                f"(its names: {', '.join(self.arm.names[:3])}, …: m_, mx_, my_, mz_, ixx_ … izz_<link> and "
                f"{', '.join(t + '_<joint>' for t in self.arm.joint_terms)})"
            )
        return self.arm, self.arm.vector(parameters)

    def reference_urdf(self, urdf: Path) -> dict[str, float]:
        """A published identification given as a URDF of the same arm, as this arm's standard parameters by name.
        Link k's inertials (as Pinocchio merges them into its frame: m [kg], m c [kg m], the inertia about the
        frame's origin [kg m²]) are this arm's link k's, whatever the reference calls it; each joint's <dynamics>
        damping and friction are fv_<joint> [N m s/rad] and fc_<joint> [N m] (0 left out). The file must have
        this arm's joints, by name, as one serial chain (an InputError naming the file otherwise)."""
        model = self.arm
        _, _, links = parse_urdf(Path(urdf))
        base = self.base if self.base in links else None  # the same arm may call its base otherwise
        arm = ChainArm(str(urdf), self.joint_names, self.gravity, base)
        count = model.n_link_params  # link parameters come first, link by link, in both arms
        parameters = dict(zip(model.names[:count], map(float, arm.cad_parameters()[:count])))
        for name in self.joint_names:
            for prefix, attribute in (("fv", "damping"), ("fc", "friction")):
                value = getattr(arm.urdf_joints[name], attribute)
                if not value:
                    continue
                if f"{prefix}_{name}" not in model.names:
                    raise InputError(
                        f"<joint name={name!r}> has <dynamics {attribute}={value:g}>, but the problem's model has no "
                        "friction terms ([robot] friction = false); set friction = true to compare with it"
                    )
                parameters[f"{prefix}_{name}"] = float(value)
        return parameters

    def limits(self) -> dict[str, tuple[float | None, ...]]:
        """`[limits]` defaults from each joint's URDF <limit>: position_min/max [rad] (lower, upper), velocity
        [rad/s], torque [N m] (effort); None for a joint whose <limit> lacks the value, a key absent when no
        joint has it."""
        parsed = self.arm.urdf_joints
        keys = {"position_min": "lower", "position_max": "upper", "velocity": "velocity", "torque": "effort"}
        out = {}
        for key, attribute in keys.items():
            values = tuple(parsed[name].limit.get(attribute) for name in self.joint_names)
            if any(v is not None for v in values):
                out[key] = values
        return out

    def tool_directions(self, arm: ChainArm) -> np.ndarray:
        """(P, 10): a body fixed to the last link moves that link's 10 standard parameters (unit columns)."""
        start = arm.n_link_params - N_LINK
        return np.eye(arm.n_params)[:, start : start + N_LINK]

    def payload(self, arm: ChainArm, mass: float, at: tuple[float, ...] | None = None) -> np.ndarray:
        """Δπ (P,) for a point mass `mass` [kg] at `at` (3,) [m] in the last link's frame (None: at the last link's
        centre of mass in the URDF): m, m c and m (|c|² 1 − c cᵀ) added to that link's parameters."""
        c = np.asarray(at, dtype=float) if at is not None else arm._model.inertias[arm.n_joints].lever.copy()
        point = pin.Inertia(float(mass), c, np.zeros((3, 3))).toDynamicParameters()
        return self.tool_directions(arm) @ point

    @property
    def headline(self) -> str:
        """The arm in one line."""
        return f"{self.n_joints}-joint arm from the URDF {shown(self.urdf)}"

    def describe(self) -> list[str]:
        """The joints, gravity, the model's parameters, the URDF's mass, couplings and the statement's notes."""
        arm, info = self.arm, self.summary()
        mass = (
            f"{info['urdf_mass_kg']:.3f} kg"
            if info["urdf_mass_kg"] is not None
            else f"unknown: no <inertial> on {', '.join(info['missing_inertials'])}"
        )
        terms = ", ".join(arm.joint_terms) or "none"
        lines = [
            f"  joints: {', '.join(self.joint_names)}",
            f"  gravity [m/s²]: ({', '.join(f'{g:g}' for g in self.gravity)})",
            f"  parameters: {arm.n_params} standard ({N_LINK} per link, joint terms: {terms})",
            f"  URDF mass of the moving links: {mass}",
        ]
        lines += [f"  coupling: drive {a} also acts on {b} (ratio {r:g})" for a, b, r in self.couplings]
        return lines + list(self.statement[1:])

    def summary(self) -> dict:
        """What `ident-opt check --json` says of the robot (key "robot"): the URDF, its joints and moving links,
        gravity [m/s²], the joint terms, couplings, the number of parameters, the URDF's total mass [kg] (None
        when a link has no <inertial>, which `missing_inertials` names)."""
        arm = self.arm
        mass = None if arm.missing_inertials else sum(arm.link_masses(arm.cad_parameters()).values())
        return {
            "form": "n-joint chain from a URDF",
            "urdf": str(self.urdf),
            "joints": list(self.joint_names),
            "links": list(arm.links),
            "gravity": list(self.gravity),
            "joint_terms": list(arm.joint_terms),
            "couplings": [list(c) for c in self.couplings],
            "parameters": arm.n_params,
            "urdf_mass_kg": mass,
            "missing_inertials": list(arm.missing_inertials),
            "statement": list(self.statement),
        }

    @cached_property
    def arm(self) -> ChainArm:
        """The `ChainArm` (built once; InputError naming the file and element on a bad URDF)."""
        return ChainArm(
            str(self.urdf),
            self.joint_names,
            self.gravity,
            self.base,
            self.friction,
            self.armature,
            self.offsets,
            self.couplings,
        )

    def nominal_parameters(self) -> np.ndarray:
        """π0 (P,): the URDF's inertials, each drive's nominal viscous and Coulomb friction (mean of the two
        directions) and reflected rotor inertia, no offsets: the arm's "datasheet" model."""
        arm = self.arm
        pi = arm.cad_parameters()
        values = {
            "fv": [j.viscous_friction.mean for j in self.joints],
            "fc": [j.coulomb_friction.mean for j in self.joints],
            "ia": [j.rotor_inertia for j in self.joints],
        }
        n = self.n_joints
        for t, term in enumerate(arm.joint_terms):
            if term in values:
                start = arm.n_link_params + t * n
                pi[start : start + n] = values[term]
        return pi
