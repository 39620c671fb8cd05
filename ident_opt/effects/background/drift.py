"""``drift``: a slow torque disturbance on the joints (cable drag, thermal), an Ornstein-Uhlenbeck process.

d(t) of standard deviation s and correlation time T, stationary from the start, per control tick Δt:

    d_{k+1} = a d_k + s √(1 − a²) ξ_k,   a = exp(−Δt / T),   ξ_k ~ N(0, 1).

The controller does not know it; the PD answers it, so it shows in the logged torque, mostly below 1 Hz.
"""

from __future__ import annotations

import math

from ident_opt.effects.base import Background, np
from ident_opt.effects.keys import Key


class Drift(Background):
    summary = "a slow torque disturbance on the joints (cable drag, thermal): an Ornstein-Uhlenbeck process"
    order = 2
    keys = {  # noqa: RUF012
        "std": Key("pair", (0.7, 0.2), "N m, its standard deviation, per joint", magnitude=True),
        "time": Key("float", 4.0, "s, its correlation time", 0.0, True),
    }
    disturbs = True

    def disturbance(self, p: dict, n: int, dt: float, rng) -> np.ndarray:
        out = np.zeros((n, 2))
        if n == 0:
            return out
        s, a = np.asarray(p["std"]), math.exp(-dt / p["time"])
        xi = rng.standard_normal((n, 2))
        out[0] = s * xi[0]  # stationary from the start
        kick = s * math.sqrt(1.0 - a * a) * xi
        for k in range(1, n):  # first-order recursion: a Python loop over 80 000 ticks costs ~50 ms
            out[k] = a * out[k - 1] + kick[k]
        return out


EFFECT = Drift()
