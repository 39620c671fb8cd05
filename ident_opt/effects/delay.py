"""``delay``: the torque (or current) channel lags the encoder channel."""

from __future__ import annotations

from functools import partial

from ident_opt.effects.base import Effect, Key, deferred

np = deferred("numpy")


class Delay(Effect):
    name = "delay"
    summary = "the torque (or current) channel lags the encoder channel"
    order = 6
    keys = {"seconds": Key("float", 0.02, "s", magnitude=True)}  # noqa: RUF012

    # ------------------------------------------------------------------ simulator: the logged torque lags
    def true_plant(self, plant, p: dict) -> None:
        plant.channel.append(partial(delayed, p["seconds"]))


def delayed(seconds: float, t: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """τ (N, 2) at the ticks t [s] as a channel lagging by `seconds` logs it: what is logged at t was applied
    at t − d (linear interpolation; held at the start before that)."""
    return np.column_stack([np.interp(t - seconds, t, tau[:, j]) for j in range(2)])


EFFECT = Delay()
