"""`ident-opt detect` (`docs/contacts.md`): the recommended fit, thresholds calibrated on collision-free trials (their
false alarms per minute held out one trial at a time), and the observer with its alarms over each trial.

    import ident_opt as iopt

    problem = iopt.load_problem("problems/kuka_lwr4.toml")
    training, testing = iopt.load_trials(problem)
    found = iopt.detect(problem, training, calibration=training, data=testing)
    found.trials[0].tau_ext        # (N, n) [N m]
    found.trials[0].alarms         # [Alarm(start, end, joint, peak), …]
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ident_opt.contact.alarm import Alarm, alarms, per_minute, spans
from ident_opt.contact.dynamics import Momentum
from ident_opt.contact.observer import MomentumObserver, default_gain
from ident_opt.contact.thresholds import MARGIN, Thresholds, calibrate
from ident_opt.data.dataset import Dataset
from ident_opt.data.validate import checked_problem, checked_trials
from ident_opt.errors import InputError, excerpt
from ident_opt.fitting.recommend import ArmFit, choose, fit_options
from ident_opt.paths import shown
from ident_opt.problem import Problem
from ident_opt.warnings import ResultWarning

#: Samples a calibration trial needs at least (its halves, held out, need a few persistence windows each).
MIN_CALIBRATION = 20


@dataclass
class TrialDetection:
    """The observer over one trial: t (N,) [s], τ_ext (N, n) [N m], `alarm` (N,) (in alarm from that sample on),
    `quiet` (N,) (alarm or settling: no learning), and its `alarms`."""

    source: str
    t: np.ndarray
    tau_ext: np.ndarray
    dq: np.ndarray
    alarm: np.ndarray
    quiet: np.ndarray
    alarms: list[Alarm]

    @property
    def per_minute(self) -> float:
        """Alarms per minute of the trial."""
        return per_minute(len(self.alarms), self.t)

    def as_json(self) -> dict:
        return {
            "source": shown(self.source),
            "duration_s": float(self.t[-1] - self.t[0]) if len(self.t) else 0.0,
            "alarms": [a.as_json() for a in self.alarms],
            "alarms_per_minute": self.per_minute,
        }


@dataclass
class Detection:
    """What `detect` found: the fit (`estimator`, `why`), the `thresholds` (calibrated on every calibration trial),
    per calibration trial its false alarms per minute with thresholds from the others (`calibration`), each data
    trial's detection (`trials`) and the `warnings`."""

    estimator: str
    why: str
    thresholds: Thresholds
    calibration: list[dict]
    trials: list[TrialDetection]
    fit: ArmFit = field(repr=False)
    warnings: list[ResultWarning] = field(default_factory=list)

    def as_json(self) -> dict:
        """The `detect --json` payload (`docs/contacts.md`)."""
        return {
            "estimator": self.estimator,
            "why": self.why,
            "thresholds": self.thresholds.as_json(),
            "persistence": self.thresholds.persistence,
            "settling_s": self.thresholds.settling,
            "margin": self.thresholds.margin,
            "calibration": self.calibration,
            "trials": [trial.as_json() for trial in self.trials],
            "warnings": [w.as_dict() for w in self.warnings],
        }


def detect(
    problem: Problem,
    training: Sequence[Dataset],
    calibration: Sequence[Dataset] | None = None,
    data: Sequence[Dataset] = (),
    *,
    estimator: str | None = None,
    margin: float = MARGIN,
) -> Detection:
    """Fit `problem`'s arm on `training` (`ident_opt.fit`: the recommended fit, or `estimator`), calibrate the
    thresholds on the collision-free `calibration` trials (default: `training`) with `margin`, and run the observer
    and its alarms over each trial of `data` (τ_ext, alarms). Bad input raises `InputError` naming it."""
    checked_problem(problem, "detect")
    if isinstance(margin, bool) or not isinstance(margin, (int, float)) or not np.isfinite(margin) or margin < 1:
        raise InputError(
            f"detect: margin must be a number ≥ 1 (a factor on the calibrated level), got {excerpt(margin)}"
        )
    training = checked_trials(problem, training, "detect", "training", fit=True)
    calibration = checked_trials(problem, training if calibration is None else calibration, "detect", "calibration")
    data = checked_trials(problem, data, "detect", "data", required=False)
    for i, trial in enumerate(calibration):
        if trial.n < MIN_CALIBRATION:
            raise InputError(
                f"detect: calibration[{i}] ({shown(trial.source)}) has {trial.n} samples; a collision-free trial to "
                f"calibrate on needs at least {MIN_CALIBRATION}"
            )
    fit = _fit(problem, training, estimator)
    warnings = list(fit.choice.warnings) if fit.choice is not None else []
    if fit.model.min_mass_eigenvalue(fit.pi) <= 0:
        warnings.append(
            ResultWarning(
                "mass_not_positive",
                f"the {fit.choice.estimator if fit.choice else estimator} fit's M(q) is not positive definite "
                f"({fit.model.consistency_measure} {fit.model.min_mass_eigenvalue(fit.pi):.3g}): its momentum is not "
                "physical and τ_ext not trustworthy; use the physically consistent fit (no --estimator)",
            )
        )
    dt = float(np.median(np.concatenate([np.diff(d.t) for d in calibration])))
    observer = MomentumObserver(Momentum(fit.model, fit.pi), default_gain(1.0 / dt, fit.model.n_joints))
    observed = [_pieces(observer, d) for d in calibration]
    thresholds = calibrate(*zip(*[(r, d.dq, d.tau) for r, d in observed]), observer.gain, dt, margin)
    rates, warning = held_out(observed, observer.gain, dt, margin)
    warnings += warning
    trials = [run_trial(observer, d, thresholds) for d in data]
    name = fit.choice.estimator if fit.choice is not None else str(estimator)
    why = fit.choice.why if fit.choice is not None else "asked for"
    return Detection(name, why, thresholds, rates, trials, fit, warnings)


def _fit(problem: Problem, training: list[Dataset], estimator: str | None) -> ArmFit:
    """The fit `ident_opt.fit` makes (the recommended one, or `estimator`) of the problem's arm on `training`."""
    robot, model = problem.robot, problem.robot.model()
    if estimator is not None:  # an unknown fit is refused before the trials' evidence is weighed
        choose(problem, [], estimator=estimator, command="detect")
    choice = choose(problem, training, estimator=estimator, command="detect")
    try:
        return choice.fit(robot, model, training, **fit_options(robot, choice.estimator, model, {}, "detect"))
    except RuntimeError as exc:  # the solver failed: nothing to stand behind
        raise InputError(f"detect: the {choice.estimator} fit failed ({exc}); try another estimator") from None


def _pieces(observer: MomentumObserver, trial: Dataset) -> tuple[np.ndarray, Dataset]:
    """(τ_ext (N, n) [N m], the trial) of one trial."""
    return observer.run(trial.t, trial.q, trial.dq, trial.tau), trial


def run_trial(observer: MomentumObserver, trial: Dataset, thresholds: Thresholds) -> TrialDetection:
    """The observer and the alarms over one trial."""
    r = observer.run(trial.t, trial.q, trial.dq, trial.tau)
    alarm, quiet = alarms(trial.t, r, trial.dq, thresholds)
    return TrialDetection(
        trial.source, trial.t, r, trial.dq, alarm, quiet, spans(trial.t, r, trial.dq, alarm, thresholds)
    )


def held_out(
    observed: list[tuple[np.ndarray, Dataset]], gain: np.ndarray, dt: float, margin: float
) -> tuple[list[dict], list[ResultWarning]]:
    """Per calibration trial: its false alarms per minute at thresholds calibrated on the others. With one trial,
    its two halves in time stand for two (each scored with thresholds from the other)."""
    warnings = []
    parts = [(r, d, shown(d.source)) for r, d in observed]
    if len(parts) == 1:
        r, d, source = parts[0]
        parts = [(r[s], d.subset(s), f"{source} ({which} half)") for s, which in _halves(d.n)]
        warnings.append(
            ResultWarning(
                "one_calibration_trial",
                "one calibration trial: its false alarms are those of each half in time at thresholds from the other "
                "half; give more collision-free trials (--calibrate) for a held-out rate per trial",
            )
        )
    out = []
    for i, (r, d, source) in enumerate(parts):
        others = [p for k, p in enumerate(parts) if k != i]
        held = calibrate(
            [p[0] for p in others], [p[1].dq for p in others], [p[1].tau for p in others], gain, dt, margin
        )
        alarm, _ = alarms(d.t, r, d.dq, held)
        found = spans(d.t, r, d.dq, alarm, held)
        out.append(
            {
                "source": source,
                "duration_s": float(d.t[-1] - d.t[0]),
                "false_alarms": len(found),
                "false_alarms_per_minute": per_minute(len(found), d.t),
            }
        )
    return out, warnings


def _halves(n: int) -> list[tuple[np.ndarray, str]]:
    """The sample indices of a trial's first and second half."""
    return [(np.arange(n // 2), "first"), (np.arange(n // 2, n), "second")]
