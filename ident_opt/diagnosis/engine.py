"""What the one diagnosis loop (`rounds.diagnose_trial`) asks of an arm kind: a declared engine.

An engine holds the diagnosis's data (the training and held-out parts, `Parts`), its two nominal models (`Nominal`:
the datasheet's π and the rigid fit's, their held-out predictions) and the context its candidates are fitted in,
and offers the candidate families of the catalogue's causes (each cause's own module declares them,
`ident_opt.effects`), how a family is fitted against a baseline, composed with the causes named before it and held
at its θ, and how the extended model's motion is integrated (question 4). Two implementations:
`diagnosis.planar.PlanarEngine` (the planar two-link arm's grouped π, flexible links, tuned on the MERIt trials) and
`diagnosis.chain.ChainEngine` (any arm of n joints from a URDF). `ENGINES` (an `arm.kinds.ByKind`) picks the
robot's: the one place the diagnosis asks which kind of arm it has.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from ident_opt.arm.base import Arm
from ident_opt.data.dataset import Dataset
from ident_opt.diagnosis.nominal import NominalFit


@dataclass(frozen=True)
class Request:
    """What the loop hands an engine to build itself on: the trial to diagnose, an unseen trial for the held-out
    part (None: the trial's last `1 - train_fraction` is held out), the torque low-pass setting (`split.prepare`),
    the rigid fit's estimator (a name of `ident_opt.fitting.estimators`) and the identified arm that stands in for the
    datasheet, if any."""

    trial: Dataset
    unseen: Dataset | None
    train_fraction: float
    torque_filter_hz: float | str | None
    estimator: str
    #: An identified arm in place of the datasheet (`nominal.NominalFit`; None: the problem's datasheet).
    nominal: NominalFit | None = None


@dataclass
class Parts:
    """The diagnosis's data: the training and held-out parts as prepared (torque low-passed like the derivatives,
    velocities at rest held at 0), the held-out part's measured torque as logged (what `nmse_before`/`nmse_after`
    are measured against), the split in words, and the trial an unseen held-out trial was paired with (None: the
    held-out part is a piece of the training trial)."""

    train: Dataset
    test: Dataset
    raw_test: Dataset
    how: str
    source: Dataset | None = None


@dataclass
class Nominal:
    """The two nominal models by baseline ("datasheet", "rigid_fit"): their π (P,) of `model`, their held-out
    predictions (N, n) [N m], the parameters a refitted π counts (`rigid_parameters`), the held-out part's labels
    the engine scores with (`rest_test`, `signals.rest_runs`), and extra keys of the rigid fit's JSON entry."""

    model: Arm
    pi: dict[str, np.ndarray]
    pred: dict[str, np.ndarray]
    rigid_parameters: int
    rest_test: np.ndarray
    extra: dict = field(default_factory=dict)


class Engine(Protocol):
    """An arm kind's side of the diagnosis (module doc), built as `Kind(robot, request)` (a `Request`). `Family` and
    `Candidate` are the engine's own types: the loop only passes them back (`family.cause`, `family.nests`,
    `family.baselines`; `cand.cause`, `cand.estimate`, `cand.detail`, `cand.n_added`, `cand.predict(ds)`)."""

    #: The least share of a joint's torque variance a named cause removes (`scoring.shortfall`).
    margin_variance: float
    #: The least share of a refitted π's log-gain a datasheet-side cause explains to be taken on trial.
    partner: float
    #: Whether later rounds search every cause's θ again, or only the first round's promising ones.
    search_again: bool
    parts: Parts
    nominal: Nominal

    def families(self) -> list:
        """Every catalogue cause's candidate families on this arm, in catalogue order."""
        ...

    def fit(self, family, baseline: str):
        """`family` fitted against `baseline` ("datasheet" or "rigid_fit") on the training part: a candidate."""
        ...

    def compose(self, earlier: list[tuple], new):
        """One family for `new` with the causes named before it (each (family, θ), θ held)."""
        ...

    def frozen(self, family, theta: dict):
        """`family` with its θ held at `theta`: only its linear coefficients move."""
        ...

    def theta(self, family, cand) -> dict:
        """The θ a later round holds `family`'s cause at, from its fitted candidate."""
        ...

    def forward_after(self, final, baseline: str) -> list:
        """Question 4's motion error [rad] of the extended model (`final`: its fitted version, None: no cause)."""
        ...

    #: The pose evidence of a residual (`evidence.pose_r2` or `pose_r2_any`): (q, r) -> R² per joint.
    pose: Callable

    def screening(self) -> dict | None:
        """What the engine's screening found, for the JSON's evidence (None: it has none)."""
        ...

    #: The request the engine was built on, and the torque low-pass's cut-off it applied [Hz] (None: none).
    request: Request
    filter_hz: float | None
    #: The datasheet parameters an identified nominal (`Request.nominal`) gave no value for, kept as they were.
    kept: list[str]
    #: The arm's moving links' mass [kg] (0: unknown) and the chain's length [m] (None: no centre of mass to bound):
    #: the plausibility rule's payload bounds (`plausibility.facts`).
    moving_mass: float
    reach: float | None

    def other(self, trial: Dataset) -> tuple[Dataset, Dataset, np.ndarray]:
        """Another trial read as the held-out part is (prepared alike): (prepared, its torque as logged on the same
        samples, the labels the engine scores with): where a named cause is confirmed (`confirm`)."""
        ...

    def nominal_prediction(self, baseline: str, ds: Dataset) -> np.ndarray:
        """The nominal model `baseline`'s torque (N, n) [N m] along a prepared trial `ds`."""
        ...

    def leave_implausible(self, failing: Callable) -> None:
        """Hand the engine the plausibility rule's per-joint failures (`failing(cause, estimate, detail) -> {joint:
        [why]}`, `plausibility.failing_joints`): an engine whose per-joint candidates can be fitted again without a
        joint does so (the n-joint engine, `chain.families.fit`); the planar engine's two-joint families cannot."""
        ...


@dataclass(frozen=True)
class FamilyFunctions:
    """An arm kind's candidate functions, as its families modules define them: `fit(family, baseline, ctx)`,
    `compose(earlier, new)`, `frozen(family, theta)` and `theta(family, cand, ctx)`."""

    fit: Callable
    compose: Callable
    frozen: Callable
    theta: Callable


class OverFunctions:
    """`Engine.fit`, `compose`, `frozen` and `theta` as an engine's `functions` (a `FamilyFunctions`) called with
    its context `ctx`: how both engines implement them."""

    functions: FamilyFunctions
    ctx: object

    def fit(self, family, baseline: str):
        return self.functions.fit(family, baseline, self.ctx)

    def compose(self, earlier: list[tuple], new):
        return self.functions.compose(earlier, new)

    def frozen(self, family, theta: dict):
        return self.functions.frozen(family, theta)

    def theta(self, family, cand) -> dict:
        return self.functions.theta(family, cand, self.ctx)
