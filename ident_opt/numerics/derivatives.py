"""Velocities and accelerations from sampled joint angles: the one home of derivative estimation.

Zero-phase (offline: the loader, the trust checks, the instruments of IV, the simulator's logged trials):
`estimate_derivatives` low-passes the angles with a 4th-order Butterworth run forward and backward at a cut-off,
then takes central differences, on each gap-free `segments` of a trial with its ends extended by local cubics;
`settled` says which samples are far enough from a segment's end to be free of edge error (the loader keeps
those); `lowpass` filters the torque the same way (parallel filtering, so a fit compares like with like);
`cutoff_choice` reads the cut-off the data support from where noise starts to outweigh motion in each moving
joint's acceleration spectrum;
`resolve_cutoff` turns a problem's setting (a number or "auto") into one.

Causal (online, next to a controller): `numerics.causal`.

Units: t [s], q [rad], dq [rad/s], ddq [rad/s²], cut-offs [Hz]. Arrays are (N, n), one column per joint.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy import signal
from scipy.interpolate import CubicSpline

#: Estimated speeds below this [rad/s] are rest (0): a 10⁻⁴ rad encoder step over the filter's half second.
REST = 1e-4


# ---------------------------------------------------------------------------------------------- segments
#: A time step longer than this many median steps (and than a quarter period of the cut-off) is a gap: the
#: samples on either side are separate segments, never interpolated across.
GAP_STEPS = 10.0
#: A segment shorter than this many samples is too short to differentiate (its samples are dropped).
MIN_SEGMENT = 30


def segments(t: np.ndarray, cutoff_hz: float | None = None) -> list[slice]:
    """The runs of `t` [s] without a gap: a step longer than `GAP_STEPS` median steps and, given a cut-off [Hz],
    longer than a quarter of its period (shorter holes are interpolated harmlessly: the motion below the cut-off
    is smooth across them)."""
    if len(t) < 2:
        return [slice(0, len(t))]
    steps = np.diff(t)
    limit = GAP_STEPS * float(np.median(steps))
    if cutoff_hz is not None:
        limit = max(limit, 0.25 / cutoff_hz)
    cuts = np.flatnonzero(steps > limit) + 1
    bounds = [0, *cuts.tolist(), len(t)]
    return [slice(a, b) for a, b in itertools.pairwise(bounds)]


def _uniform(t: np.ndarray) -> tuple[bool, float]:
    """(is `t` uniform to rounding, its median step [s])."""
    steps = np.diff(t)
    dt = float(np.median(steps))
    return bool(np.max(np.abs(steps - dt)) <= 1e-6 * max(dt, 1e-12) + 1e-9 * abs(t[-1])), dt


# ---------------------------------------------------------------------------------------------- zero-phase
#: Edges: each end of a segment is extended by a cubic fitted to its first (last) `EDGE_FIT` periods of the
#: cut-off, over `EDGE_PAD` periods, before filtering. An odd reflection (SciPy's default) forces zero curvature
#: at the ends, which puts up to half the peak acceleration into the estimate there; the cubic keeps the
#: curvature (measured on sines below the cut-off: the error one period in falls from 4–14 % to 1.5–2 %).
EDGE_FIT, EDGE_PAD = 0.5, 3.0
#: The padding is at most this many times the segment's own length on each side.
EDGE_PAD_MAX = 3
#: Samples closer than this many periods of the cut-off to a segment's end keep an edge error (about 2 % of the
#: peak acceleration at one period): the loader drops them (`settled`).
SETTLE_PERIODS = 1.0


def _butter(cutoff_hz: float, fs: float):
    """The 4th-order Butterworth low-pass at `cutoff_hz` for sampling rate `fs` [Hz] as second-order sections
    (exact at any cut-off: as (b, a) it breaks down below about 10⁻⁴ of Nyquist, giving 10³⁷ for a sine), or None
    at or above Nyquist."""
    return None if cutoff_hz >= 0.5 * fs else signal.butter(4, cutoff_hz / (0.5 * fs), output="sos")


def zero_phase_sos(cutoff_hz: float, fs: float):
    """The second-order sections every zero-phase filter here runs forward and backward (`_butter`): for a reader
    that filters a segment in pieces (`fleet.chunks`); None at or above Nyquist."""
    return _butter(cutoff_hz, fs)


def edge_extensions(x: np.ndarray, fs: float, cutoff_hz: float, n: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(before, after): the samples `_filtfilt` puts before the first and after the last of a segment `x` (N, J)
    of `n` samples (default: len(x); only its first and last `EDGE_FIT` periods are read): local cubics over at
    most `EDGE_PAD` periods of the cut-off and at most the segment's own length again on each side (a cut-off far
    below what the segment can show must not ask for millions of padding samples)."""
    n = len(x) if n is None else n
    fit = max(4, min(n, round(EDGE_FIT * fs / cutoff_hz)))
    pad = min(round(EDGE_PAD * fs / cutoff_hz), EDGE_PAD_MAX * n)
    s = np.arange(fit) / fs  # time into the segment from its first (last) sample
    beyond = -np.arange(1, pad + 1) / fs  # before the first (after the last) sample, nearest first
    head = np.polynomial.polynomial.polyfit(s, x[:fit], 3)
    tail = np.polynomial.polynomial.polyfit(s, x[::-1][:fit], 3)
    left = np.polynomial.polynomial.polyval(beyond, head).T[::-1]
    right = np.polynomial.polynomial.polyval(beyond, tail).T
    return left, right


def _filtfilt(sos, x: np.ndarray, fs: float, cutoff_hz: float) -> np.ndarray:
    """Zero-phase filtering of `x` (N, J) along axis 0, its ends extended by local cubics (`edge_extensions`)."""
    left, right = edge_extensions(x, fs, cutoff_hz)
    y = signal.sosfiltfilt(sos, np.concatenate([left, x, right]), axis=0, padtype=None)
    return y[len(left) : len(left) + len(x)]


def lowpass(t: np.ndarray, x: np.ndarray, cutoff_hz: float) -> np.ndarray:
    """`x` (N, J) through the derivative estimate's zero-phase 4th-order Butterworth at `cutoff_hz` (per segment,
    at the median step; unchanged at or above Nyquist or for segments of `MIN_SEGMENT` samples or fewer)."""
    out = np.array(x, dtype=float, copy=True)
    for seg in segments(t, cutoff_hz):
        ts = t[seg]
        if len(ts) <= MIN_SEGMENT:
            continue
        fs = 1.0 / float(np.median(np.diff(ts)))
        ba = _butter(cutoff_hz, fs)
        if ba is not None:
            out[seg] = _filtfilt(ba, x[seg], fs, cutoff_hz)
    return out


def settled(t: np.ndarray, cutoff_hz: float) -> np.ndarray:
    """Samples (bool (N,)) at least `SETTLE_PERIODS` periods of the cut-off from either end of their segment, in
    segments long enough to differentiate: where the zero-phase estimate has no edge error to speak of. A segment
    shorter than four settle lengths keeps its middle half."""
    keep = np.zeros(len(t), dtype=bool)
    for seg in segments(t, cutoff_hz):
        ts = t[seg]
        if len(ts) <= MIN_SEGMENT:
            continue
        settle = min(SETTLE_PERIODS / cutoff_hz, 0.25 * (ts[-1] - ts[0]))
        keep[seg] = (ts >= ts[0] + settle) & (ts <= ts[-1] - settle)
    return keep


# ---------------------------------------------------------------------------------------------- the cut-off
#: The acceleration spectrum is smoothed over this fraction of an octave before its minimum is read.
SMOOTHING_OCTAVE = 1 / 3
#: A joint moves (and has a say in the cut-off) when its acceleration spectrum between the angle's peak and the
#: minimum stands this far above the minimum (20 dB); a joint at rest or held shows noise only, rising from its peak.
MOVING_CONTRAST = 100.0
#: A joint's band edge is where the floor holding its acceleration spectrum's minimum begins: the spectrum within
#: this factor of the minimum. Motion and noise can share a flat floor over an octave or more (DFKI A.0's swing-up:
#: 8–35 Hz), and the minimum could be anywhere along it.
FLOOR_FACTOR = 3.0
#: The cut-off sits this factor above the widest band edge: the 4th-order Butterworth run forward and backward
#: passes 1/(1 + (f/f_c)⁸) of the amplitude, so the motion keeps 96 % at the edge, and the instruments of IV at half
#: the cut-off (`INSTRUMENT_RATIO`) sit just below it. Measured: 1 leaves the filter distorting the dynamics in
#: simulation; 2 biases the DFKI pendulum's gravity parameters 10 % low (its spectra carry more than rigid-body
#: motion there); 1.5 puts both DFKI designs' inertial and gravity parameters within 6 % of their makers'.
CUTOFF_MARGIN = 1.5
#: The range a chosen cut-off is clipped to [Hz, fraction of the sampling rate].
CUTOFF_MIN_HZ, CUTOFF_MAX_FRACTION = 0.5, 0.25


@dataclass(frozen=True)
class CutoffChoice:
    """What `cutoff_choice` read from a trial: the cut-off [Hz], each joint's band edge [Hz] (None: the joint did
    not move above its noise) and a sentence saying how."""

    cutoff_hz: float
    edges_hz: tuple[float | None, ...]
    how: str


def _spectrum(t: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(f [Hz], Welch PSD (F, J) of the detrended angles [rad²/Hz], fs) over the longest segment (resampled if
    jittery), 4 s windows."""
    seg = max(segments(t), key=lambda s: s.stop - s.start)
    t, q = t[seg], q[seg]
    uniform, dt = _uniform(t)
    fs = 1.0 / dt
    if not uniform:
        grid = np.arange(t[0], t[-1] + 0.5 * dt, dt)
        q = CubicSpline(t, q, axis=0)(grid)
    f, P = signal.welch(q, fs=fs, nperseg=min(len(q), max(int(4 * fs), 8)), detrend="linear", axis=0)
    return f, P, fs


def _smoothed(f: np.ndarray, S: np.ndarray) -> np.ndarray:
    """S (F,) smoothed by a running median over `SMOOTHING_OCTAVE` of an octave around each frequency."""
    half = 2 ** (SMOOTHING_OCTAVE / 2)
    lo, hi = np.searchsorted(f, f / half), np.searchsorted(f, f * half, side="right")
    return np.array([np.median(S[a:b]) if b > a else S[i] for i, (a, b) in enumerate(zip(lo, hi))])


def cutoff_choice(t: np.ndarray, q: np.ndarray) -> CutoffChoice:
    """The derivative cut-off [Hz] the data support, with each joint's evidence (`CutoffChoice`).

    Noise in estimated accelerations sits inside the regressor, and least squares with a noisy regressor is
    biased toward zero (errors-in-variables); a cut-off that passes frequencies where noise outweighs motion only
    adds noise, one below the motion's band removes motion. Per joint j, the spectrum of its acceleration as the
    angles give it, S_j(f) = (2πf)⁴ P_j(f) (P_j the Welch spectrum of the detrended angle, 4 s windows, smoothed
    over a third of an octave): above the motion's band the motion's share falls steeply while encoder and
    electrical noise rise (white angle noise as f⁴, quantisation of slow motion little less), so S_j falls to a floor
    and rises again where every further hertz adds more noise than motion. Joint j's band edge is where the floor
    that holds the minimum (above the spectrum's peak) begins: one bin past the last point of the fall that stands
    more than `FLOOR_FACTOR` above the minimum — whatever the noise's colour, rate or level. A joint whose spectrum
    between its peak and that minimum does not stand `MOVING_CONTRAST` above the minimum (at rest, held) has no
    say. The cut-off is `CUTOFF_MARGIN` × the widest moving joint's edge — the filter leaves the motion nearly whole,
    and the instruments of IV at half the cut-off sit just below the edge — clipped to [`CUTOFF_MIN_HZ`,
    `CUTOFF_MAX_FRACTION` × fs]. Between edge and cut-off some noise passes: `fitting.recommend` sees whether it
    biases least squares.
    """
    f, P, fs = _spectrum(t, q)
    high = CUTOFF_MAX_FRACTION * fs
    edges: list[float | None] = []
    for j in range(P.shape[1]):
        S = _smoothed(f, (2 * np.pi * f) ** 4 * P[:, j])
        peak = int(np.argmax(np.where(f > 0, P[:, j], -np.inf)))
        band = np.flatnonzero((f >= f[peak]) & (f <= high))
        if band.size == 0:
            edges.append(None)
            continue
        lowest = band[np.argmin(S[band])]
        # Motion: accelerations between the peak and the minimum well above it. Noise alone rises from its peak on.
        moving = S[peak : lowest + 1].max() > MOVING_CONTRAST * S[lowest]
        # The edge: where the floor that ends at the minimum begins (the last point of the motion's fall above
        # `FLOOR_FACTOR` × the minimum, one bin on): on a flat floor the minimum itself could be anywhere along it,
        # and a dip between two harmonics of the motion is not the floor.
        above = band[(band < lowest) & (S[band] > FLOOR_FACTOR * S[lowest])]
        edge = min(above[-1] + 1, lowest) if above.size else lowest
        edges.append(float(f[edge]) if moving else None)
    moving = [e for e in edges if e is not None]
    if not moving:
        return CutoffChoice(
            CUTOFF_MIN_HZ, tuple(edges), f"no joint moves above its noise: cut-off {CUTOFF_MIN_HZ:g} Hz"
        )
    cutoff = float(np.clip(CUTOFF_MARGIN * max(moving), CUTOFF_MIN_HZ, high))
    still = [f"q{j + 1}" for j, e in enumerate(edges) if e is None]
    how = f"cut-off {cutoff:.3g} Hz, where noise starts to outweigh motion in the accelerations" + (
        f" ({', '.join(still)} at rest: not counted)" if still else ""
    )
    return CutoffChoice(cutoff, tuple(edges), how)


def choose_cutoff(t: np.ndarray, q: np.ndarray) -> float:
    """The derivative cut-off [Hz] the data support (`cutoff_choice`)."""
    return cutoff_choice(t, q).cutoff_hz


def resolve_cutoff(setting: float | str, t: np.ndarray, q: np.ndarray) -> tuple[float, str]:
    """(cut-off [Hz], how it was set): a number as given, or "auto" by `cutoff_choice`."""
    if setting == "auto":
        choice = cutoff_choice(t, q)
        return choice.cutoff_hz, f" ({choice.how})"
    return float(setting), ""


# ---------------------------------------------------------------------------------------------- derivatives
def _segment_derivatives(
    t: np.ndarray, q: np.ndarray, cutoff_hz: float, dq: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, bool]:
    """(dq, ddq, resampled) of one gap-free segment (`estimate_derivatives`); zeros for fewer than 3 samples."""
    if len(t) < 3:
        return (np.zeros_like(q, dtype=float) if dq is None else dq), np.zeros_like(q, dtype=float), False
    uniform, dt = _uniform(t)
    if uniform:
        grid, qg, dqg = t, q, dq
    else:
        grid = np.arange(t[0], t[-1] + 0.5 * dt, dt)
        qg = CubicSpline(t, q, axis=0)(grid)
        dqg = CubicSpline(t, dq, axis=0)(grid) if dq is not None else None
    fs = 1.0 / dt
    ba = _butter(cutoff_hz, fs) if len(grid) > MIN_SEGMENT else None

    def smooth(x):
        return x if ba is None else _filtfilt(ba, x, fs, cutoff_hz)

    v = np.gradient(smooth(qg), grid, axis=0) if dqg is None else dqg
    acc = np.gradient(smooth(v), grid, axis=0) if len(grid) > 1 else np.zeros_like(v)
    if not uniform:
        v, acc = CubicSpline(grid, v, axis=0)(t), CubicSpline(grid, acc, axis=0)(t)
    return (dq if dq is not None else v), acc, not uniform


def estimate_derivatives(
    t: np.ndarray, q: np.ndarray, cutoff_hz: float, dq: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, str]:
    """Zero-phase velocity and acceleration estimates from sampled angles (and velocities, if logged).

    A 4th-order Butterworth low-pass run forward and backward (no phase lag) at `cutoff_hz`, the ends of each
    segment extended by local cubics (`EDGE_FIT`), then central differences. Each gap-free segment (`segments`)
    on its own; a jittery one is resampled onto a uniform grid (cubic spline) and mapped back. Samples near a
    segment's end keep some edge error (`settled` says which). Returns (dq, ddq, description).
    """
    parts = segments(t, cutoff_hz)
    dq_out, ddq_out = np.zeros_like(q, dtype=float), np.zeros_like(q, dtype=float)
    resampled = False
    for seg in parts:
        v, a, r = _segment_derivatives(t[seg], q[seg], cutoff_hz, None if dq is None else dq[seg])
        dq_out[seg], ddq_out[seg], resampled = v, a, resampled or r
    fs = 1.0 / float(np.median(np.diff(t))) if len(t) > 1 else float("inf")
    if cutoff_hz < 0.5 * fs:
        how = f"estimated: 4th-order Butterworth at {cutoff_hz:g} Hz, forward-backward, central differences"
    else:
        how = "estimated: central differences (cut-off at or above Nyquist, no smoothing)"
    if dq is not None:
        how += " (velocities as logged)"
    if len(parts) > 1:
        how += f"; {len(parts)} segments between gaps, each on its own"
    if resampled:
        how += f"; non-uniform sampling resampled to {fs:.6g} Hz"
    return (dq if dq is not None else dq_out), ddq_out, how


#: The instruments' cut-off as a fraction of the data's (`fitting.iv`): measured on DFKI C.0, 0.5 keeps the motion
#: and removes most of the errors-in-variables bias.
INSTRUMENT_RATIO = 0.5


def instrument_derivatives(t: np.ndarray, q: np.ndarray, cutoff_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(dq, ddq) estimated independently of the regressor's, at `INSTRUMENT_RATIO` × `cutoff_hz` [Hz]: the
    kinematics of the instruments of IV (`fitting.iv`). The noise that biases least squares lives in the upper
    part of the regressor's pass band, which this lower cut-off removes."""
    dq, ddq, _ = estimate_derivatives(t, q, INSTRUMENT_RATIO * cutoff_hz)
    return dq, ddq
