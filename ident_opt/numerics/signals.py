"""Signal tools the evidence and the candidates share: a fractional delay, the elastic-mode filter, spectra.

All assume (near-)uniform sampling with step dt [s]; time runs along axis 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage, signal

from ident_opt.numerics.derivatives import lowpass

#: The diagnosis's default torque filter cut-off [Hz] (`diagnosis.prepare`): the data loader's and the
#: simulator's derivative cut-off, so both sides of τ = Y π share one bandwidth.
TORQUE_FILTER_HZ = 15.0


def delayed(x: np.ndarray, seconds: float, dt: float) -> np.ndarray:
    """x(t − d) on the same grid, by linear interpolation between samples (d ≥ 0; the first samples repeat
    x[0]). Linear in x, so delaying each regressor column delays the whole prediction."""
    steps = max(seconds, 0.0) / dt
    m = int(np.floor(steps))
    frac = steps - m
    n = x.shape[0]
    idx = np.arange(n)
    a = x[np.clip(idx - m, 0, n - 1)]
    b = x[np.clip(idx - m - 1, 0, n - 1)]
    return (1.0 - frac) * a + frac * b


def deflection_acceleration(ddq: np.ndarray, frequency_hz: float, damping: float, dt: float) -> np.ndarray:
    """Acceleration ë [rad/s²] of an elastic link's deflection e = q_link − θ_motor, driven by the measured
    motor-side acceleration θ̈ (motor held on its measured path):

        ë + 2ζω ė + ω² e = −θ̈     ⇒     ë = −s² / (s² + 2ζω s + ω²) · θ̈,     ω = 2π f.

    The link then adds m_eff·ë to the torque the rigid model predicts from θ (its stiffness is k = m_eff ω²).
    Discretised by the bilinear transform pre-warped at ω, so the mode sits at f exactly.
    """
    fs = 1.0 / dt
    w = 2.0 * fs * np.tan(np.pi * frequency_hz / fs)  # pre-warped ω [rad/s]
    K = 2.0 * fs  # s = K (z − 1) / (z + 1)
    den = np.array([K * K + 2 * damping * w * K + w * w, 2 * (w * w - K * K), K * K - 2 * damping * w * K + w * w])
    num = np.array([-K * K, 2 * K * K, -K * K])
    return signal.lfilter(num / den[0], den / den[0], ddq, axis=0)


def deflection(drive: np.ndarray, frequency_hz: float, damping: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(e, ë) of a deflection driven as `deflection_acceleration`'s, ë + 2ζω ė + ω² e = −drive [rad/s²]: the
    deflection itself [rad] too (its stiffness torque, a gravity load's shift), by the same pre-warped bilinear
    transform, from the static deflection of the first drive (not from zero: a load there from the start, gravity,
    would otherwise ring the mode for seconds at the start of every stretch of data)."""
    fs = 1.0 / dt
    w = 2.0 * fs * np.tan(np.pi * frequency_hz / fs)
    K = 2.0 * fs
    den = np.array([K * K + 2 * damping * w * K + w * w, 2 * (w * w - K * K), K * K - 2 * damping * w * K + w * w])
    a = den / den[0]
    out = []
    for num in (-np.array([1.0, 2.0, 1.0]), np.array([-K * K, 2 * K * K, -K * K])):
        b = num / den[0]
        # at rest in the first drive: a load present from the start (gravity) is a static deflection, not a step
        zi = signal.lfilter_zi(b, a) * drive[0]
        out.append(signal.lfilter(b, a, drive, axis=0, zi=zi)[0])
    return out[0], out[1]


@dataclass
class Peak:
    """A spectral peak: frequency [Hz], damping ratio from the half-power bandwidth, prominence [dB]."""

    frequency_hz: float
    damping: float
    prominence_db: float

    def as_dict(self) -> dict[str, float]:
        return {
            "frequency_hz": self.frequency_hz,
            "damping": self.damping,
            "prominence_db": self.prominence_db,
        }


def spectrum(x: np.ndarray, dt: float, window_s: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """Welch power spectral density of a 1-D signal (mean removed): (frequencies [Hz], PSD [unit²/Hz])."""
    x = np.asarray(x, dtype=float) - np.mean(x)
    nperseg = int(min(len(x), max(16, round(window_s / dt))))
    return signal.welch(x, fs=1.0 / dt, nperseg=nperseg)


def peaks(
    x: np.ndarray,
    dt: float,
    low_hz: float = 0.7,
    count: int = 3,
    min_prominence_db: float = 6.0,
    window_s: float = 10.0,
) -> list[Peak]:
    """The most prominent spectral peaks of x above `low_hz` (the motion band lies below), strongest first.

    Damping comes from the half-power (−3 dB) bandwidth: ζ ≈ (f₂ − f₁) / (2 f₀), a lower bound on the
    resolution (window_s) — a lightly damped mode reads as narrow as the window allows.
    """
    f, p = spectrum(x, dt, window_s)
    band = (f >= low_hz) & (f <= 0.45 / dt)
    if band.sum() < 5 or not np.any(p[band] > 0):
        return []
    db = 10 * np.log10(np.maximum(p, 1e-300))
    fb, dbb = f[band], db[band]
    idx, props = signal.find_peaks(dbb, prominence=min_prominence_db)
    order = np.argsort(props["prominences"])[::-1][:count]
    out = []
    for i in idx[order]:
        half = dbb[i] - 3.0
        lo = i
        while lo > 0 and dbb[lo] > half:
            lo -= 1
        hi = i
        while hi < len(dbb) - 1 and dbb[hi] > half:
            hi += 1
        f1 = np.interp(half, [dbb[lo], dbb[lo + 1]], [fb[lo], fb[lo + 1]]) if lo < i else fb[i]
        f2 = np.interp(half, [dbb[hi], dbb[hi - 1]], [fb[hi], fb[hi - 1]]) if hi > i else fb[i]
        out.append(Peak(float(fb[i]), float((f2 - f1) / (2 * fb[i])), float(props["prominences"][list(idx).index(i)])))
    return out


def band_fraction(x: np.ndarray, dt: float, below_hz: float) -> float:
    """Fraction of x's power (mean removed) below `below_hz`."""
    f, p = spectrum(x, dt)
    total = float(np.sum(p))
    return float(np.sum(p[f < below_hz]) / total) if total > 0 else float("nan")


def lag(reference: np.ndarray, x: np.ndarray, dt: float, max_s: float = 0.2) -> float:
    """The delay d [s] (positive: x lags reference) maximising the cross-correlation of x with reference,
    refined between samples by a parabola through the peak."""
    a = np.asarray(reference, dtype=float) - np.mean(reference)
    b = np.asarray(x, dtype=float) - np.mean(x)
    m = int(min(len(a) - 1, max(1, round(max_s / dt))))
    shifts = np.arange(-m, m + 1)
    c = np.array([np.dot(a[max(0, -s) : len(a) - max(0, s)], b[max(0, s) : len(b) - max(0, -s)]) for s in shifts])
    i = int(np.argmax(c))
    offset = 0.0
    if 0 < i < len(c) - 1:
        den = c[i - 1] - 2 * c[i] + c[i + 1]
        offset = 0.5 * (c[i - 1] - c[i + 1]) / den if den != 0 else 0.0
    return float((shifts[i] + offset) * dt)


#: A joint (or drive) moving slower than this fraction of its speed scale (95th percentile of |v|) is at rest.
REST_FRACTION = 0.01
#: How long [s] it must stay slow, before or after a sample, for it to count as at rest (the diagnosis's rule).
REST_WINDOW_S = 0.01
#: The loader's longer window (`data.dataset.at_rest`): a stop, not a smooth reversal. A reversal is slow for
#: 2·REST_FRACTION·(95th-percentile speed)/|q̈|, about 0.02/ω for a sine of ω rad/s: longer than 10 ms for any
#: motion slower than 2 rad/s, so the diagnosis's window held the reversals of a swinging passive joint, whose
#: friction flips there (the cut-off study's passive trials: parameter errors up to 1.2× those of the velocities as
#: read); 50 ms spares every reversal of a motion faster than a 15 s period and keeps every stop.
HOLD_WINDOW_S = 0.05
#: The n-joint diagnosis compares only samples moving faster than this many rest speeds (`rest_speed`): slower, a
#: joint may be held by stiction, whose torque is anything up to the static friction level, following what the
#: controller commands. Within a stop that torque ramps by N m on a clean simulated TX40 (a Fourier trajectory's
#: joint 2: 2.7 N m RMS about each stop's mean, 0.7 N m up to 2 rest speeds, 0.08 N m beyond, for 0.06 N m sensor
#: noise), which no cause of the catalogue predicts and a Stribeck hump narrower than the band fitted instead.
STICK_SPEEDS = 2.0


def rest_speed(v: np.ndarray) -> np.ndarray:
    """(m,) [rad/s]: the speed below which each velocity column of v (N, m) reads as at rest (`resting`),
    `REST_FRACTION` of its speed scale (95th percentile of |v|)."""
    return REST_FRACTION * np.quantile(np.abs(v), 0.95, axis=0)


def stick_speed(v: np.ndarray) -> np.ndarray:
    """(m,) [rad/s]: the speed below which each velocity column of v (N, m) may be held by stiction, `STICK_SPEEDS` ×
    its rest speed (`rest_speed`): the n-joint diagnosis compares only faster samples."""
    return STICK_SPEEDS * rest_speed(v)


def resting(v: np.ndarray, dt: float, window_s: float = REST_WINDOW_S) -> np.ndarray:
    """(N, m) bool: the samples where each velocity column of v (N, m) [rad/s] at step `dt` [s] is at rest: below
    `REST_FRACTION` of its speed scale (95th percentile of |v|) there, and staying below it for `window_s` before
    or after (the filter ringing just before a start or after a stop counts as rest, a smooth reversal, slow only for an
    instant, does not). The rule of `data.dataset.at_rest` (joints) and `chain.context.ArmContext` (drives)."""
    w = max(1, round(window_s / dt))
    slow = np.abs(v) < rest_speed(v)
    quiet = quiet_runs(np.pad(slow, ((w, w), (0, 0)), mode="edge"), w + 1)
    before, after = quiet[: len(v)], quiet[w : w + len(v)]
    return slow & (before | after)


def quiet_runs(slow: np.ndarray, k: int) -> np.ndarray:
    """(len(slow) − k + 1, m) bool: whether each column of `slow` (N, m) is True throughout the k samples starting
    at each index; by running counts, so its cost does not grow with k (a log whose time unit is wrong can make k
    huge)."""
    counts = np.concatenate([np.zeros((1, slow.shape[1]), dtype=np.int64), np.cumsum(slow, axis=0, dtype=np.int64)])
    return counts[k:] - counts[:-k] == k


def rest_runs(dq: np.ndarray, below: np.ndarray | None = None) -> np.ndarray:
    """Labels (N, m): for each joint, the index of the rest stretch a sample belongs to (a run of dq = 0
    exactly, as `data.dataset.at_rest` leaves it), −1 where the joint moves. With `below` (m,) [rad/s], every sample of
    joint j slower than below_j (rests included) is a stretch of its own instead: its mean is itself, so
    `demean_runs` removes it from every fit and score (`STICK_SPEEDS`)."""
    labels = np.full(dq.shape, -1, dtype=int)
    for j in range(dq.shape[1]):
        if below is not None:
            slow = np.abs(dq[:, j]) < below[j]
            labels[slow, j] = np.arange(int(slow.sum()))
            continue
        rest = dq[:, j] == 0
        run = np.cumsum(rest & ~np.concatenate([[False], rest[:-1]])) - 1  # +1 at each stretch's start
        labels[rest, j] = run[rest]
    return labels


def near_stops(dq: np.ndarray, dt: float, stop_s: float, within_s: float) -> np.ndarray:
    """(N, 2) bool: the samples of each joint within `within_s` [s] of a rest stretch (dq = 0 exactly, as
    `data.dataset.at_rest` leaves it) that lasts at least `stop_s` [s] — a stop or a start, not the slow instant
    of a reversal."""
    out = np.zeros(dq.shape, dtype=bool)
    shortest, reach = max(1, round(stop_s / dt)), round(within_s / dt)
    for j in range(dq.shape[1]):
        labels, n = ndimage.label(dq[:, j] == 0)
        if n == 0:
            continue
        long = np.concatenate([[False], np.bincount(labels.ravel())[1:] >= shortest])[labels]
        out[:, j] = ndimage.binary_dilation(long, iterations=reach) if reach > 0 and long.any() else long
    return out


def demean_runs(x: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """x (N, 2, ...) with, for each joint, the mean over each of its rest stretches removed (a copy).

    While a joint rests, stiction holds whatever torque the controller leaves on it, a per-stretch constant no
    model here predicts; removing each stretch's mean from data and prediction alike compares only the
    variation within it (ringing after a stop survives; the held level does not count)."""
    out = np.array(x, dtype=float, copy=True)
    for j in range(labels.shape[1]):
        rest = labels[:, j] >= 0
        if not rest.any():
            continue
        lab = labels[rest, j]
        counts = np.bincount(lab)
        block = out[rest, j]
        flat = block.reshape(len(lab), -1)
        for c in range(flat.shape[1]):
            flat[:, c] -= (np.bincount(lab, weights=flat[:, c]) / counts)[lab]
        out[rest, j] = flat.reshape(block.shape)
    return out


#: Cut-offs [Hz] `matched_cutoff` tries, from this lowest one up to `MATCH_TOP` of the sampling rate.
MATCH_LOWEST_HZ, MATCH_TOP, MATCH_GRID = 1.0, 0.45, 48
#: A logged acceleration that the best Butterworth of the grid imitates worse than this (relative squared error)
#: is not a low-passed second derivative of the angles at all (zeros, another signal): the torque is then left
#: unfiltered. A Savitzky–Golay filter's side lobes leave up to 0.18 on a motion with lines in them (21 samples
#: at 100 Hz, a line at 6.7 Hz); exact accelerations are imitated best by the grid's top (no filter either).
MATCH_MISFIT = 0.5


def matched_cutoff(t: np.ndarray, q: np.ndarray, ddq: np.ndarray) -> float | None:
    """The cut-off [Hz] of the zero-phase Butterworth (`derivatives.lowpass`) that, applied to the angles' second
    difference, best reproduces the logged accelerations `ddq`: the bandwidth of a logger's own derivative filter
    (a Savitzky–Golay filter, say), which the torque must share for τ = Y π to compare like with like. None when
    none imitates them (`MATCH_MISFIT`) or the best is the grid's top (the accelerations are not low-passed).

    The second difference (q[k+1] − 2 q[k] + q[k−1]) / dt² passes (sin(ω dt/2) / (ω dt/2))² of the amplitude,
    0.93 at 15 Hz in a 100 Hz log: close enough to 1 within the band that matters."""
    dt = float(np.median(np.diff(t)))
    second = np.zeros_like(q)
    second[1:-1] = (q[2:] - 2 * q[1:-1] + q[:-2]) / dt**2
    second[0], second[-1] = second[1], second[-2]
    inner = slice(50, len(t) - 50)  # the filters' edges disagree whatever the bandwidth
    grid = np.geomspace(MATCH_LOWEST_HZ, MATCH_TOP / dt, MATCH_GRID)
    errors = [float(np.sum((lowpass(t, second, f) - ddq)[inner] ** 2)) for f in grid]
    best = int(np.argmin(errors))
    if best == len(grid) - 1 or errors[best] > MATCH_MISFIT * float(np.sum(ddq[inner] ** 2)):
        return None
    return float(grid[best])
