"""What the one trial pipeline (`trial.simulate_trial`) asks of a kind of arm's simulator: a declared `Plant`.

A plant is the true arm the hidden effects shape (its model and π, friction, sensors, a mechanism), with the closed
loop that drives it along a reference and what its truth file says. Two implementations: `planar.PlanarPlant` (the
planar two-link arm's datasheet read physically, flexible links, tuned on the MERIt trials) and `chain.ChainPlant`
(any arm of n joints from a URDF, within its limits). `trial.PLANTS` (an `arm.kinds.ByKind`) picks the robot's.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol

import numpy as np

from ident_opt.simulator.trajectories import Reference


class Plant(Protocol):
    """A kind of arm's simulated trial (module doc). `requested`: the effects as asked (normalised); `effects`: the
    active ones; `elastic`: the mechanism whose deflection is logged (None: rigid); `sensors`: the measurement's
    noise σ and encoder steps where they are not the planar arm's (keywords of `measurement.log`)."""

    requested: Mapping
    effects: Mapping
    sensors: dict

    @property
    def elastic(self): ...

    def logged_torque(self, t: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The torque channel as logged at the control ticks t [s]: the applied τ (N, n) [N m] through the hidden
        effects on that channel."""
        ...

    def reference(self, settings: dict, control: float) -> Reference:
        """The reference the loop follows, sampled at the control rate `control` [Hz]."""
        ...

    def run(self, ref: Reference, control: float, settings: dict, progress: bool) -> np.ndarray:
        """The closed loop along `ref`: (N, ≥ 4n) τ, q_enc, dq_enc, ddq_enc, deflection at each tick."""
        ...

    def truth_file(self, out: np.ndarray, ref: Reference, settings: dict, scale: np.ndarray) -> dict:
        """The ground truth, JSON-able, effects in the diagnosis's estimate keys (`docs/effects.md`)."""
        ...


def plain(value):
    """JSON-able copy (tuples to lists, NumPy scalars to floats)."""
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value
