"""The effect syntax's vocabulary: one key of an effect (`Key`: its kind, default, bounds, whether it carries the
magnitude), the joints as the syntax sees them (`Joints`: names, 1-based indices, an n-joint arm's reference magnitudes
`ArmScale`), and how values are written back in words. Plain Python: the catalogue loads for `--help`."""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

from ident_opt.errors import InputError


@dataclass(frozen=True)
class Key:
    """One key of an effect: its kind ("pair": one value per joint, "float", "vector": x, y, z, "joint", "joints",
    "choice"), default, meaning and bounds.

    `magnitude`: the key carries the effect's size, so ``scale`` multiplies it (see `Effect.scaled`)."""

    kind: str
    default: object
    doc: str
    minimum: float | None = 0.0
    strict: bool = False  # minimum excluded
    choices: tuple[str, ...] = ()  # for kind "choice"
    magnitude: bool = False
    maximum: float | None = None  # the largest value the simulator accepts (bounds its work and its numbers)


_SCALE = Key("float", 1.0, "multiplies the effect's magnitude; 0 gives the clean trial", maximum=1e3)


#: The joint selector of a per-joint effect: which joints it touches (1-based indices or the joints' names); the
#: others are untouched, and a per-joint key may then be one number for each selected joint.
SELECT = Key("joints", None, "the joint(s) it touches: 1-based index or name, or a list [2,5]; the others untouched")


@dataclass(frozen=True)
class ArmScale:
    """Reference magnitudes of an n-joint arm (tuples: one per joint): what its effects' defaults and hidden draws
    are relative to, so one rule serves a 1 kg and a 30 kg arm (`simulator.chain_plant.arm_scale`)."""

    torque: tuple[float, ...]  # N m: each joint's effort limit, else its nominal torque's 95th percentile in motion
    inertia: tuple[float, ...]  # kg m²: the nominal diagonal inertia at the centre of the joint ranges
    speed: tuple[float, ...]  # rad/s: the speed the reference motions cruise at
    mass: float  # kg: the moving links' total
    reach: float  # m: base to last joint, along the chain


class Joints(tuple):
    """The arm's joints as the effect syntax sees them. A pair, as the hooks have always read it: the datasheet's
    per-direction Coulomb levels (positive, negative) [N m, joint side], one per joint; plus the joints' `names`
    and, from the n-joint simulator, `scale`: reference magnitudes the defaults of an n-joint arm are relative to
    (`ArmScale`), None for the planar two-link arm (its defaults are the table's, in absolute units)."""

    names: tuple[str, ...]
    scale: object

    def __new__(cls, positive, negative, names=None, scale=None):
        self = super().__new__(cls, (tuple(positive), tuple(negative)))
        n = len(self[0])
        self.names = tuple(names) if names is not None else tuple(f"joint{j + 1}" for j in range(n))
        self.scale = scale
        return self

    @property
    def n(self) -> int:
        """The number of joints."""
        return len(self[0])

    def position(self, value: object, where: str, effect: str, key: str = "joint") -> int:
        """The 0-based index of a joint given as a 1-based number or by name; `InputError` naming the arm's."""
        if isinstance(value, str) and value.strip() in self.names:
            return self.names.index(value.strip())
        try:
            j = int(value) if not isinstance(value, bool) and float(value) == int(float(value)) else 0
        except (TypeError, ValueError):
            j = 0
        if 1 <= j <= self.n:
            return j - 1
        if self.n == 2 and self.names == ("joint1", "joint2"):
            raise InputError(f"effect {where!r}: key {key!r} of {effect} must be 1 or 2, got {value!r}")
        shown = ", ".join(self.names[:8]) + (", …" if self.n > 8 else "")
        raise InputError(
            f"effect {where!r}: key {key!r} of {effect} names joint {value!r}, which the arm does not have: give "
            f"1 to {self.n} or a joint's name ({shown})"
        )


def as_joints(coulomb) -> Joints:
    """`coulomb` as `Joints` (a plain (positive, negative) pair becomes one, joints named joint1, joint2, …)."""
    return coulomb if isinstance(coulomb, Joints) else Joints(coulomb[0], coulomb[1])


def _joint_word(value: str) -> int | str:
    """A joint as written: a 1-based index, or a name."""
    value = value.strip()
    if not value:
        raise ValueError
    try:
        return int(value)
    except ValueError:
        return value


def _shape(spec: Key, joints: Joints) -> str:
    """What a value of `spec` must look like on this arm, in words."""
    if spec.kind == "vector":
        return "a vector [x,y,z]"
    if spec.kind != "pair":
        return "a number"
    if joints.n == 2:
        return "a pair [v1,v2]"
    return f"one number or a list of {joints.n} (one per joint: {', '.join(joints.names[:3])}, …)"


def _written(spec: Key, joints: Joints | None) -> str:
    """How a value of `spec` is written in an effect string, in words: on this arm (`joints`) when it is known,
    else for any arm (an effect of a problem's [simulate] section is read before its arm)."""
    if spec.kind == "pair":
        if joints is None:
            return "one number, or a bracketed list of one number per joint ([v1,v2] on a two-joint arm)"
        if joints.n == 2:
            return "one number or a pair [v1,v2]"
        return f"one number or a bracketed list of {joints.n} ([v1,…,v{joints.n}], one per joint: " + (
            f"{', '.join(joints.names[:3])}, …)"
        )
    if spec.kind in ("joint", "joints"):
        if joints is not None and joints.n == 2 and joints.names == ("joint1", "joint2"):
            return "1 or 2" if spec.kind == "joint" else "a joint (1 or 2) or a list [1,2]"
        one = f"a joint: 1 to {joints.n} or its name" if joints is not None else "a joint: its 1-based index or name"
        return one if spec.kind == "joint" else f"{one}, or a list of them [2,5]"
    return {"vector": "a vector [x,y,z]"}.get(spec.kind, "a number")


def _show(value: object) -> str:
    if isinstance(value, tuple):
        return "[" + ",".join(f"{v:g}" for v in value) + "]"
    return f"{value:g}" if isinstance(value, float) else str(value)


class Syntax:
    """An effect's text syntax (`NAME:key=value,...`, module doc of `effects.base`): its keys (`keys`, the table
    of `Key`s), how a string is parsed and checked against them, defaults, the `joint` selector, `scale`. `Effect`
    is one."""

    name: str = ""
    keys: dict[str, Key] = {}  # noqa: RUF012 (read-only class tables)

    @property
    def per_joint(self) -> bool:
        """Whether the effect has per-joint keys (it then takes the `joint` selector, `SELECT`)."""
        return any(spec.kind == "pair" for spec in self.keys.values())

    def key(self, key: str, where: str) -> Key:
        """The `Key` of `key` (``scale`` and a per-joint effect's ``joint`` included); `InputError` for an unknown
        one."""
        if key == "scale":
            return _SCALE
        if key == "joint" and key not in self.keys and self.per_joint:
            return SELECT
        if key not in self.keys:
            extra = ", joint" if self.per_joint and "joint" not in self.keys else ""
            raise InputError(
                f"effect {where!r}: unknown key {key!r} for {self.name}; known: {', '.join(self.keys)}{extra}, scale"
            )
        return self.keys[key]

    def parse(self, body: str, text: str, joints: Joints | None = None) -> dict:
        """The ``key=value,...`` part of an effect string as key -> value (only the keys written). `joints`: the
        arm's, when known, so that a malformed per-joint value is told the count this arm needs."""
        params: dict[str, object] = {}
        if body.strip():
            # Split on commas that are not inside brackets, so that key=[v1,v2] stays whole.
            for item in re.split(r",(?![^\[]*\])", body):
                key, eq, value = item.partition("=")
                key = key.strip()
                if not eq or not key:
                    raise InputError(f"effect {text!r}: expected key=value, got {item.strip()!r}")
                if key in params:
                    raise InputError(f"effect {text!r}: key {key!r} given twice")
                params[key] = self._parse_value(text, key, value.strip(), joints)
        return params

    def _parse_value(self, text: str, key: str, value: str, joints: Joints | None = None) -> object:
        spec = self.key(key, text)
        bracketed = value[1:-1] if value.startswith("[") and value.endswith("]") else None
        try:
            if spec.kind in ("pair", "vector"):
                if bracketed is None:
                    if spec.kind == "pair":  # one number: every joint, or each joint `joint` selects
                        return float(value)
                    raise ValueError
                return tuple(float(v) for v in bracketed.split(","))
            if spec.kind == "joints":
                items = bracketed.split(",") if bracketed is not None else [value]
                return tuple(_joint_word(v) for v in items)
            if spec.kind == "joint":
                return _joint_word(value)
            if spec.kind == "choice":
                return value
            return float(value)
        except ValueError:
            raise InputError(
                f"effect {text!r}: key {key!r} of {self.name} must be {_written(spec, joints)}, got {value!r}"
            ) from None

    def check(self, key: str, value: object, where: str, joints: Joints | None = None) -> object:
        """Validate one value against its key; returns it in canonical form (a tuple of one float per joint, a
        float, a 1-based joint index). `joints`: the arm's (default: a two-link arm's)."""
        joints = joints or as_joints(((0.0, 0.0), (0.0, 0.0)))
        spec = self.key(key, where)
        if spec.kind == "joint":
            return joints.position(value, where, self.name) + 1
        if spec.kind == "joints":
            picked = [joints.position(v, where, self.name) for v in (value if isinstance(value, tuple) else (value,))]
            if len(set(picked)) != len(picked):
                raise InputError(f"effect {where!r}: key 'joint' of {self.name} names a joint twice")
            return tuple(sorted(picked))
        if spec.kind == "choice":
            if value not in spec.choices:
                raise InputError(
                    f"effect {where!r}: key {key!r} of {self.name} must be one of {', '.join(spec.choices)}, "
                    f"got {value!r}"
                )
            return value
        size = {"pair": joints.n, "vector": 3}.get(spec.kind)
        values = value if size else (value,)
        if isinstance(values, str) or not isinstance(values, Sequence) or (size and len(values) != size):
            raise InputError(
                f"effect {where!r}: key {key!r} of {self.name} must be {_shape(spec, joints)}, got {value!r}"
            )
        return self._numbers(key, spec, values, where)

    def _numbers(self, key: str, spec: Key, values: Sequence, where: str) -> object:
        out = []
        for v in values:
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise InputError(f"effect {where!r}: key {key!r} of {self.name} must be a finite number, got {v!r}")
            low, high = spec.minimum, spec.maximum
            if low is not None and (v < low or (spec.strict and v == low)):
                bound = f"> {low:g}" if spec.strict else f">= {low:g}"
                raise InputError(f"effect {where!r}: key {key!r} of {self.name} must be {bound}, got {v!r}")
            if high is not None and abs(v) > high:
                raise InputError(
                    f"effect {where!r}: key {key!r} of {self.name} must be at most {high:g} in size (the simulator's "
                    f"bound), got {v!r}"
                )
            out.append(float(v))
        return tuple(out) if spec.kind in ("pair", "vector") else out[0]

    def complete(self, params: dict, where: str, coulomb: tuple[tuple, tuple]) -> dict:
        """`params` checked, with defaults for the keys omitted and ``scale`` applied (`checked`)."""
        full = self.checked(params, where, coulomb)
        scale = full.pop("scale", 1.0)
        return self.scaled(full, scale, coulomb)

    def checked(self, params: dict, where: str, coulomb: tuple[tuple, tuple]) -> dict:
        """`params` checked, with defaults for the keys omitted. A per-joint key given as one number applies to
        every joint, or to each joint the ``joint`` selector names (the others untouched, `untouched`)."""
        joints = as_joints(coulomb)
        params = dict(params)
        selected = None
        if "joint" in params and "joint" not in self.keys and self.per_joint:
            selected = self.check("joint", params.pop("joint"), where, joints)
        full = {k: self.check(k, self._spread(k, v, selected, joints, where), where, joints) for k, v in params.items()}
        for key in self.keys:
            if key not in full:
                full[key] = self.default(key, joints) if joints.scale is None else self.chain_default(key, joints)
        return full if selected is None else self._untouched(full, selected, joints)

    def _spread(self, key: str, value: object, selected: tuple[int, ...] | None, joints: Joints, where: str) -> object:
        """A per-joint key's value as one per joint: one number for every (selected) joint, or one per selected
        joint when `joint` selects some (the others untouched, `untouched`)."""
        spec = self.key(key, where)
        if spec.kind != "pair" or (selected is None and not isinstance(value, float)):
            return value
        if selected is None:
            return (value,) * joints.n
        given = (value,) * len(selected) if isinstance(value, float) else value
        if isinstance(given, tuple) and len(given) == len(selected) and len(selected) != joints.n:
            out = [self.untouched(key, j, joints) for j in range(joints.n)]
            for j, v in zip(selected, given):
                out[j] = v
            return tuple(out)
        return given

    def _untouched(self, full: dict, selected: tuple[int, ...], joints: Joints) -> dict:
        """`full` with every per-joint key at its untouched value on the joints the selector leaves out."""
        for key, spec in self.keys.items():
            if spec.kind == "pair":
                full[key] = tuple(
                    v if j in selected else self.untouched(key, j, joints) for j, v in enumerate(full[key])
                )
        return full

    def untouched(self, key: str, joint: int, joints: Joints) -> float:
        """The value of per-joint key `key` on a joint the effect leaves alone (0-based `joint`): 0 by default."""
        return 0.0

    def default(self, key: str, coulomb: tuple[tuple, tuple]) -> object:
        """The value of an omitted key (the planar two-link arm's, in absolute units)."""
        return self.keys[key].default

    def chain_default(self, key: str, joints: Joints) -> object:
        """The value of an omitted key on an n-joint arm (`joints.scale` holds its reference magnitudes): by
        default the planar one, a per-joint key's repeated over the joints (its first joint's value)."""
        value = self.default(key, joints)
        if self.keys[key].kind == "pair" and isinstance(value, tuple):
            return (value[0],) * joints.n
        return value

    def scaled(self, p: dict, s: float, coulomb: tuple[tuple, tuple]) -> dict:
        """Multiply the effect's magnitude (its `magnitude` keys) by `s`."""
        for key, spec in self.keys.items():
            if spec.magnitude:
                p[key] = tuple(s * x for x in p[key]) if spec.kind in ("pair", "vector") else p[key] * s
        return p

    def is_active(self, p: dict, coulomb: tuple[tuple, tuple]) -> bool:
        """Whether the effect changes the trial at all (inactive ones are skipped: the trial is the clean one)."""
        sizes = [p[key] for key, spec in self.keys.items() if spec.magnitude]
        return any(any(v) if isinstance(v, tuple) else v > 0 for v in sizes)

    def describe(self, defaults_shown: bool = True) -> list[str]:
        """Lines for `--help`: the effect, then each key with its default and meaning."""
        lines = [f"  {self.name}: {self.summary}"]
        for key, spec in self.keys.items():
            default = (
                ("per arm" if spec.kind == "vector" else "datasheet") if spec.default is None else _show(spec.default)
            )
            lines.append(f"      {key}={default}  ({spec.doc})")
        return lines
