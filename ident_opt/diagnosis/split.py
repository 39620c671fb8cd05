"""The diagnosis's data: the training and held-out parts of the trials and how they are prepared.

Split: with a second (unseen) trial, the first trial trains and the second is held out; with one trial, the first
`train_fraction` of it in time trains and the rest is held out (contiguous, so delays and modes survive the split) —
or, when a joint barely moves in that last part and less so in the first, the first part is held out (`held_out`);
a joint the held-out part still barely moves is a warning (`compared_warnings`). Both parts are `prepare`d alike:
the torque low-passed like the derivatives, the velocity of a joint at rest read as 0 (`data.dataset.at_rest`,
whatever the problem's `[data] rest_velocity`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy import signal

from ident_opt.data.dataset import Dataset, at_rest, chronological_split, refiltered
from ident_opt.errors import InputError
from ident_opt.numerics import signals
from ident_opt.numerics.derivatives import choose_cutoff
from ident_opt.outputs import shown
from ident_opt.warnings import ResultWarning

#: Fewest held-out / training samples that make a diagnosis meaningful.
MIN_SAMPLES = 200


#: A joint is under-compared when the share of its held-out samples in motion is below this fraction of the share of
#: its training samples in motion: what a cause does on it can hardly show in the held-out score.
UNDER_COMPARED = 0.25


def compared(train_dq: np.ndarray, test_dq: np.ndarray) -> np.ndarray:
    """(n,): for each joint, the share of held-out samples in motion over the share of training samples in motion
    (1: the held-out part exercises it as much as the training part). In motion: faster than its stick speed on the
    training part (`signals.stick_speed`), the samples an arm's diagnosis compares."""
    fast = signals.stick_speed(train_dq)
    trained = np.mean(np.abs(train_dq) >= fast, axis=0)
    held = np.mean(np.abs(test_dq) >= fast, axis=0)
    return held / np.maximum(trained, np.finfo(float).tiny)


def split(train: Dataset, test: Dataset | None, train_fraction: float) -> tuple[Dataset, Dataset, str]:
    """(training part, held-out part, description); see the module docstring and `held_out`. The description names
    the trials as every output does (`outputs.shown`: relative to the working folder when inside it), never the
    absolute paths the problem file resolved them to."""
    if test is not None:
        return train, test, f"train on {shown(train.source)}, held out: {shown(test.source)}"
    tr, te, how = held_out(train, train_fraction)
    return train.subset(tr), train.subset(te), how


def held_out(trial: Dataset, train_fraction: float) -> tuple[np.ndarray, np.ndarray, str]:
    """(training indices, held-out indices, description) of one trial: the last `1 − train_fraction` in time is held
    out, unless a joint is under-compared there (`UNDER_COMPARED`: a point-to-point trial whose last moves leave one
    joint at rest) and less so when the first part is held out instead. Both parts stay contiguous."""
    tr, te = chronological_split(trial.n, train_fraction)
    worst = compared(trial.dq[tr], trial.dq[te]).min()
    if worst < UNDER_COMPARED:
        te_first, tr_last = chronological_split(trial.n, 1.0 - train_fraction)
        if compared(trial.dq[tr_last], trial.dq[te_first]).min() > worst:
            held = f"{1.0 - train_fraction:.0%}"
            return (
                tr_last,
                te_first,
                f"chronological, held out first: the last {train_fraction:.0%} of {shown(trial.source)} trains, "
                f"the first {held} is held out (a joint moves too little in its last {held})",
            )
    return tr, te, f"chronological: first {train_fraction:.0%} of {shown(trial.source)} trains, the rest is held out"


def compared_warnings(train: Dataset, test: Dataset, names: tuple[str, ...]) -> list[ResultWarning]:
    """A warning per joint the held-out part under-compares (`compared`): the diagnosis cannot judge a cause on it."""
    share = compared(train.dq, test.dq)
    low = [j for j in range(len(share)) if share[j] < UNDER_COMPARED]
    if not low:
        return []
    joints = ", ".join(f"{names[j]} (q{j + 1}: {share[j]:.0%})" for j in low)
    return [
        ResultWarning(
            "joint_not_compared",
            f"the held-out part moves {joints} far less than the training part does (share of samples in motion, "
            "held out over training): a cause on such a joint can hardly show in the held-out score, so `none` "
            "there is not evidence of its absence; record a trial that moves every joint throughout, or hold out "
            "another trial",
        )
    ]


def logged_bandwidth(trial: Dataset) -> tuple[Dataset, float | None]:
    """(The trial, the torque's cut-off [Hz]) for derivatives as logged, under "auto".

    The logger's filter is unknown; its bandwidth is read from the logged accelerations
    (`signals.matched_cutoff`). Where it is narrower than what the angles support (`derivatives.choose_cutoff`,
    the rule the loader uses for a file without derivatives), the derivatives are estimated again from the
    angles at that cut-off (`data.refiltered`): a narrow logger filter (a Savitzky–Golay filter of 21 samples at
    100 Hz passes 4.7 Hz) smears Coulomb steps and modes that the data hold. Assumption: the angles are logged
    at the full rate and resolution, so they carry the motion's whole band. The trial keeps every sample (the
    held-out part is aligned with the raw torque's)."""
    matched = signals.matched_cutoff(trial.t, trial.q, trial.ddq)
    if matched is None:
        return trial, None
    supported = choose_cutoff(trial.t, trial.q)
    if matched >= supported:
        return trial, matched
    return refiltered(trial, supported), supported


def prepare(trial: Dataset, torque_filter_hz: float | str | None) -> Dataset:
    """`at_rest`, then the torque low-passed by the zero-phase filter the derivatives are estimated with
    (4th-order Butterworth at `torque_filter_hz`, forward-backward; "auto": the cut-off the trial's derivatives
    were estimated with, `Dataset.cutoff_hz`, or for derivatives as logged the bandwidth of the logger's own
    filter, with the derivatives estimated again where that filter is narrower than the data, `logged_bandwidth`;
    None: no filter).

    Estimated accelerations are a smoothed version of the true ones (a step in acceleration becomes a ramp
    over tens of ms); the measured torque steps. Filtering τ the same way puts both sides of τ = Y π in the
    same bandwidth, so the smoothing mismatch at every start and stop does not pose as a delay or a mode,
    and noise above the cut-off goes too. Modes and delays inside the band are untouched (the filter is
    zero-phase and linear).
    """
    if torque_filter_hz == "auto":  # the problem's `derivative_cutoff_hz = "auto"`: the one this trial was read with
        trial, torque_filter_hz = (trial, trial.cutoff_hz) if trial.cutoff_hz is not None else logged_bandwidth(trial)
    trial = at_rest(trial, signals.REST_WINDOW_S)  # the diagnosis's shorter window (`data.dataset.at_rest`)
    if torque_filter_hz is None:
        return trial
    dt = float(np.median(np.diff(trial.t)))
    if torque_filter_hz >= 0.45 / dt or trial.n <= 30:
        return trial
    b, a = signal.butter(4, torque_filter_hz * 2 * dt)
    return replace(trial, tau=signal.filtfilt(b, a, trial.tau, axis=0))


#: [rad/s] A joint whose speed never exceeds this is still: its derivatives re-estimated from a constant angle are
#: round-off, not motion.
STILL_SPEED = 1e-9


def parts(
    trial: Dataset, unseen: Dataset | None, train_fraction: float, torque_filter_hz, names: tuple[str, ...]
) -> tuple[Dataset, Dataset, Dataset, str]:
    """(training part, held-out part, the held-out part's measured torque as logged, the split in words): `prepare`d
    and `split`; an InputError when there is too little data, a torque channel is constant, or a joint never
    moves in the training part (named: nothing about it can be fitted, and its rows would be one rest stretch)."""
    prepared = prepare(trial, torque_filter_hz)
    if unseen is not None:
        train, test, how = split(prepared, prepare(unseen, torque_filter_hz), train_fraction)
        raw_test = unseen  # the measured torque, as compare and identify see it
    else:  # one choice of samples (from the trial as logged, as `fitting.recommend.for_diagnosis` makes it)
        tr, te, how = held_out(trial, train_fraction)
        train, test, raw_test = prepared.subset(tr), prepared.subset(te), trial.subset(te)
    if train.n < MIN_SAMPLES or test.n < MIN_SAMPLES:
        raise InputError(
            f"{trial.source}: too little data to diagnose ({train.n} training and {test.n} held-out "
            f"samples; at least {MIN_SAMPLES} each)"
        )
    for ds, part in ((train, "training"), (test, "held-out")):
        if np.any(np.var(ds.tau, axis=0) <= 0):
            raise InputError(f"{ds.source}: a torque channel is constant; nothing to diagnose")
        still = (
            [j for j in range(ds.dq.shape[1]) if np.max(np.abs(ds.dq[:, j])) < STILL_SPEED]
            if part == "training"
            else []
        )
        if still:
            joints = ", ".join(f"{names[j]} (q{j + 1})" for j in still)
            raise InputError(
                f"{ds.source}: joint{'s' if len(still) > 1 else ''} {joints} never move{'' if len(still) > 1 else 's'} "
                f"in the {part} part; the diagnosis needs every joint in motion (move it, or leave it out of the "
                "problem)"
            )
    return train, test, raw_test, how
