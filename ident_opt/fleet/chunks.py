"""A long trial filtered and differentiated in pieces, each with as much of its neighbours as the zero-phase filter
needs: what `numerics.derivatives` computes on the whole trial, with memory that does not grow with its length.

The whole-trial estimate of a uniform, gap-free segment: the angles low-passed forward and backward (4th-order
Butterworth, second-order sections, the segment's ends extended by local cubics: `derivatives.edge_extensions`),
central differences (`np.gradient` on t), the velocity low-passed the same way, central differences again. A
piece [a, b) is computed from the samples [a − M, b + M) (clipped to the segment): its ends extended as the
segment's only where they are the segment's ends; elsewhere the filter starts from the steady state of its first
sample (`sosfiltfilt` with no padding), and that start-up transient is what separates the piece from the whole.

The transient of a stable filter decays with its poles: after k samples it is below the ℓ1 tail Σ_{i≥k} |h_i| of
the impulse response h, relative to Σ|h|. `transient_samples` finds the k where that tail falls below `TRANSIENT`
(computed out to the slowest pole's horizon, where |p|^k is below it squared) plus the samples the slowest pole
takes to shrink anything by a further `SAFETY`: what the constants of a transient could add. Each of the two
passes loses that many samples at each end of the piece, each central difference one: M = 2 L + 2.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np
from scipy import signal

from ident_opt.numerics.derivatives import MIN_SEGMENT, edge_extensions, zero_phase_sos

#: What may be left of a start-up transient where a piece's output begins, relative to the transient itself.
TRANSIENT = 1e-15
#: A further factor the slowest pole must shrink the transient by (margin for the transient's constants).
SAFETY = 1e-3


def _slowest_pole(sos: np.ndarray) -> float:
    """|p| of the cascade's slowest pole (the one nearest the unit circle)."""
    return float(max(np.abs(np.roots(section[3:])).max() for section in sos))


def transient_samples(sos: np.ndarray, tol: float = TRANSIENT) -> int:
    """Samples after which a start-up transient of the cascade `sos` is below `tol` of itself (module doc)."""
    radius = _slowest_pole(sos)
    horizon = int(np.ceil(2 * np.log(tol) / np.log(radius))) + 8
    impulse = np.zeros(horizon)
    impulse[0] = 1.0
    h = np.abs(signal.sosfilt(sos, impulse))
    tail = np.cumsum(h[::-1])[::-1]  # tail[k] = Σ_{i≥k} |h_i|
    below = int(np.argmax(tail <= tol * tail[0]))
    return below + int(np.ceil(np.log(SAFETY) / np.log(radius)))


def margin(fs: float, *cutoffs_hz: float) -> int:
    """Samples M a piece needs on each side for the derivatives at every one of `cutoffs_hz` [Hz] (module doc)."""
    lengths = [transient_samples(sos) for c in cutoffs_hz if (sos := zero_phase_sos(c, fs)) is not None]
    return 2 * max(lengths, default=0) + 2


@dataclass
class Window:
    """A piece of the segment: its samples [lo, lo + len) by name, its output range [a, b) (indices in the
    segment), and whether it holds the segment's first and last sample."""

    arrays: dict[str, np.ndarray]
    lo: int
    a: int
    b: int
    first: bool
    last: bool

    @property
    def core(self) -> slice:
        """The output range within the piece's arrays."""
        return slice(self.a - self.lo, self.b - self.lo)


def windows(blocks: Iterable[dict[str, np.ndarray]], size: int, margin: int) -> Iterator[Window]:
    """The segment given as consecutive `blocks` (arrays by name, of any lengths) cut into pieces of `size`
    outputs, each with `margin` samples of its neighbours on each side (fewer at the segment's ends); what is held
    at once is at most about size + 2·margin + one block."""
    held: dict[str, np.ndarray] = {}
    start = end = out = 0  # held covers [start, end); outputs so far end at `out`
    source = iter(blocks)
    done = False
    while not done:
        while end - out < size + margin:
            block = next(source, None)
            if block is None:
                done = True
                break
            held = {k: np.concatenate([held[k], v]) if held else v for k, v in block.items()}
            end += len(block["t"])
        if end == out:
            return
        b = end if done else out + size
        lo, hi = max(start, out - margin), end if done else b + margin
        arrays = {k: v[lo - start : hi - start] for k, v in held.items()}
        yield Window(arrays, lo, out, b, lo == 0, done)
        out = b
        keep = max(start, out - margin)
        held = {k: v[keep - start :] for k, v in held.items()}
        start = keep


def _filtfilt(sos, x: np.ndarray, fs: float, cutoff_hz: float, w: Window, n: int) -> np.ndarray:
    """`x` over the piece `w` low-passed forward and backward, its ends extended as the segment's (of `n` samples)
    where they are the segment's ends."""
    if len(x) <= MIN_SEGMENT:
        raise ValueError(f"a piece of {len(x)} samples is too short to filter as part of a segment")
    left, right = edge_extensions(x, fs, cutoff_hz, n)
    left = left if w.first else left[:0]
    right = right if w.last else right[:0]
    y = signal.sosfiltfilt(sos, np.concatenate([left, x, right]), axis=0, padtype=None)
    return y[len(left) : len(left) + len(x)]


def lowpassed(w: Window, key: str, fs: float, cutoff_hz: float, n: int) -> np.ndarray:
    """`derivatives.lowpass` of signal `key` on the piece's output range (segment of `n` samples at `fs` [Hz])."""
    x = w.arrays[key]
    sos = zero_phase_sos(cutoff_hz, fs)
    return (x if sos is None else _filtfilt(sos, x, fs, cutoff_hz, w, n))[w.core]


def derivatives(w: Window, key: str, fs: float, cutoff_hz: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(velocity, acceleration) of signal `key` on the piece's output range, as `derivatives.estimate_derivatives`
    gives them for the whole uniform segment of `n` samples at `fs` [Hz] (module doc)."""
    t, x = w.arrays["t"], w.arrays[key]
    sos = zero_phase_sos(cutoff_hz, fs) if n > MIN_SEGMENT else None

    def smooth(values: np.ndarray) -> np.ndarray:
        return values if sos is None else _filtfilt(sos, values, fs, cutoff_hz, w, n)

    v = np.gradient(smooth(x), t, axis=0)
    a = np.gradient(smooth(v), t, axis=0)
    return v[w.core], a[w.core]
