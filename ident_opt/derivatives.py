"""Velocities and accelerations from sampled joint angles: the one home of derivative estimation.

Zero-phase (offline: the loader, the trust checks, the instruments of IV, the simulator's logged trials):
`estimate_derivatives` low-passes the angles with a 4th-order Butterworth run forward and backward at a cut-off,
then takes central differences; `lowpass` filters the torque the same way (parallel filtering, so a fit compares
like with like); `choose_cutoff` reads a cut-off from where the motion's spectrum ends; `resolve_cutoff` turns a
problem's setting (a number or "auto") into one.

Causal (online, next to a controller): `derivative_kernels` makes the same recipe causal as a linear-phase FIR
whose delay is stated, and `CausalDerivatives` runs it over a stream of samples, delaying the rest of each sample
(torque, time) to match.

Units: t [s], q [rad], dq [rad/s], ddq [rad/s²], cut-offs [Hz]. Arrays are (N, n), one column per joint.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np
from scipy import signal
from scipy.interpolate import CubicSpline

#: Share of the zero-phase filter's impulse response left out by the causal FIR (`derivative_kernels`).
TAIL = 0.02
#: Estimated speeds below this [rad/s] are rest (0): a 10⁻⁴ rad encoder step over the filter's half second.
REST = 1e-4


class NonIncreasingTime(ValueError):
    """A streamed sample whose t does not increase (the caller reports and skips it)."""


# ---------------------------------------------------------------------------------------------- zero-phase
def lowpass(t: np.ndarray, x: np.ndarray, cutoff_hz: float) -> np.ndarray:
    """`x` (N, J) through the derivative estimate's zero-phase 4th-order Butterworth at `cutoff_hz` (at the
    median step; unchanged at or above Nyquist or for 30 samples or fewer)."""
    fs = 1.0 / float(np.median(np.diff(t)))
    if cutoff_hz >= 0.5 * fs or len(t) <= 30:
        return x
    b, a = signal.butter(4, cutoff_hz / (0.5 * fs))
    return signal.filtfilt(b, a, x, axis=0)


# ---------------------------------------------------------------------------------------------- derivatives
#: The motion band ends where the angle spectrum has fallen this far below its peak (40 dB).
MOTION_DYNAMIC_RANGE = 1e-4
#: Margin above that edge, and the range a chosen cut-off is clipped to [Hz, fraction of the sampling rate].
CUTOFF_MARGIN, CUTOFF_MIN_HZ, CUTOFF_MAX_FRACTION = 1.2, 0.5, 0.25


def choose_cutoff(t: np.ndarray, q: np.ndarray) -> float:
    """The derivative cut-off [Hz] read from where the motion's spectrum ends.

    Noise in estimated accelerations sits inside the regressor, and least squares with a noisy regressor is
    biased toward zero (errors-in-variables); the noise power of ddq grows as f⁴ above the motion's band,
    so the cut-off should sit just above that band, not at a fixed 15 Hz. Rule: Welch spectrum P_j(f) of
    each joint's detrended angle (4 s segments); the band of joint j ends at the highest frequency where
    P_j(f) ≥ 10⁻⁴ max P_j (40 dB below the peak); the cut-off is 1.2 × the widest joint's band edge,
    clipped to [0.5 Hz, fs/4].
    """
    steps = np.diff(t)
    fs = 1.0 / float(np.median(steps))
    grid = np.arange(t[0], t[-1] + 0.5 / fs, 1.0 / fs)
    qg = CubicSpline(t, q, axis=0)(grid) if np.ptp(steps) > 1e-6 / fs else q
    f, P = signal.welch(signal.detrend(qg, axis=0), fs=fs, nperseg=min(len(grid), max(int(4 * fs), 8)), axis=0)
    edges = [f[np.flatnonzero(P[:, j] >= MOTION_DYNAMIC_RANGE * P[:, j].max())[-1]] for j in range(P.shape[1])]
    return float(np.clip(CUTOFF_MARGIN * max(edges), CUTOFF_MIN_HZ, CUTOFF_MAX_FRACTION * fs))


def resolve_cutoff(setting: float | str, t: np.ndarray, q: np.ndarray) -> tuple[float, str]:
    """(cut-off [Hz], how it was set): a number as given, or "auto" by `choose_cutoff`."""
    if setting == "auto":
        cutoff = choose_cutoff(t, q)
        return cutoff, f" (cut-off {cutoff:.3g} Hz chosen from where the motion's spectrum ends)"
    return float(setting), ""


def estimate_derivatives(
    t: np.ndarray, q: np.ndarray, cutoff_hz: float, dq: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, str]:
    """Zero-phase velocity and acceleration estimates from sampled angles (and velocities, if logged).

    A 4th-order Butterworth low-pass run forward and backward (no phase lag) at `cutoff_hz`, then central
    differences. Non-uniform sampling is resampled onto a uniform grid first (cubic spline) and mapped back.
    Returns (dq, ddq, description).
    """
    steps = np.diff(t)
    dt = float(np.median(steps))
    uniform = np.max(np.abs(steps - dt)) <= 1e-6 * max(dt, 1e-12) + 1e-9 * abs(t[-1])
    if uniform:
        grid, qg, dqg = t, q, dq
    else:
        grid = np.arange(t[0], t[-1] + 0.5 * dt, dt)
        qg = CubicSpline(t, q, axis=0)(grid)
        dqg = CubicSpline(t, dq, axis=0)(grid) if dq is not None else None
    fs = 1.0 / dt
    if cutoff_hz < 0.5 * fs and len(grid) > 30:
        b, a = signal.butter(4, cutoff_hz / (0.5 * fs))

        def smooth(x):
            return signal.filtfilt(b, a, x, axis=0)

        how = f"estimated: 4th-order Butterworth at {cutoff_hz:g} Hz, forward-backward, central differences"
    else:

        def smooth(x):
            return x

        how = "estimated: central differences (cut-off at or above Nyquist, no smoothing)"
    if dqg is None:
        v = np.gradient(smooth(qg), grid, axis=0)
    else:
        v = dqg
        how += " (velocities as logged)"
    acc = np.gradient(smooth(v), grid, axis=0)
    if not uniform:
        v, acc = CubicSpline(grid, v, axis=0)(t), CubicSpline(grid, acc, axis=0)(t)
        how += f"; non-uniform sampling resampled to {fs:.6g} Hz"
    return (dq if dq is not None else v), acc, how


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
    (0.26 s at 100 Hz and 15 Hz)."""
    fc = cutoff_hz * dt * 2  # fraction of Nyquist
    if fc >= 1.0:  # cut-off at or above Nyquist: no smoothing, as the batch loader
        h = np.ones(1)
    else:
        b, a = signal.butter(4, fc)
        n = 20 * math.ceil(1.0 / fc) + 50
        impulse = signal.lfilter(b, a, np.r_[1.0, np.zeros(n - 1)])
        ac = np.correlate(impulse, impulse, "full")
        centre = n - 1
        mass = np.abs(ac[centre:])[::-1].cumsum()[::-1] / np.abs(ac).sum()  # mass at lag ≥ k (one side)
        m = max(1, int(np.argmax(mass < tail / 2)))
        h = ac[centre - m : centre + m + 1]
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
    None while the window fills. A time step off the nominal one by more than 25 % (a gap, jitter) restarts
    the window: the samples in it are lost (counted in `lost`). The nominal step is the stream's first."""

    def __init__(self, cutoff_hz: float):
        self.cutoff_hz = cutoff_hz
        self.dt: float | None = None
        self.k1 = self.k2 = None
        self.delay = 0
        self.window: deque = deque()
        self.pushed = 0
        self.completed = 0
        self.restarts = 0
        self.last_t: float | None = None

    @property
    def lost(self) -> int:
        """Samples pushed that no output completed (the last `delay` at the end, and those lost to restarts)."""
        return self.pushed - self.completed

    @staticmethod
    def _angles(sample: dict[str, float]) -> list[str]:
        """q1 … qn, the joint angles a sample carries (every sample of a stream has the same n)."""
        names = []
        while f"q{len(names) + 1}" in sample:
            names.append(f"q{len(names) + 1}")
        return names

    def delay_seconds(self) -> float | None:
        """The stated delay [s] (None before the second sample sets the rate)."""
        return None if self.dt is None else self.delay * self.dt

    def push(self, sample: dict[str, float]) -> dict[str, float] | None:
        """Add one sample (a dict with t and q1 … qn [s, rad]); raises `NonIncreasingTime` when t does not
        increase. The completed sample gets dq1 … dqn, ddq1 … ddqn."""
        t = sample["t"]
        if self.last_t is not None:
            step = t - self.last_t
            if step <= 0:
                raise NonIncreasingTime(f"t = {t!r} does not increase (last {self.last_t!r})")
            if self.dt is None:
                self.dt = step
                self.k1, self.k2, self.delay = derivative_kernels(step, self.cutoff_hz)
            elif abs(step - self.dt) > 0.25 * self.dt:
                self.window.clear()
                self.restarts += 1
        self.last_t = t
        self.pushed += 1
        self.window.append(sample)
        if self.k2 is None or len(self.window) < self.k2.size:
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
