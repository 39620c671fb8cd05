"""What every effect shares: its keys and their text syntax, and the hooks the rest of ident-opt calls.

An effect is written ``NAME`` or ``NAME:key=value,key=value``; a per-joint value is a bracketed pair
``key=[v1,v2]``. Every effect also takes ``scale`` (default 1): it multiplies the effect's magnitude (its
departure from the clean trial), so ``scale=0`` reproduces the clean trial exactly. Omitted keys take the
defaults of the effect's `Key` table.

An `Effect` is one module of `ident_opt.effects` (a cause the diagnosis can name) or of
`ident_opt.effects.background` (a realism term of the simulator that no diagnosis names). Its hooks are
no-ops by default; each effect overrides those it needs:

| who calls                                 | hooks                                                          |
|-------------------------------------------|----------------------------------------------------------------|
| the syntax (`--effect`, problem files)    | `keys`, `default`, `scaled`, `is_active`                       |
| the model (`PlanarArm(extensions=...)`)    | `parameters`, `replaces`, `fallback`, `aliases`,               |
|                                           | `check_model`, `columns`, `add_terms`                          |
| the simulator's truth (`simulate/truth`)  | `true_robot`, `true_plant`, `mechanism`, `truth_entry`,        |
|                                           | `true_physical`                                                |
| the simulator's loop (background terms)   | see `Background`                                               |
| the diagnosis (`diagnosis/`)               | `families`, `resolved`, `resolution`, `sentence`,              |
|                                           | `spectrum_marker`, `channel_lines`                             |
| hidden-effect trials (tests, benchmarks)  | `reference`, `draw`, `judged`, `judge`                         |

This module and the effect modules import nothing heavy at load time: `ident-opt --help` and problem-file
parsing read the catalogue, and must not pay for NumPy, CasADi or SciPy. Hooks reach those (and the parts
of ident-opt that import the catalogue themselves) through `deferred`.
"""

from __future__ import annotations

import importlib
import math
import pkgutil
import re
from collections.abc import Sequence
from dataclasses import dataclass

from ident_opt.errors import InputError
from ident_opt.parameters import Parameter


class deferred:  # lower case: used like the module it stands for
    """A module imported on its first attribute access: `np = deferred("numpy")` reads like an import.

    The catalogue loads for `--help` and problem files without NumPy, CasADi or SciPy (0.1 s instead of
    about 1 s), and the modules that iterate the catalogue (robot, simulate, diagnose) can be reached from
    an effect's hooks without an import cycle: the hooks only run once those modules are loaded anyway."""

    def __init__(self, module: str) -> None:
        self._module = module

    def __getattr__(self, attr: str):
        return getattr(importlib.import_module(self._module), attr)


#: What the hooks reach, name -> module, each imported on first use: an effect module's
#: ``from ident_opt.effects.base import np`` gives a `deferred` (see `__getattr__`).
DEFERRED = {
    "np": "numpy",
    "ca": "casadi",
    "cands": "ident_opt.diagnosis.candidates",
    "datasheet": "ident_opt.arm.datasheet",
    "elastic_nlp": "ident_opt.diagnosis.elastic_nlp",
    "flexible_link": "ident_opt.simulate.flexible_link",
    "linear": "ident_opt.diagnosis.linear",
    "nlp": "ident_opt.identify.nlp",
    "report": "ident_opt.diagnosis.report",
    "robot_model": "ident_opt.arm.planar",
    "signals": "ident_opt.diagnosis.signals",
    "sim": "ident_opt.simulate.truth",
}


def __getattr__(name: str) -> deferred:
    """The names of `DEFERRED`, each a `deferred` of its module (PEP 562: asked only for names not defined)."""
    if name in DEFERRED:
        return deferred(DEFERRED[name])
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


np, cands = deferred(DEFERRED["np"]), deferred(DEFERRED["cands"])  # the two this module's own hooks use

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
    """One key of an effect: its kind ("pair", "float", "joint", "choice"), default, meaning and lower bound.

    `magnitude`: the key carries the effect's size, so ``scale`` multiplies it (see `Effect.scaled`)."""

    kind: str
    default: object
    doc: str
    minimum: float | None = 0.0
    strict: bool = False  # minimum excluded
    choices: tuple[str, ...] = ()  # for kind "choice"
    magnitude: bool = False


_SCALE = Key("float", 1.0, "multiplies the effect's magnitude; 0 gives the clean trial")


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
    def key(self, key: str, where: str) -> Key:
        """The `Key` of `key` (``scale`` included); `InputError` for an unknown one."""
        if key == "scale":
            return _SCALE
        if key not in self.keys:
            raise InputError(
                f"effect {where!r}: unknown key {key!r} for {self.name}; known: {', '.join(self.keys)}, scale"
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
        try:
            if spec.kind == "pair":
                inner = value[1:-1] if value.startswith("[") and value.endswith("]") else None
                if inner is None:
                    raise ValueError
                return tuple(float(v) for v in inner.split(","))
            if spec.kind == "joint":
                return int(value)
            if spec.kind == "choice":
                return value
            return float(value)
        except ValueError:
            shape = "[v1,v2]" if spec.kind == "pair" else ("1 or 2" if spec.kind == "joint" else "a number")
            raise InputError(f"effect {text!r}: key {key!r} of {self.name} must be {shape}, got {value!r}") from None

    def check(self, key: str, value: object, where: str) -> object:
        """Validate one value against its key; returns it in canonical form (tuple of 2 floats, float, int)."""
        spec = self.key(key, where)
        if spec.kind == "joint":
            if isinstance(value, bool) or value not in (1, 2):
                raise InputError(f"effect {where!r}: key 'joint' of {self.name} must be 1 or 2, got {value!r}")
            return int(value)
        if spec.kind == "choice":
            if value not in spec.choices:
                raise InputError(
                    f"effect {where!r}: key {key!r} of {self.name} must be one of {', '.join(spec.choices)}, "
                    f"got {value!r}"
                )
            return value
        values = value if spec.kind == "pair" else (value,)
        if isinstance(values, str) or not isinstance(values, Sequence) or (spec.kind == "pair" and len(values) != 2):
            raise InputError(f"effect {where!r}: key {key!r} of {self.name} must be a pair [v1,v2], got {value!r}")
        return self._numbers(key, spec, values, where)

    def _numbers(self, key: str, spec: Key, values: Sequence, where: str) -> object:
        out = []
        for v in values:
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise InputError(f"effect {where!r}: key {key!r} of {self.name} must be a finite number, got {v!r}")
            low = spec.minimum
            if low is not None and (v < low or (spec.strict and v == low)):
                bound = f"> {low:g}" if spec.strict else f">= {low:g}"
                raise InputError(f"effect {where!r}: key {key!r} of {self.name} must be {bound}, got {v!r}")
            out.append(float(v))
        return tuple(out) if spec.kind == "pair" else out[0]

    def complete(self, params: dict, where: str, coulomb: tuple[tuple, tuple]) -> dict:
        """`params` checked, with defaults for the keys omitted and ``scale`` applied."""
        full = {k: self.check(k, v, where) for k, v in params.items()}
        for key in self.keys:
            if key not in full:
                full[key] = self.default(key, coulomb)
        scale = full.pop("scale", 1.0)
        return self.scaled(full, scale, coulomb)

    def default(self, key: str, coulomb: tuple[tuple, tuple]) -> object:
        """The value of an omitted key."""
        return self.keys[key].default

    def scaled(self, p: dict, s: float, coulomb: tuple[tuple, tuple]) -> dict:
        """Multiply the effect's magnitude (its `magnitude` keys) by `s`."""
        for key, spec in self.keys.items():
            if spec.magnitude:
                p[key] = tuple(s * x for x in p[key]) if spec.kind == "pair" else p[key] * s
        return p

    def is_active(self, p: dict, coulomb: tuple[tuple, tuple]) -> bool:
        """Whether the effect changes the trial at all (inactive ones are skipped: the trial is the clean one)."""
        sizes = [p[key] for key, spec in self.keys.items() if spec.magnitude]
        return any(any(v) if isinstance(v, tuple) else v > 0 for v in sizes)

    def describe(self, defaults_shown: bool = True) -> list[str]:
        """Lines for `--help`: the effect, then each key with its default and meaning."""
        lines = [f"  {self.name}: {self.summary}"]
        for key, spec in self.keys.items():
            default = "datasheet" if spec.default is None else _show(spec.default)
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
        """Change the true plant (`simulate.truth.PlantSpec`: π, model structure, sensors), in place."""

    def mechanism(self, plant, p: dict):
        """A mechanism that replaces the rigid arm (an elastic joint or link), or None."""
        return None

    def truth_entry(self, truth, p: dict) -> dict:
        """The effect in the truth file (`<trial>.truth.json`), in the diagnosis's estimate keys."""
        return dict(p)

    def true_physical(self, physical: dict, p: dict) -> None:
        """Change the truth file's rigid-body description of the true plant, in place."""

    # ------------------------------------------------------------------ diagnosis
    #: (rule, reason) when `resolved` can refuse an estimate: the rule goes into the reports.
    resolution: tuple[str, str] | None = None

    def families(self, robot) -> list:
        """The candidate model families (`diagnosis.candidates.Family`) that explain this cause."""
        return []

    def family(self, model=None, free: tuple[str, ...] = (), **options):
        """One candidate family of this cause: `model(θ)` (default: the nominal model) with the π names
        `free` freed against the datasheet (default: none) and the other `Family` fields in `options`."""
        return cands.Family(self.name, model or cands.nominal, free, **options)

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
    loop, whatever the plant, through the hooks below (used by `simulate.background`)."""

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


def per_joint_draw(rng, untouched: float, draw) -> tuple[float, float]:
    """A hidden per-joint value: joint 1, joint 2 or both (equally likely) take `draw()`, the others `untouched`."""
    values = [untouched, untouched]
    for j in ((0,), (1,), (0, 1))[int(rng.integers(3))]:
        values[j] = draw()
    return tuple(values)


def relative_error(estimate: float, true: float) -> float:
    """|estimate − true| / |true| (|estimate| when true is 0)."""
    return abs(estimate - true) / abs(true) if true != 0 else abs(estimate)


def _show(value: object) -> str:
    if isinstance(value, tuple):
        return "[" + ",".join(f"{v:g}" for v in value) + "]"
    return f"{value:g}" if isinstance(value, float) else str(value)
