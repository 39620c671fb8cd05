"""The observer and its alarm one sample at a time, for a stream (`online --stream`): every sample with a torque moves
the observer and the alarm (`ContactWatch.step`); while an alarm or its settling lasts (`quiet`), the online
identifier learns nothing from the sample (neither its parameters nor its GMR residual): it does not learn the
person leaning on the arm."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ident_opt.contact.alarm import Detector
from ident_opt.contact.dynamics import Momentum
from ident_opt.contact.observer import MomentumObserver, default_gain, residual_step
from ident_opt.contact.thresholds import MARGIN, Thresholds, calibrate
from ident_opt.data.dataset import Dataset
from ident_opt.fitting.recommend import ArmFit, Choice, fit_options


@dataclass
class ContactWatch:
    """One arm's observer (`momentum` at the fitted π) and alarm (`thresholds`) over a stream of samples."""

    momentum: Momentum
    thresholds: Thresholds
    detector: Detector = field(init=False)
    tau_ext: np.ndarray = field(init=False)
    last: tuple[float | None, np.ndarray, np.ndarray] | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        self.detector = Detector(self.thresholds)
        self.tau_ext = np.zeros(self.thresholds.n)

    @property
    def alarm(self) -> bool:
        return self.detector.alarm

    @property
    def quiet(self) -> bool:
        """No learning now: in alarm or settling after one."""
        return self.detector.quiet

    def step(self, t: float | None, q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, bool]:
        """One sample (t [s] or None: the calibration's step after the last; q, dq, τ (n,)): (τ_ext (n,) [N m],
        alarm)."""
        p, beta = (np.asarray(x, dtype=float).ravel() for x in self.momentum.function(q, dq))
        u = np.asarray(tau, dtype=float) - beta
        dt = self.thresholds.dt
        if self.last is not None:
            t_prev, p_prev, u_prev = self.last
            if t is not None and t_prev is not None and t > t_prev:
                dt = t - t_prev
            gain = np.asarray(self.thresholds.gain)
            self.tau_ext = residual_step(self.tau_ext, p_prev, u_prev, p, u, dt, gain)
        self.last = (t, p, u)
        return self.tau_ext.copy(), self.detector.step(self.tau_ext, np.asarray(dq, dtype=float), dt)


def watch_for(fit: ArmFit, trials: Sequence[Dataset], margin: float = MARGIN) -> ContactWatch:
    """The watch of `fit`'s arm with thresholds calibrated on the collision-free `trials` (`contact.thresholds`)."""
    return watch_with(Momentum(fit.model, fit.pi), trials, margin)


def watch_with(momentum: Momentum, trials: Sequence[Dataset], margin: float = MARGIN) -> ContactWatch:
    """The watch of an arm's `momentum` (at its fitted π) with thresholds calibrated on the collision-free `trials`."""
    dt = float(np.median(np.concatenate([np.diff(d.t) for d in trials])))
    observer = MomentumObserver(momentum, default_gain(1.0 / dt, momentum.arm.n_joints))
    residuals = [observer.run(d.t, d.q, d.dq, d.tau) for d in trials]
    thresholds = calibrate(residuals, [d.dq for d in trials], [d.tau for d in trials], observer.gain, dt, margin)
    return ContactWatch(observer.momentum, thresholds)


def stream_watch(problem, trials: Sequence[Dataset], choice: Choice, margin: float = MARGIN) -> ContactWatch:
    """The watch `online --stream` serves: `choice`'s fit (the recommended one) of the problem's arm on the offline
    `trials`, thresholds calibrated on them (collision-free: the identification's own trials)."""
    robot = problem.robot
    model = robot.model()
    fit = choice.fit(robot, model, trials, **fit_options(robot, choice.estimator, model, {}, "online"))
    return watch_for(fit, trials, margin)
