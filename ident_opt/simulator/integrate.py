"""The simulators' one integrator step: classical fourth-order Runge–Kutta on a CasADi expression.

Every simulated plant (the planar arm's closed loop `closed_loop`, any arm's `chain_loop`, the cut-off study's
`evaluation.cutoff_plant`) holds the torque over a control tick and takes a fixed number of these steps within it.
"""

from __future__ import annotations

from collections.abc import Callable

import casadi as ca
import numpy as np
from tqdm import tqdm


def rk4_step(f: Callable[[ca.SX], ca.SX], x: ca.SX, h) -> ca.SX:
    """x after one RK4 step of length h [s] of ẋ = f(x) (f: the state's rate as an expression of the state)."""
    k1 = f(x)
    k2 = f(x + h / 2 * k1)
    k3 = f(x + h / 2 * k2)
    k4 = f(x + h * k3)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def march(
    ticks: ca.Function, x0, refs: np.ndarray, constants: tuple = (), chunk: int = 2000, progress: bool = True
) -> np.ndarray:
    """A closed loop's outputs (width, N) along the per-tick inputs `refs` (k, N), from the state `x0`.

    `ticks`: one tick (x, ref, *constants) -> (x_next, out) accumulated over `chunk` ticks (`Function.mapaccum`,
    or its compiled C): called once per chunk, the last one padded with its final input (the padded ticks are
    dropped), with a progress bar in ticks."""
    total = refs.shape[1]
    out = None
    x = x0
    bar = tqdm(total=total, unit="tick", desc="simulate", disable=not progress, leave=False, unit_scale=True)
    for start in range(0, total, chunk):
        m = min(chunk, total - start)
        block = refs[:, start : start + m]
        if m < chunk:
            block = np.hstack([block, np.repeat(block[:, -1:], chunk - m, axis=1)])
        xs, outs = ticks(x, block, *constants)
        outs = np.asarray(outs)
        if out is None:
            out = np.empty((outs.shape[0], total))
        out[:, start : start + m] = outs[:, :m]
        x = xs[:, m - 1]
        bar.update(m)
    bar.close()
    return out if out is not None else np.empty((0, 0))
