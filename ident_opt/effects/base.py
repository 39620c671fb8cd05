"""What every effect shares: its keys and their text syntax, and the hooks the rest of ident-opt calls.

An effect is written ``NAME`` or ``NAME:key=value,key=value``; a per-joint value is a bracketed pair
``key=[v1,v2]``. Every effect also takes ``scale`` (default 1): it multiplies the effect's magnitude (its
departure from the clean trial), so ``scale=0`` reproduces the clean trial exactly. Omitted keys take the
defaults of the effect's `Key` table.

An `Effect` is one module of `ident_opt.effects` (a cause the diagnosis can name) or of
`ident_opt.effects.background` (a realism term of the simulator that no diagnosis names). Its hooks are
no-ops by default; each effect overrides those it needs:

The hooks, by who calls them; where the two kinds of arm (`Robot.kind`) differ, the planar two-link arm's hook and
the chain's (`chain_…`) stand side by side, each engine calls its own and passes it its context:

| who calls                                   | planar two-link arm                     | arm of n joints (chain)     |
|---------------------------------------------|-----------------------------------------|-----------------------------|
| the syntax (`--effect`, problem files)      | `keys`, `default`, `scaled`,            | `chain_default`             |
|                                             | `is_active`, `untouched`                |                             |
| the model (`PlanarArm(extensions=...)`)     | `parameters`, `replaces`, `fallback`,   | — (the chain's own terms)   |
|                                             | `aliases`, `check_model`, `columns`,    |                             |
|                                             | `add_terms`                             |                             |
| the simulator's true plant                  | `true_robot`, `true_plant(spec)`,       | `chain_plant(plant)`,       |
| (`simulator.truth`, `simulator.chain_plant`) | `mechanism(spec)`, `true_physical`      | `chain_mechanism(plant)`    |
| the simulator's truth file                  | `truth_entry(truth)`                    | `chain_truth(plant)`        |
| the simulator's loop (background terms)     | see `Background`                        | —                           |
| the diagnosis's candidates                  | `families(ctx)`: `PlanarFamily`s        | `chain_families(ctx)`:      |
| (`diagnosis.planar`, `diagnosis.chain`)     |                                         | `ChainFamily`s              |
| the diagnosis's naming and report (both)    | `resolved`, `resolution`, `sentence`,   | the same                    |
|                                             | `spectrum_marker`, `channel_lines`      |                             |
| hidden-effect trials (tests, benchmarks)    | `reference`, `draw`, `judged`, `judge`  | `chain_draw`, `chain_judge` |

A mechanism is described, not built: `mechanism` and `chain_mechanism` return its kind, joint, frequency and damping,
and the simulator builds the plant (`simulator.elastic`, `simulator.chain_plant`). The candidates' families are
declared in `effects.families`; the diagnosis's `ctx` (`diagnosis.planar.families.Context`,
`diagnosis.chain.search.ChainContext`) gives what else they need of the engine (its nominal model, its screens).

This module and the effect modules import nothing heavy at load time: `ident-opt --help` and problem-file
parsing read the catalogue, and must not pay for NumPy, CasADi or SciPy. Hooks reach those (and the parts
of ident-opt below every floor, `ident_opt.numerics`) through `deferred` (`effects.lazy`); what they need of an
engine (the diagnosis's, the simulator's), the engine passes them: its context.
"""

from __future__ import annotations

import importlib
import math
import pkgutil
import re
from collections.abc import Sequence
from dataclasses import dataclass

from ident_opt.effects.families import PlanarFamily
from ident_opt.effects.lazy import DEFERRED, deferred
from ident_opt.errors import InputError
from ident_opt.parameters import Parameter

#: The numerics an effect's hooks use (and this module's own), imported on first use: an effect module's
#: ``from ident_opt.effects.base import np`` gives a `deferred` (`effects.lazy`).
np = deferred(DEFERRED["np"])


def __getattr__(name: str) -> deferred:
    """The names of `DEFERRED`, each a `deferred` of its module (PEP 562: asked only for names not defined)."""
    if name in DEFERRED:
        return deferred(DEFERRED[name])
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


#: Relative tolerance on a hidden magnitude (the default `Effect.judge`).
MAGNITUDE_TOL = 0.15
#: A nonlinear parameter fitted this close (relative) to a bound of its search is the search stopped by the
#: bound, not a feature of the data: causes whose estimate sits there are not named (`Effect.resolved`).
SEARCH_EDGE = 0.02


def inside(value: float, low: float, high: float) -> bool:
    """Whether `value` lies inside (low, high) and not within `SEARCH_EDGE` (relative) of either bound."""
    return low * (1 + SEARCH_EDGE) < value < high * (1 - SEARCH_EDGE)


def edge_rule(what: str, bounds: tuple[float, float], unit: str, reason: str) -> tuple[str, str]:
    """An `Effect.resolution` for a fitted value that must lie `inside` its search's `bounds` [unit]."""
    where = f"within {SEARCH_EDGE:.0%} of a bound of its search ({bounds[0]:g} to {bounds[1]:g} {unit})"
    return f"{what} {where} is not named", reason


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


class Effect:
    """One effect: its name, one-line summary and keys, and no-op hooks (see the module docstring).

    `coulomb` below is the datasheet's per-direction Coulomb levels (positive, negative) [N m, joint side]:
    the nominal friction an effect may depart from."""

    #: The effect's name in the syntax and the reports: its module's (see `__init_subclass__`).
    name: str = ""
    summary: str = ""
    keys: dict[str, Key] = {}  # noqa: RUF012 (read-only class tables)
    #: The effect's place in the catalogue (listings, `--help`, the causes' order).
    order: int = 0

    def __init_subclass__(cls, **kwargs) -> None:
        """An effect is named after its module: the catalogue lists the modules (`discover`), so the one name
        stands for both."""
        super().__init_subclass__(**kwargs)
        if cls.__module__ != __name__ and "name" not in cls.__dict__:
            cls.name = cls.__module__.rpartition(".")[2]

    # ------------------------------------------------------------------ syntax
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

    def parse(self, body: str, text: str) -> dict:
        """The ``key=value,...`` part of an effect string as key -> value (only the keys written)."""
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
                params[key] = self._parse_value(text, key, value.strip())
        return params

    def _parse_value(self, text: str, key: str, value: str) -> object:
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
            shape = {"pair": "[v1,v2]", "vector": "[x,y,z]", "joint": "1 or 2", "joints": "a joint or a list"}
            raise InputError(
                f"effect {text!r}: key {key!r} of {self.name} must be {shape.get(spec.kind, 'a number')}, got {value!r}"
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

    # ------------------------------------------------------------------ model (`PlanarArm` extension)
    #: Parameters the extension adds to π, in column order (empty: the effect is no model extension).
    parameters: tuple[Parameter, ...] = ()
    #: Rigid parameters the extension replaces.
    replaces: tuple[str, ...] = ()
    #: name -> the parameter whose value `PlanarArm.vector` uses when `name` is not given.
    fallback: dict[str, str] = {}  # noqa: RUF012
    #: Other names `PlanarArm(extensions=...)` accepts for this extension.
    aliases: tuple[str, ...] = ()

    def check_model(self, model) -> None:
        """Raise `ValueError` when this extension does not fit the rest of `model`."""

    def columns(self, model) -> dict:
        """NumPy regressor columns: parameter name -> f(q, dq, ddq) -> (row 1, row 2), inputs (N, 2)."""
        return {}

    def add_terms(self, model, q, dq, p: dict, M: list, G: list, F: list) -> None:
        """Add the extension's terms to the CasADi M (2×2 nested list), G and F (lists of 2), in place;
        `p` maps parameter names to their CasADi entries of π."""

    # ------------------------------------------------------------------ simulator truth
    def true_robot(self, robot, p: dict):
        """The true robot (a `problem.PlanarRobot`) the datasheet π is computed from."""
        return robot

    def true_plant(self, plant, p: dict) -> None:
        """Change the true plant (`simulator.truth.PlantSpec`: π, model structure, sensors), in place."""

    def mechanism(self, plant, p: dict):
        """A mechanism that replaces the rigid arm (an elastic joint or link), or None."""
        return None

    def truth_entry(self, truth, p: dict) -> dict:
        """The effect in the truth file (`<trial>.truth.json`), in the diagnosis's estimate keys."""
        return dict(p)

    def true_physical(self, physical: dict, p: dict) -> None:
        """Change the truth file's rigid-body description of the true plant, in place."""

    # ------------------------------------------------------------- simulator truth, any arm (`simulator.chain_plant`)
    def chain_plant(self, plant, p: dict) -> None:
        """Change the true plant of an n-joint arm (`simulator.chain_plant.ArmPlant`: π, extra inertia, friction
        terms, encoder offsets, the logged torque channel), in place."""

    def chain_mechanism(self, plant, p: dict) -> tuple[int, float, float] | None:
        """An elastic joint that replaces the rigid one: (0-based joint, natural frequency [Hz], damping ratio),
        or None."""
        return None

    def chain_truth(self, plant, p: dict) -> dict:
        """The effect in an n-joint trial's truth file, in the diagnosis's estimate keys."""
        return dict(p)

    # ------------------------------------------------------------------ diagnosis
    #: (rule, reason) when `resolved` can refuse an estimate: the rule goes into the reports.
    resolution: tuple[str, str] | None = None

    def families(self, robot) -> list:
        """The candidate model families (`diagnosis.planar.families.Family`) that explain this cause."""
        return []

    def family(self, model=None, free: tuple[str, ...] = (), **options):
        """One candidate family of this cause: `model(θ)` (default: the nominal model) with the π names
        `free` freed against the datasheet (default: none) and the other `Family` fields in `options`."""
        return PlanarFamily(self.name, model, free, **options)

    def resolved(self, estimate: dict, dt: float) -> bool:
        """Whether a fitted estimate describes an effect at all (`dt` the sample step [s])."""
        return True

    def sentence(self, d, base: str, gain: str) -> str:
        """What the diagnosis `d` found, in words (`base`: the baseline's name; `gain`: the nMSE sentence)."""
        return gain

    def spectrum_marker(self, estimate: dict, joint: int) -> float | None:
        """A frequency [Hz] to mark on joint `joint`'s (0-based) residual spectrum, or None."""
        return None

    def channel_lines(self, d, channels: dict) -> list[str]:
        """Report lines on what the file's other channels say about this cause's candidate."""
        return []

    # ------------------------------------------------------------------ hidden-effect trials
    #: The simulator reference (`tud01`, `fourier`) on which the effect shows.
    reference: str = "tud01"
    #: The estimate keys a hidden instance is judged on.
    judged: tuple[str, ...] = ()

    def draw(self, rng, robot) -> dict:
        """Keys for `simulate_trial(effects={name: keys})`, drawn from a realistic range."""
        return {}

    # ------------------------------------------------------------------ any arm: diagnosis and hidden trials
    def chain_families(self, robot, ctx) -> list:
        """The candidate families (`diagnosis.chain.families.ArmFamily`) of this cause on an n-joint arm (`ctx`: its
        `ArmContext`, with the evidence per joint)."""
        return []

    def chain_draw(self, rng, joints: Joints, chosen: tuple[int, ...]) -> dict:
        """Keys of a hidden instance on an n-joint arm (`joints.scale` its reference magnitudes), on the 0-based
        joints `chosen` where the cause is per joint."""
        return {}

    def chain_judge(self, estimate: dict, truth: dict) -> list[tuple[bool, float]]:
        """(within tolerance, relative error) per judged number on an n-joint arm: the planar rule (`judge`), with a
        joint whose true value is 0 (untouched) judged relative to the largest true value of the same key."""
        checks = []
        for key in self.judged:
            e, t = (
                np.atleast_1d(np.asarray(estimate[key], dtype=float)),
                np.atleast_1d(np.asarray(truth[key], dtype=float)),
            )
            largest = float(np.max(np.abs(t))) or 1.0
            for ej, tj in zip(e, t):
                rel = abs(ej - tj) / (abs(tj) if tj != 0 else largest)
                checks.append((rel <= MAGNITUDE_TOL, rel))
        return checks

    def judge(self, estimate: dict, truth: dict) -> list[tuple[bool, float]]:
        """(within tolerance, relative error) per judged number; by default `MAGNITUDE_TOL` relative."""
        checks = []
        for key in self.judged:
            for e, t in zip(np.atleast_1d(estimate[key]), np.atleast_1d(truth[key])):
                rel = relative_error(float(e), float(t))
                checks.append((rel <= MAGNITUDE_TOL, rel))
        return checks


class Background(Effect):
    """A background realism term of the simulator: it acts on the joint (motor-side) torques of the closed
    loop, whatever the plant, through the hooks below (used by `simulator.background`)."""

    def states(self, p: dict) -> int:
        """How many states the term adds to the plant."""
        return 0

    def initial(self, p: dict, rng):
        """The added states at the start (length `states`)."""
        return np.zeros(0)

    #: Whether the term is an external torque d on the joints (see `disturbance`).
    disturbs: bool = False

    def disturbance(self, p: dict, n: int, dt: float, rng):
        """The external torque d (n, 2) [N m] on a grid of step dt [s] (terms that `disturb`)."""
        return np.zeros((n, 2))

    def force(self, p: dict, z):
        """The torque [N m] the term's states z resist the motion with, at the joints (a CasADi 2-vector)."""
        return 0

    def rate(self, p: dict, z, v):
        """dz/dt of the term's states at encoder-side joint rates v [rad/s] (CasADi)."""
        return z[:0]

    def current(self, p: dict, robot, q, dq):
        """A torque [N m] added to the commanded one (part of the actual motor current), or None."""
        return None

    def rates(self, p: dict, inertia) -> list[float]:
        """Bounds of the fastest rates [1/s] the term adds (sizes the RK4 step); `inertia` [kg m²] per joint."""
        return []


def discover(package: str, path: Sequence[str], skip: tuple[str, ...] = ()) -> dict[str, Effect]:
    """The ``EFFECT`` of every module of `package` (at `path`) but `skip`, name -> effect, by `Effect.order`."""
    found = [
        importlib.import_module(f"{package}.{info.name}").EFFECT
        for info in pkgutil.iter_modules(path)
        if info.name not in skip
    ]
    return {e.name: e for e in sorted(found, key=lambda e: e.order)}


def arm_values(n: int, chosen: tuple[int, ...], untouched: float, draw) -> tuple[float, ...]:
    """A hidden per-joint value on an n-joint arm: `draw(j)` on the 0-based joints `chosen`, `untouched` elsewhere."""
    return tuple(float(draw(j)) if j in chosen else untouched for j in range(n))


def per_joint_draw(rng, untouched: float, draw) -> tuple[float, float]:
    """A hidden per-joint value: joint 1, joint 2 or both (equally likely) take `draw()`, the others `untouched`."""
    values = [untouched, untouched]
    for j in ((0,), (1,), (0, 1))[int(rng.integers(3))]:
        values[j] = draw()
    return tuple(values)


def relative_error(estimate: float, true: float) -> float:
    """|estimate − true| / |true| (|estimate| when true is 0)."""
    return abs(estimate - true) / abs(true) if true != 0 else abs(estimate)


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


def _show(value: object) -> str:
    if isinstance(value, tuple):
        return "[" + ",".join(f"{v:g}" for v in value) + "]"
    return f"{value:g}" if isinstance(value, float) else str(value)
