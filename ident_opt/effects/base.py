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
import pkgutil
from collections.abc import Sequence

from ident_opt.effects.families import PlanarFamily
from ident_opt.effects.keys import Joints, Key, Syntax
from ident_opt.effects.lazy import DEFERRED, deferred
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


class Effect(Syntax):
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
    #: The estimate's physical ranges and its searches' bounds, as data (each cause's `PLAUSIBLE`): entries {"key",
    #: "least"/"most"/"most_abs"/"most_norm"/"most_sag", "search", "se", "unless", "unit", "why"}, which one rule reads
    #: for every cause (`diagnosis.plausibility`, docs/effects.md "Plausibility").
    plausible: tuple[dict, ...] = ()

    def families(self, ctx) -> list:
        """The candidate families (`effects.families.PlanarFamily`) that explain this cause on the planar arm, in the
        planar engine's context `ctx` (`diagnosis.planar.families.Context`: the robot, the nominal model, …)."""
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
    def chain_families(self, ctx) -> list:
        """The candidate families (`effects.families.ChainFamily`) of this cause on an n-joint arm, in the chain
        engine's context `ctx` (`diagnosis.chain.search.ChainContext`: the arm, the evidence per joint, the screens)."""
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
    #: Whether the term acts on any arm (the n-joint simulator adds its `disturbance` too), not the planar one's only.
    any_arm: bool = False

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


def discover(package: str, path: Sequence[str]) -> dict[str, Effect]:
    """The ``EFFECT`` of every module of `package` (at `path`) that defines one (the shared modules, `base`, `keys`,
    `families`, `lazy`, define none), name -> effect, by `Effect.order`."""
    modules = (importlib.import_module(f"{package}.{info.name}") for info in pkgutil.iter_modules(path))
    found = [m.EFFECT for m in modules if isinstance(getattr(m, "EFFECT", None), Effect)]
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
