"""The loader's rest rule (`data.dataset.at_rest`) on a trial read in pieces: each joint's speed scale (the 95th
percentile of |q̇| over the kept samples) in flat memory, then the rest mask with the few samples of look-ahead and
look-behind `signals.resting` asks, carried from piece to piece.

The percentile is exact, in two counting passes: the first counts |q̇| per joint into a fixed set of bins that
keep the order of the values (the float's exponent and its mantissa's first 8 bits), which tells in which bins the
two order statistics `np.quantile` interpolates between lie; the second keeps only the values in those bins, and
sorts them. A bin spans 1/256 of its values' magnitude: a small share of a trial's samples, not all of them.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

from ident_opt.numerics.signals import HOLD_WINDOW_S, REST_FRACTION, quiet_runs

#: Mantissa bits a bin keeps, and the powers of two binned: |q̇| below 2^LOW (1e-9 rad/s) shares one bin, and the
#: loader's plausibility limits keep every velocity far below 2^HIGH. Dense counts: 16385 per joint.
BITS, LOW, HIGH = 8, -30, 34
N_BINS = 1 + (HIGH - LOW) * (1 << BITS)
QUANTILE = 0.95  # `signals.rest_speed`


def _bins(v: np.ndarray) -> np.ndarray:
    """The order-keeping bin of each value of v ≥ 0 (module doc)."""
    m, e = np.frexp(v)  # v = m · 2^e, m in [0.5, 1)
    e = np.clip(e, LOW + 1, HIGH)
    bins = 1 + (e - LOW - 1) * (1 << BITS) + np.floor((m - 0.5) * (1 << (BITS + 1))).astype(np.int64)
    return np.where(v >= 2.0**LOW, np.minimum(bins, N_BINS - 1), 0)


class SpeedScale:
    """Each joint's 95th percentile of |q̇| over the samples shown, from two passes over the same samples:
    `count` every piece, then `collect` every piece again, then `value`."""

    def __init__(self, n_joints: int) -> None:
        self.counts = np.zeros((n_joints, N_BINS), dtype=np.int64)
        self.kept: list[list[np.ndarray]] = [[] for _ in range(n_joints)]
        self.wanted: list[tuple[int, int, int]] | None = None  # per joint: (first bin, last bin, samples below)

    def count(self, v: np.ndarray) -> None:
        """Pass 1: one piece's velocities (k, n) [rad/s]."""
        for j in range(v.shape[1]):
            self.counts[j] += np.bincount(_bins(np.abs(v[:, j])), minlength=N_BINS)

    def _ranks(self) -> tuple[int, float]:
        n = int(self.counts[0].sum())
        return n, QUANTILE * (n - 1)

    def _plan(self) -> None:
        n, h = self._ranks()
        k0, k1 = int(np.floor(h)), min(int(np.floor(h)) + 1, n - 1)
        self.wanted = []
        for c in self.counts:
            cum = np.cumsum(c)
            i0, i1 = int(np.searchsorted(cum, k0, side="right")), int(np.searchsorted(cum, k1, side="right"))
            self.wanted.append((i0, i1, int(cum[i0 - 1]) if i0 else 0))

    def collect(self, v: np.ndarray) -> None:
        """Pass 2: the same piece again; only the values in the two order statistics' bins are kept."""
        if self.wanted is None:
            self._plan()
        for j, (lo, hi, _) in enumerate(self.wanted):
            a = np.abs(v[:, j])
            k = _bins(a)
            self.kept[j].append(a[(k >= lo) & (k <= hi)])

    def value(self) -> np.ndarray:
        """(n,) [rad/s]: the 95th percentile of |q̇| per joint, as `np.quantile(|q̇|, 0.95)` reads it."""
        n, h = self._ranks()
        k0 = int(np.floor(h))
        out = []
        for (_, _, below), kept in zip(self.wanted, self.kept):
            x = np.sort(np.concatenate(kept))
            a = x[k0 - below]
            b = x[min(k0 + 1, n - 1) - below]
            out.append(float(np.quantile(np.array([a, b]), h - k0)))  # numpy's own interpolation between the two
        return np.array(out)


def held(
    pieces: Iterable[tuple[np.ndarray, dict]], rest_speed: np.ndarray, dt: float
) -> Iterator[tuple[dict, np.ndarray]]:
    """The pieces (velocities (k, n) [rad/s] and a dict of arrays of the same samples) in order, as parts (a dict of
    those arrays cut to the part, its rest mask (k', n)) as `signals.resting` gives it for the whole trial at step
    `dt` [s] and rest speed `rest_speed` (n,) [rad/s] (the loader's window, `signals.HOLD_WINDOW_S`), its ends
    padded with their own flags. A sample's mask needs the w = HOLD_WINDOW_S / dt flags after it: each piece is given
    but its last w samples, which go with the next (so what is held between pieces is w samples, not a piece)."""
    w = max(1, round(HOLD_WINDOW_S / dt))
    behind: np.ndarray | None = None  # the w flags before the next sample given
    carry: tuple[dict, np.ndarray] | None = None  # samples not given yet: their arrays and flags

    def part(arrays: dict, slow: np.ndarray, until: int, after: np.ndarray) -> tuple[dict, np.ndarray]:
        """The first `until` samples of (arrays, slow), `after` the flags that follow them, at least w."""
        nonlocal behind
        quiet = quiet_runs(np.concatenate([behind, slow[:until], after[:w]]), w + 1)
        behind = np.concatenate([behind, slow[:until]])[-w:]
        return {k: v[:until] for k, v in arrays.items()}, slow[:until] & (quiet[:until] | quiet[w : w + until])

    for v, arrays in pieces:
        slow = np.abs(v) < rest_speed
        if behind is None:
            behind = np.repeat(slow[:1], w, axis=0)
        if carry is not None:
            if len(slow) < w:  # too short to be the carry's look-ahead: both wait for the next piece (small)
                arrays = {k: np.concatenate([carry[0][k], x]) for k, x in arrays.items()}
                carry = (arrays, np.concatenate([carry[1], slow]))
                continue
            yield part(*carry, len(carry[1]), slow)
        if len(slow) > w:
            yield part(arrays, slow, len(slow) - w, slow[len(slow) - w :])
            carry = ({k: x[len(slow) - w :] for k, x in arrays.items()}, slow[len(slow) - w :])
        else:
            carry = (arrays, slow)
    if carry is not None:
        yield part(*carry, len(carry[1]), np.repeat(carry[1][-1:], w, axis=0))


def unheld(pieces: Iterable[tuple[np.ndarray, dict]]) -> Iterator[tuple[dict, np.ndarray]]:
    """The pieces as `held` gives them, no sample at rest (`[data] rest_velocity = "as_read"`)."""
    for v, arrays in pieces:
        yield arrays, np.zeros(v.shape, dtype=bool)


def speed_to_rest(scale: np.ndarray) -> np.ndarray:
    """(n,) [rad/s]: the rest speed of a speed scale (`signals.rest_speed`)."""
    return REST_FRACTION * scale
