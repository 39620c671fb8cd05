"""How far a fit on measured data can be trusted: the checks behind `compare`'s warnings.

- **OLS against IV.** Noise in estimated accelerations sits inside the regressor and biases least squares
  toward zero (errors-in-variables); the instrumental-variable estimate (`fitting.iv`) is not biased that
  way. When an inertial, coupling or gravity parameter of the two differs by more than 3 standard errors
  *and* by more than `OLS_IV_TOLERANCE` of its IV value, the cut-off lets noise into the regressor. Judged only
  when the derivatives were estimated: logged ones (MERIt's) carry the logger's own filters and lag, which the
  instruments (differentiated from q) do not share, so there the two differ for more reasons than noise.
- **Cut-off sensitivity.** OLS again with every training trial's derivatives at ½× and 2× its cut-off. At 2×
  more noise enters the regressor: a move beyond 3 SE and `SENSITIVITY_TOLERANCE` of its value means the
  result depends on the cut-off. The ½× fit is reported, not judged: a cut-off chosen at 1.2× the motion's band
  edge (`derivatives.choose_cutoff`) halved removes part of the motion itself, and the parameters move for that reason.
- **Slow samples.** A joint's samples slower than its stick speed (`signals.stick_speed`: 2 % of its
  95th-percentile speed) carry friction that stiction sets: anything up to the breakaway level, following what the
  controller commands. Where the loader holds a resting joint's velocity at 0 (`data.dataset.at_rest`, the problem's
  `[data] rest_velocity`) the model predicts no friction there and its friction is read from the moving samples;
  where it does not, the sign of a velocity at rest decides the Coulomb term. What stiction holds is in no model,
  so where such samples are many (`SLOW_SHARE` of a joint's training samples or more) that error weighs in every
  score of the joint and the friction rests on the other samples alone (results/slow_samples.md).
- **Angle convention.** OLS with the `joint_offset` extension's sine gravity columns: the direction of gravity
  per joint, δ1 = atan2(−b1s, b1), δ1 + δ2 = atan2(−b2s, b2) (`docs/conventions.md`), with derivatives at the
  motion's own cut-off (`derivatives.choose_cutoff`, if lower than the trial's) so a noisy cut-off cannot hide
  it. Beyond `CONVENTION_TOLERANCE_RAD`, near a quarter, half or three-quarter turn, the data's zero is not
  ident-opt's, and the warning gives the `[data.columns]` offset that fixes it (that multiple of π/2). A large direction
  elsewhere is reported, not warned about: the sine columns then absorb some other effect (on MERIt's joint 2,
  δ2 ≈ 0.9 rad with a 24 % smaller residual, where the logged zero is right).

Standard errors assume independent residuals (optimistic on densely sampled data), so every rule also asks
for a relative change: the SE alone would flag every real trial.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ident_opt.arm.base import Arm
from ident_opt.data.dataset import Dataset, refiltered
from ident_opt.fitting import estimators
from ident_opt.fitting.fit import LinearFit
from ident_opt.fitting.stats import Stats
from ident_opt.numerics import signals
from ident_opt.numerics.derivatives import choose_cutoff
from ident_opt.warnings import ResultWarning

#: OLS and IV disagree when a judged parameter differs by more than this fraction of its IV value (and 3 SE).
OLS_IV_TOLERANCE = 0.10
#: A judged parameter depends on the cut-off when 2× moves it by more than this fraction (and 3 SE).
SENSITIVITY_TOLERANCE = 0.25
#: The data's zero is off when the fitted direction of gravity differs from the convention's by more [rad] ...
CONVENTION_TOLERANCE_RAD = 0.15
#: ... and lies within this of a quarter, half or three-quarter turn [rad]: the zeros robots use (hanging down,
#: pointing up, the other way). A direction elsewhere is the sine columns absorbing another effect, not a zero.
QUARTER_TURN_TOLERANCE_RAD = 0.35
#: A joint with this share of its training samples (or more) slower than its stick speed is the warning
#: `slow_samples`: the shipped real trials read 56–73 % (MERIt), 24 % (TX40) and 1.5–5 % (the others).
SLOW_SHARE = 0.2
#: The parameter kinds the checks judge (friction and armature are small and poorly determined on most trials).
JUDGED_KINDS = ("inertia", "coupling", "gravity")
#: The cut-off factors of the sensitivity check.
FACTORS = (0.5, 2.0)


@dataclass
class Trust:
    """The checks' results: the sensitivity fits {factor: OLS fit}, the fitted gravity directions [rad] and
    the offsets that would fix them [rad], and the warnings."""

    sensitivity: dict[float, LinearFit] = field(default_factory=dict)
    cutoffs: list[float] = field(default_factory=list)  # each training trial's cut-off [Hz]
    gravity_direction: dict[str, float] = field(default_factory=dict)  # "delta1", "delta2" [rad]
    warnings: list[ResultWarning] = field(default_factory=list)


def stats_of(model: Arm, trials: list[Dataset]) -> Stats:
    """Σ of each trial's statistics, with the torque the fits use (`Dataset.tau_fit`)."""
    return estimators.statistics(model, trials, "ols")


def iv_fit(model: Arm, trials: list[Dataset]) -> LinearFit:
    """IDIM-IV on all training trials (instrument statistics added up, each trial's derivatives its own), on the
    base parameters when the regressor does not determine every parameter (`estimators.iv`)."""
    return estimators.iv(estimators.statistics(model, trials), model)


def _judged(model: Arm) -> list[int]:
    return [i for i, p in enumerate(model.parameters) if p.kind in JUDGED_KINDS]


def _moved(model: Arm, a: LinearFit, b: LinearFit, tolerance: float) -> list[tuple[str, float, float]]:
    """(name, a's value, b's value) of the judged parameters that differ by > 3 SE and > `tolerance` × |b|."""
    out = []
    for i in _judged(model):
        diff = abs(a.pi[i] - b.pi[i])
        se = math.hypot(a.se[i], b.se[i])
        if diff > 3 * se and diff > tolerance * abs(b.pi[i]):
            out.append((model.names[i], float(a.pi[i]), float(b.pi[i])))
    return out


def _listing(moved: list[tuple[str, float, float]]) -> str:
    return ", ".join(f"{n} {x:.4g} vs {y:.4g}" for n, x, y in moved)


def _remedy(trials: list[Dataset], setting: float | str | None) -> str:
    """What to change so that least squares itself is not biased, never what the run already did: with a fixed
    cut-off above the one the data support, that one (`derivatives.cutoff_choice`); otherwise less noise in the
    regressor itself."""
    if setting is not None and setting != "auto":
        supported = [choose_cutoff(d.t, d.q) for d in trials]
        if max(supported) < 0.8 * min(d.cutoff_hz for d in trials):
            return (
                f'Set [data] derivative_cutoff_hz = "auto": the data support {_hz(supported)} (where noise starts to '
                "outweigh motion in the accelerations)."
            )
    return (
        "The cut-off already sits where noise starts to outweigh motion; to take noise out of the regressor itself, "
        "log the joint velocities (dq) from the drives or record at a higher rate."
    )


def check_ols_iv(
    model: Arm, ols: LinearFit, iv: LinearFit, trials: list[Dataset], setting: float | str | None = None
) -> list[ResultWarning]:
    """The OLS-against-IV rule (module doc)."""
    moved = _moved(model, ols, iv, OLS_IV_TOLERANCE)
    if not moved or any(d.cutoff_hz is None for d in trials):
        return []
    cutoffs = [d.cutoff_hz for d in trials]
    return [
        ResultWarning(
            "ols_iv_disagree",
            f"OLS and the instrumental-variable fit disagree at the derivative cut-off {_hz(cutoffs)} "
            f"({_listing(moved)}): noise in the estimated accelerations biases OLS toward zero. The recommended fit is "
            "therefore the robust one (consistent, on instrumental variables), and every command uses it. "
            + _remedy(trials, setting),
        )
    ]


def _hz(cutoffs: list[float]) -> str:
    low, high = min(cutoffs), max(cutoffs)
    return f"{low:.3g} Hz" if math.isclose(low, high) else f"{low:.3g}–{high:.3g} Hz"


def check_cutoff(
    model: Arm, trials: list[Dataset], ols: LinearFit, setting: float | str | None = None
) -> tuple[dict[float, LinearFit], list[ResultWarning]]:
    """OLS at ½× and 2× each trial's cut-off; a warning when 2× moves a judged parameter (module doc)."""
    if any(d.cutoff_hz is None for d in trials):
        return {}, []
    fits = {}
    for factor in FACTORS:
        moved_trials = [refiltered(d, factor * d.cutoff_hz) for d in trials]
        fits[factor] = estimators.fit("ols", stats_of(model, moved_trials), model)
    moved = _moved(model, fits[2.0], ols, SENSITIVITY_TOLERANCE)
    if not moved:
        return fits, []
    message = (
        f"the parameters depend on the derivative cut-off ({_hz([d.cutoff_hz for d in trials])}): at twice it, "
        f"{_listing(moved)} (2× vs chosen): noise is in the regressor. The recommended fit is therefore the robust "
        "one (consistent, on instrumental variables), and every command uses it. " + _remedy(trials, setting)
    )
    return fits, [ResultWarning("cutoff_sensitivity", message)]


#: A trial's cut-off this far from the median of the problem's trials (either way) is an outlier: trials differ in
#: motion (DFKI C.0's single-joint sines end at a third of its other trials' band), a misread trial by far more (a
#: joint at rest read as noise to a quarter of the rate: 20× and more).
CUTOFF_OUTLIER = 4.0


def check_cutoff_outliers(trials: list[Dataset]) -> list[ResultWarning]:
    """A warning per training trial whose chosen cut-off is more than `CUTOFF_OUTLIER` × (or less than 1/that) the
    median of the problem's trials (three or more, with cut-offs chosen per trial): its spectrum reads differently
    from the others', which the user should look at rather than have it enter the fit silently."""
    cutoffs = [d.cutoff_hz for d in trials]
    if len(trials) < 3 or any(c is None for c in cutoffs) or len(set(cutoffs)) == 1:
        return []
    median = float(np.median(cutoffs))
    out = []
    for d in trials:
        ratio = d.cutoff_hz / median
        if not 1 / CUTOFF_OUTLIER <= ratio <= CUTOFF_OUTLIER:
            out.append(
                ResultWarning(
                    "cutoff_outlier",
                    f"{d.source}: its derivative cut-off ({d.cutoff_hz:.3g} Hz) is {ratio:.2g}× the median of the "
                    f"training trials' ({median:.3g} Hz); its spectrum reads differently (a joint at rest, a burst of "
                    "noise, another rate?). Its derivatives are estimated at its own cut-off; look at that trial, or "
                    "pin [data] derivative_cutoff_hz for all.",
                )
            )
    return out


def check_convention(
    robot, model: Arm, trials: list[Dataset], conversions: dict[str, tuple[float, float]] | None = None
) -> tuple[dict[str, float], list[ResultWarning]]:
    """The direction of gravity per joint from OLS with the sine gravity columns of `robot`'s joint-offset model;
    a warning with the `[data.columns]` offsets that fix it when it is off by more than
    `CONVENTION_TOLERANCE_RAD`."""
    extended = model if "b1s" in model.names else robot.model((*model.extensions, "joint_offset"))
    # Gravity is static: judge it at the motion's own cut-off, so that a noisy cut-off cannot hide the zero.
    trials = [d if d.cutoff_hz is None else refiltered(d, min(d.cutoff_hz, choose_cutoff(d.t, d.q))) for d in trials]
    p = estimators.fit("ols", stats_of(extended, trials), extended).as_dict()
    d1 = math.atan2(-p["b1s"], p["b1"])
    d12 = math.atan2(-p["b2s"], p["b2"])
    d2 = math.remainder(d12 - d1, math.tau)
    direction = {"delta1": d1, "delta2": d2}
    turns = {j: round(d / (math.pi / 2)) for j, d in enumerate((d1, d2))}
    off = [
        j
        for j, d in enumerate((d1, d2))
        if abs(d) > CONVENTION_TOLERANCE_RAD
        and turns[j] != 0
        and abs(d - turns[j] * math.pi / 2) < QUARTER_TURN_TOLERANCE_RAD
    ]
    if not off:
        return direction, []
    conversions = conversions or {}
    fixes = []
    for j in off:
        scale, offset = conversions.get(f"q{j + 1}", (1.0, 0.0))
        new = offset + turns[j] * math.pi / 2
        fixes.append(f"q{j + 1} = {{ column = …, offset = {new:.7g} }}" + (f" (scale {scale:g})" if scale != 1 else ""))
    sentence = (
        f"gravity acts as if the angles were off by δ1 = {d1:+.3f} rad, δ2 = {d2:+.3f} rad "
        f"({math.degrees(d1):+.0f}°, {math.degrees(d2):+.0f}°): the data's zero is not ident-opt's (q1 from the "
        "horizontal, q2 relative to link 1, counter-clockwise, docs/conventions.md). In [data.columns] set "
        + "; ".join(fixes)
        + ", then run again."
    )
    return direction, [ResultWarning("angle_convention", sentence)]


def checks(
    model: Arm,
    trials: list[Dataset],
    ols: LinearFit,
    iv: LinearFit,
    conversions: dict[str, tuple[float, float]] | None,
    robot,
    setting: float | str | None = None,
) -> Trust:
    """Every check on the training trials: the convention first (a wrong zero spoils the others), where the arm
    offers the joint-offset model that reads it (`Robot.extensions`: the planar arm's). `setting`: the problem's
    `derivative_cutoff_hz`, so that advice never asks for what the run already did."""
    direction, warnings = {}, []
    if "joint_offset" in robot.extensions:
        direction, warnings = check_convention(robot, model, trials, conversions)
    logged = any(d.cutoff_hz is None for d in trials)
    cutoffs = [] if logged else [d.cutoff_hz for d in trials]
    sensitivity, cut_warnings = check_cutoff(model, trials, ols, setting)
    if not warnings:  # with the zero off, every parameter is off: fix the convention first
        warnings += check_ols_iv(model, ols, iv, trials, setting) + cut_warnings
    warnings += check_cutoff_outliers(trials)
    return Trust(sensitivity, cutoffs, direction, warnings)


def check_slow_samples(model: Arm, trials: list[Dataset], joints: tuple[str, ...]) -> list[ResultWarning]:
    """The warning `slow_samples` naming each joint (of `joints`, the arm's names) with at least `SLOW_SHARE` of the
    training `trials`' samples slower than its stick speed (module doc); none for a model without friction
    parameters (by kind, as the consistency constraints tell them: no name is matched)."""
    if not trials or not any(p.kind == "friction" for p in model.parameters):
        return []
    slow = sum((np.abs(d.dq) < signals.stick_speed(d.dq)).sum(axis=0) for d in trials)
    share = slow / sum(d.n for d in trials)
    named = [f"{joint} {s:.0%}" for joint, s in zip(joints, share) if s >= SLOW_SHARE]
    if not named:
        return []
    return [
        ResultWarning(
            "slow_samples",
            f"of the training samples, {', '.join(named)} move slower than the joint's stick speed (2 % of its "
            "95th-percentile speed): there the torque is whatever stiction holds, which no model predicts, so that "
            "error weighs in every score of the joint, and the friction is read from the other samples (where "
            "`[data] rest_velocity` holds a resting joint's velocity at 0) or from the sign of a velocity at rest "
            "(where it does not). Record motion that keeps the joints moving (`ident-opt excite`) for a sharper "
            "friction estimate.",
        )
    ]


#: A link's mass beyond this factor of its nominal one (either way), or a total beyond `TOTAL_MASS_RANGE` of the
#: nominal total, is not a plausible identification of that arm.
LINK_MASS_FACTOR = 3.0
TOTAL_MASS_RANGE = 0.5


def check_masses(model: Arm, pis: dict[str, np.ndarray], nominal: dict[str, float]) -> list[ResultWarning]:
    """A warning per parameter set π of `model` (by the fit's name) whose links' masses (`Arm.link_masses`) are far
    from the nominal ones (`nominal`, by link [kg]): a link beyond `LINK_MASS_FACTOR` × its nominal mass or below
    1/`LINK_MASS_FACTOR` of it, or a total beyond ± `TOTAL_MASS_RANGE` of the nominal total. Pass only estimates:
    a fit of base parameters lifted to standard ones (`fitting.base.lifted_fit`) holds a representative."""
    if not nominal:
        return []
    total0 = sum(nominal.values())
    out = []
    for key, pi in pis.items():
        masses = model.link_masses(pi)
        odd = [
            f"{link} {m:.3g} kg (nominal {nominal[link]:.3g})"
            for link, m in masses.items()
            if nominal[link] > 0 and not 1 / LINK_MASS_FACTOR <= m / nominal[link] <= LINK_MASS_FACTOR
        ]
        total = sum(masses.values())
        if odd or abs(total / total0 - 1) > TOTAL_MASS_RANGE:
            out.append(
                ResultWarning(
                    "implausible_masses",
                    f"the {key} fit's links weigh {total:.3g} kg in all (nominal {total0:.3g} kg)"
                    + (f"; {', '.join(odd)}" if odd else "")
                    + ": the data do not pin these masses and the fit put them where no real arm has them. Prefer a "
                    "fit with the nominal model as a prior (its mass range, `[robot] mass_range`), or record motion "
                    "that excites these links (`ident-opt excite`).",
                )
            )
    return out
