"""A robot as rigid bodies, neutral of file formats: what `ident-opt export` writes as a URDF or a MuJoCo MJCF.

`RobotDescription` is a fixed-base tree: the base link, the moving links (`Body`: mass, centre of mass, inertia
about it) and the revolute joints that carry them (`Joint`: origin in the parent link's frame, axis, limits and
the joint terms), massless frames fixed to links (`Frame`: a flange), drives that turn several joints
(`Drive`: a coupled wrist), gravity and the lines the file must say (`notes`). Each link's frame is its
joint's frame (the URDF convention), so a joint's q is measured from its origin about its axis.

The joint torque the description stands for, at q, dq, ddq [rad, rad/s, rad/s²]:

    τ_j = RNEA_j(q, dq, ddq; bodies, gravity) + damping_j dq_j + friction_j sign(dq_j) + armature_j ddq_j + offset_j
          + Σ_drives c_j (damping v + friction sign(v) + armature Σ_k c_k ddq_k),   v = Σ_k c_k dq_k

Units: lengths m, masses kg, inertias kg m², angles rad, damping N m s/rad, friction and offsets N m, gravity m/s².

`RobotDescription.violations` says which links (and joint terms) no physical body has: a mass ≤ 0, an inertia
about the centre of mass with a negative principal moment or whose principal moments break a triangle
inequality (A + B ≥ C: together with m > 0 exactly the inertias some non-negative density has).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass

import numpy as np
import pinocchio as pin

Vector3 = tuple[float, float, float]
Matrix3 = tuple[Vector3, Vector3, Vector3]

#: Tolerance of the physical-possibility checks, relative to a link's largest principal moment: rounding of the
#: parallel-axis theorem on a realised link, not a physical margin (a consistent fit keeps 1e-6 kg m² inside).
RELATIVE_TOLERANCE = 1e-12
#: Its absolute floor [kg m²]: a point mass has no moment to be relative to (MuJoCo's mjMINVAL).
ABSOLUTE_TOLERANCE = 1e-15


def vector3(values: Iterable[float]) -> Vector3:
    """Three floats as a tuple (ValueError unless exactly three)."""
    out = tuple(float(v) for v in values)
    if len(out) != 3:
        raise ValueError(f"expected 3 values, got {len(out)}")
    return out  # type: ignore[return-value]


def matrix3(values: np.ndarray | Iterable[Iterable[float]]) -> Matrix3:
    """A 3×3 matrix as a tuple of rows."""
    return tuple(vector3(row) for row in np.asarray(values, dtype=float).reshape(3, 3))  # type: ignore[return-value]


IDENTITY: Matrix3 = matrix3(np.eye(3))


@dataclass(frozen=True)
class Origin:
    """A frame's placement in its parent's frame: translation `xyz` [m] and `rotation` (3×3, parent ← child)."""

    xyz: Vector3 = (0.0, 0.0, 0.0)
    rotation: Matrix3 = IDENTITY

    @classmethod
    def of(cls, placement: pin.SE3) -> Origin:
        """The origin of a Pinocchio placement (SE3)."""
        return cls(vector3(placement.translation), matrix3(placement.rotation))

    @property
    def se3(self) -> pin.SE3:
        """This origin as a Pinocchio SE3."""
        return pin.SE3(np.array(self.rotation), np.array(self.xyz))

    @property
    def rpy(self) -> Vector3:
        """URDF roll, pitch, yaw [rad]: rotation = R_z(yaw) R_y(pitch) R_x(roll)."""
        return vector3(pin.rpy.matrixToRpy(np.array(self.rotation)))

    @property
    def quaternion(self) -> tuple[float, float, float, float]:
        """The rotation as a unit quaternion (w, x, y, z), MuJoCo's order."""
        x, y, z, w = pin.Quaternion(np.array(self.rotation)).normalized().coeffs()
        return float(w), float(x), float(y), float(z)


@dataclass(frozen=True)
class Body:
    """One moving link: `mass` [kg], centre of mass `com` (3,) [m] in the link frame, `inertia` (3×3) [kg m²]
    about the centre of mass, in the link frame's axes."""

    name: str
    mass: float
    com: Vector3
    inertia: Matrix3

    @property
    def principal_moments(self) -> np.ndarray:
        """The inertia's principal moments (3,) [kg m²], ascending."""
        inertia = np.array(self.inertia)
        return np.linalg.eigvalsh(0.5 * (inertia + inertia.T))

    def violations(self) -> list[str]:
        """Why no physical body has this link's mass and inertia (module doc); [] when one does."""
        where = f"link {self.name!r}"
        values = [self.mass, *self.com, *np.ravel(self.inertia)]
        if not all(math.isfinite(v) for v in values):
            return [f"{where}: a mass, centre of mass or inertia that is not a finite number"]
        out = []
        if self.mass <= 0:
            out.append(f"{where}: mass {self.mass:.6g} kg ≤ 0")
        low, mid, high = self.principal_moments
        tolerance = RELATIVE_TOLERANCE * max(abs(low), abs(high)) + ABSOLUTE_TOLERANCE
        if low < -tolerance:
            out.append(f"{where}: a negative principal moment of inertia about the centre of mass ({low:.6g} kg m²)")
        elif low + mid < high - tolerance:
            out.append(
                f"{where}: principal moments ({low:.6g}, {mid:.6g}, {high:.6g}) kg m² break the triangle inequality "
                f"{low:.6g} + {mid:.6g} ≥ {high:.6g}"
            )
        return out


@dataclass(frozen=True)
class Joint:
    """One revolute joint: `parent` and `child` link, its `origin` in the parent link's frame (the child link's
    frame at q = 0), its unit `axis` (3,) in that frame, its limits where known (`lower`, `upper` [rad],
    `velocity` [rad/s], `effort` [N m]; None where not) and its own terms: viscous friction `damping`
    [N m s/rad], Coulomb friction `friction` [N m], reflected rotor inertia `armature` [kg m²], constant torque
    `offset` [N m]."""

    name: str
    parent: str
    child: str
    origin: Origin
    axis: Vector3
    lower: float | None = None
    upper: float | None = None
    velocity: float | None = None
    effort: float | None = None
    damping: float = 0.0
    friction: float = 0.0
    armature: float = 0.0
    offset: float = 0.0

    @property
    def limited(self) -> bool:
        """Whether the joint has a position range (lower and upper)."""
        return self.lower is not None and self.upper is not None

    def violations(self) -> list[str]:
        """Which of the joint's dissipative or inertial terms are negative (no passive drive has them)."""
        return _negative_terms(f"joint {self.name!r}", self.damping, self.friction, self.armature)


@dataclass(frozen=True)
class Drive:
    """A drive that turns several joints (a coupled wrist's motor): it turns at v = Σ_k c_k dq_k and its torque f
    reaches joint k as c_k f (`joints` and their `coefficients` c); viscous friction `damping` [N m s/rad],
    Coulomb friction `friction` [N m] and rotor inertia `armature` [kg m²] act on v."""

    name: str
    joints: tuple[str, ...]
    coefficients: tuple[float, ...]
    damping: float = 0.0
    friction: float = 0.0
    armature: float = 0.0

    def violations(self) -> list[str]:
        """Which of the drive's terms are negative."""
        return _negative_terms(f"drive {self.name!r}", self.damping, self.friction, self.armature)

    def velocity_text(self) -> str:
        """The drive's velocity v as text, e.g. "1 dq_joint_5 + 1 dq_joint_6" [rad/s], for the files' comments."""
        return " + ".join(f"{c:g} dq_{j}" for j, c in zip(self.joints, self.coefficients))


@dataclass(frozen=True)
class Frame:
    """A massless frame fixed to a link (a flange, a sensor, a link the chain merged): the fixed `joint` that
    attaches it, its `parent` link (or frame) and its `origin` in that frame."""

    name: str
    joint: str
    parent: str
    origin: Origin


def _negative_terms(where: str, damping: float, friction: float, armature: float) -> list[str]:
    terms = (
        ("viscous friction", damping, "N m s/rad"),
        ("Coulomb friction", friction, "N m"),
        ("armature", armature, "kg m²"),
    )
    return [
        f"{where}: {what} {value:.6g} {unit} < 0" if math.isfinite(value) else f"{where}: {what} is not a number"
        for what, value, unit in terms
        if not value >= 0
    ]


@dataclass(frozen=True)
class RobotDescription:
    """A fixed-base robot of rigid bodies (module doc): its `name`, `base` link, moving links (`bodies`, in the
    order of `joints`), revolute `joints` (base to tip, parents first), `gravity` (3,) [m/s²] in the base frame,
    massless `frames`, coupled `drives` and `notes`: the lines the written file must say."""

    name: str
    base: str
    bodies: tuple[Body, ...]
    joints: tuple[Joint, ...]
    gravity: Vector3
    frames: tuple[Frame, ...] = ()
    drives: tuple[Drive, ...] = ()
    notes: tuple[str, ...] = ()

    def violations(self) -> list[str]:
        """Every link no physical body has, and every negative friction or armature (module doc); [] when none."""
        out = [line for body in self.bodies for line in body.violations()]
        out += [line for joint in self.joints for line in joint.violations()]
        return out + [line for drive in self.drives for line in drive.violations()]

    def placement_in_body(self, frame: str) -> tuple[str, pin.SE3]:
        """(the moving link or base that carries `frame`, the frame's placement in that link's frame)."""
        frames = {f.name: f for f in self.frames}
        placement = pin.SE3.Identity()
        while frame in frames:
            placement = frames[frame].origin.se3 * placement
            frame = frames[frame].parent
        return frame, placement

    def joint_lines(self, armature: bool = True, drives: bool = True) -> list[str]:
        """What a format's joint attributes may not say, one line each: the armature (when `armature`), the
        constant offsets and the coupled drives (when `drives`); empty parts are left out."""
        lines = []
        if armature and any(j.armature for j in self.joints):
            values = ", ".join(f"{j.name} {j.armature!r}" for j in self.joints)
            lines.append(f"armature [kg m²] (adds armature · ddq to the joint's torque): {values}")
        if any(j.offset for j in self.joints):
            values = ", ".join(f"{j.name} {j.offset!r}" for j in self.joints)
            lines.append(
                f"constant torque offsets [N m] (added to the joint's torque, e.g. a torque sensor's): {values}"
            )
        for d in self.drives if drives else ():
            acting = ", ".join(f"{j} × {c:g}" for j, c in zip(d.joints, d.coefficients))
            lines.append(
                f"coupled drive {d.name}: turns at v = {d.velocity_text()}; its damping {d.damping!r} N m s/rad, "
                f"friction {d.friction!r} N m (× sign v) and armature {d.armature!r} kg m² (× dv/dt) act on v and "
                f"reach the joints as {acting}"
            )
        return lines

    def as_dict(self) -> dict:
        """Everything in the description as plain data (dicts, tuples, floats; the units under "units")."""
        out = asdict(self)
        out["units"] = {
            "mass": "kg",
            "com": "m (link frame)",
            "inertia": "kg m^2 (about the centre of mass, link axes)",
            "xyz": "m (parent frame)",
            "rotation": "parent <- child",
            "lower, upper": "rad",
            "velocity": "rad/s",
            "effort": "N m",
            "damping": "N m s/rad",
            "friction": "N m",
            "armature": "kg m^2",
            "offset": "N m",
            "gravity": "m/s^2 (base frame)",
        }
        return out
