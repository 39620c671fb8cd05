"""Causal derivatives, next to a controller: `derivative_kernels` makes the zero-phase recipe of `derivatives` causal as
a linear-phase FIR whose delay is stated, and `CausalDerivatives` runs it over a stream of samples, delaying the rest of
each sample (torque, time) to match. Units: t [s], q [rad], dq [rad/s], ddq [rad/s²], cut-offs [Hz]."""

from __future__ import annotations

import math
from collections import deque

import numpy as np
from scipy import signal

from ident_opt.numerics.derivatives import REST

#: Share of the zero-phase filter's impulse response left out by the causal FIR (`derivative_kernels`).
TAIL = 0.02


class NonIncreasingTime(ValueError):
    """A streamed sample whose t does not increase (the caller reports and skips it)."""


class RateError(ValueError):
    """A stream whose sampling rate the causal derivatives cannot serve (their filter would be too long)."""


#: Steps within this fraction of the window's step agree (jitter); others restart it, or are held as a gap.
STEP_TOLERANCE = 0.25


#: Agreeing steps that set a window's rate (never one step alone).
CONFIRM = 3


#: Samples kept while searching the start of a window for a run of agreeing steps.
START_SEARCH = 16


#: Longest causal derivative filter [taps]; `RATE_TAPS` / (2 cut-off × step) estimates its length before building it
#: (measured: 11.0 at 10 kHz and 15 Hz, 16 at 100 Hz).
MAX_TAPS = 20_001


RATE_TAPS = 11.1


# ---------------------------------------------------------------------------------------------- causal
def derivative_kernels(dt: float, cutoff_hz: float, tail: float = TAIL) -> tuple[np.ndarray, np.ndarray, int]:
    """FIR kernels (oldest sample first) giving dq [rad/s] and ddq [rad/s²] at the window's centre, and the
    delay in samples.

    The batch loader's recipe (`estimate_derivatives`: low-pass, central difference, low-pass, central
    difference) with its zero-phase filter made causal: forward-backward filtering with the 4th-order
    Butterworth b at `cutoff_hz` is convolution with b's autocorrelation h (symmetric, the same magnitude
    response |B(f)|², no phase). h is truncated to ±m samples, m the smallest with less than `tail` of h's
    absolute mass beyond, and renormalised to unit DC gain; then dq = (g∗h)∗q and ddq = (g∗h)∗(g∗h)∗q with g
    the central difference. Symmetric kernels have no phase distortion: a pure delay of 2m + 2 samples
    (0.26 s at 100 Hz and 15 Hz). The work is bounded: a step so short against the cut-off that the kernels would
    exceed `MAX_TAPS` taps (more than about 3,600 samples per period of the cut-off) is a `RateError`, raised
    before any of it."""
    fc = cutoff_hz * dt * 2  # fraction of Nyquist
    if not (np.isfinite(fc) and fc > 0):
        raise RateError(f"a time step of {dt!r} s cannot set a filter at {cutoff_hz:g} Hz")
    if fc >= 1.0:  # cut-off at or above Nyquist: no smoothing, as the batch loader
        h = np.ones(1)
    else:
        if RATE_TAPS / fc > MAX_TAPS:
            raise RateError(
                f"samples {dt:.3g} s apart ({1 / dt:.3g} Hz) with a derivative cut-off of {cutoff_hz:g} Hz would need "
                f"a causal filter of about {RATE_TAPS / fc:.3g} taps (at most {MAX_TAPS:,}); stream dq and ddq, raise "
                "[data] derivative_cutoff_hz, or stream fewer samples per second"
            )
        b, a = signal.butter(4, fc)
        n = 20 * math.ceil(1.0 / fc) + 50
        impulse = signal.lfilter(b, a, np.r_[1.0, np.zeros(n - 1)])
        ac = signal.fftconvolve(impulse, impulse[::-1])  # the autocorrelation, in O(n log n)
        centre = n - 1
        mass = np.abs(ac[centre:])[::-1].cumsum()[::-1] / np.abs(ac).sum()  # mass at lag ≥ k (one side)
        m = max(1, int(np.argmax(mass < tail / 2)))
        h = ac[centre - m : centre + m + 1]
        h = 0.5 * (h + h[::-1])  # exactly symmetric (the FFT's round-off is not)
        h = h / h.sum()
    m = h.size // 2
    gh = np.convolve(h, [0.5, 0.0, -0.5]) / dt  # one smoothed central difference, 2m + 3 taps
    k2 = np.convolve(gh, gh)  # 4m + 5 taps, centre 2m + 2
    k1 = np.zeros_like(k2)
    k1[m + 1 : m + 1 + gh.size] = gh  # the same centre
    # np.convolve(x, k)[n] = Σ k[i] x[n − i] (newest last): reversed for a dot product with the buffer, oldest first.
    return k1[::-1].copy(), k2[::-1].copy(), 2 * m + 2


class CausalDerivatives:
    """dq and ddq estimated online from q and t, `delay` samples late (`derivative_kernels`), with the rest of
    the sample (torque, t) delayed to match. `push` returns the completed sample `delay` pushes later, or
    None while the window fills.

    The window holds consecutive samples whose steps agree (each within 25 % of the window's step); its step, the
    rate the kernels are built for, is set once `CONFIRM` such steps agree (their median), never from one step
    alone. The first samples of a stream (and of a window after a restart) are searched backward from the newest
    for such a run, so a stray time among them (a step of 1e-300 s, a first step of 10 s, one sample at t = 1000) is
    left out (reported in `rejected`) instead of setting the rate. Once the rate is set: a sample whose t does not
    increase raises `NonIncreasingTime`; a step shorter than 75 % of the window's restarts the window; a longer one
    is held back for one sample: if the next sample falls between the window's last and it, it was a stray time
    (rejected), else a gap (the window restarts at it). Samples of a window that never completes are counted in
    `lost`."""

    def __init__(self, cutoff_hz: float):
        self.cutoff_hz = cutoff_hz
        self.dt: float | None = None  # the rate the kernels are built for [s]
        self.k1 = self.k2 = None
        self.delay = 0
        self.window: deque = deque()
        self.confirmed = False  # the window's step is set (`CONFIRM` agreeing steps)
        self.held: dict | None = None  # a sample after a long step, until the next one says gap or stray
        self.rejected: list[tuple[dict, str]] = []  # (sample, why) left out; the caller reports and clears them
        self.pushed = 0
        self.completed = 0
        self.restarts = 0

    @property
    def lost(self) -> int:
        """Samples pushed that no output completed (the last `delay` at the end, those lost to restarts and the
        rejected ones)."""
        return self.pushed - self.completed

    @property
    def last_t(self) -> float | None:
        """The time [s] of the window's newest sample (None before the first)."""
        return self.window[-1]["t"] if self.window else None

    @staticmethod
    def _angles(sample: dict[str, float]) -> list[str]:
        """q1 … qn, the joint angles a sample carries (every sample of a stream has the same n)."""
        names = []
        while f"q{len(names) + 1}" in sample:
            names.append(f"q{len(names) + 1}")
        return names

    def delay_seconds(self) -> float | None:
        """The stated delay [s] (None before the rate is set)."""
        return None if self.dt is None else self.delay * self.dt

    def push(self, sample: dict[str, float]) -> dict[str, float] | None:
        """Add one sample (a dict with t and q1 … qn [s, rad]); raises `NonIncreasingTime` when t does not
        increase past the window's newest, `RateError` when the window's rate cannot be served (`derivative_kernels`).
        The completed sample gets dq1 … dqn, ddq1 … ddqn."""
        self.pushed += 1
        if self.held is not None and not self._settle(sample):
            return None
        last = self.last_t
        if last is not None and sample["t"] <= last and self.confirmed:
            self.pushed -= 1  # not taken: the caller reports it
            raise NonIncreasingTime(f"t = {sample['t']!r} does not increase (last {last!r})")
        if not self.confirmed:
            self._start(sample)
        elif not self._append(sample):
            return None
        return self._complete()

    def _settle(self, sample: dict) -> bool:
        """With a held sample (after a long step): decide gap or stray time from `sample`; False when `sample` is
        itself behind (its error raised by the caller's next check)."""
        held, self.held = self.held, None
        if sample["t"] > held["t"]:  # a gap: the window restarts at the held sample
            self._restart([held])
            return True
        if sample["t"] > self.window[-1]["t"]:  # the held time was a stray one
            self.rejected.append((held, f"t = {held['t']!r} jumps ahead of the samples around it; left out"))
            return True
        self.held = held  # `sample` is behind both: it is the odd one
        return True

    def _restart(self, samples: list[dict]) -> None:
        """A new window from `samples`; the old window's samples are lost."""
        self.window = deque(samples)
        self.confirmed = False
        self.restarts += 1

    def _start(self, sample: dict) -> None:
        """Before the window's rate is set: keep the newest run of agreeing steps ending at `sample`, searched
        backward (samples that break it are rejected), and set the rate once `CONFIRM` steps agree."""
        self.window.append(sample)
        if len(self.window) < 3:
            return
        run, reference = [sample], None
        for s in reversed(list(self.window)[:-1]):
            step = run[-1]["t"] - s["t"]
            if step <= 0:
                continue
            if reference is None or abs(step - reference) <= STEP_TOLERANCE * reference:
                reference = step if reference is None else reference
                run.append(s)
            # else: a sample that does not fit the newest run; kept in the window until it can be judged
        if len(run) <= CONFIRM:
            if len(self.window) > START_SEARCH:
                self.window.popleft()
            return
        run.reverse()
        kept = {id(s) for s in run}
        first = run[0]["t"]
        for s in self.window:
            if id(s) not in kept and s["t"] >= first:  # a stray time inside the run's span
                self.rejected.append((s, f"t = {s['t']!r} does not fit the stream's steps around it; left out"))
        self.window = deque(run)
        self._confirm()

    def _confirm(self) -> None:
        """The window's rate: the median of its steps; the kernels for it (rebuilt only when it moved)."""
        t = np.array([s["t"] for s in self.window])
        dt = float(np.median(np.diff(t)))
        if self.dt is None or abs(dt - self.dt) > STEP_TOLERANCE * self.dt:
            self.k1, self.k2, self.delay = derivative_kernels(dt, self.cutoff_hz)
            self.dt = dt
        self.confirmed = True

    def _append(self, sample: dict) -> bool:
        """Once the rate is set: append `sample` if its step agrees; hold it after a long step; restart the window
        after a short one. False when nothing can complete now."""
        step = sample["t"] - self.window[-1]["t"]
        if abs(step - self.dt) <= STEP_TOLERANCE * self.dt:
            self.window.append(sample)
            return True
        if step > self.dt:
            self.held = sample
            return False
        self._restart([self.window[-1], sample])
        return False

    def _complete(self) -> dict[str, float] | None:
        """The sample `delay` steps back with its derivatives, once the window is long enough."""
        if not self.confirmed or len(self.window) < self.k2.size:
            return None
        if len(self.window) > self.k2.size:
            self.window.popleft()
        centre = dict(self.window[self.delay])
        # Relative to the centre sample (the kernels sum to 0): a joint at rest (q repeated) gives exactly 0, not
        # rounding noise whose sign would decide the Coulomb friction column.
        names = self._angles(centre)
        q = np.array([[s[name] for name in names] for s in self.window]) - [centre[name] for name in names]
        dq, ddq = self.k1 @ q, self.k2 @ q
        dq[np.abs(dq) < REST] = 0.0  # unresolvable: at rest (the Coulomb column's sign is 0, not noise)
        for j in range(len(names)):
            centre[f"dq{j + 1}"], centre[f"ddq{j + 1}"] = float(dq[j]), float(ddq[j])
        self.completed += 1
        return centre
