"""The API's door for what code hands the pipeline instead of a file: arrays (`checked_array`), parsed problems
(`checked_problem`) and trials (`checked_trials`, `checked_trial`), each checked before any work the way the loader
checks a file's columns (its shape, one column per joint of the arm, every value finite, time strictly increasing).
Every fault is an InputError naming the argument as the caller wrote it ("fit: trials[0].q[3, 1]"); nothing is
truncated, broadcast or cast silently."""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import replace
from numbers import Real
from pathlib import Path

import numpy as np
import pandas as pd

from ident_opt.arm.base import Robot
from ident_opt.data.checks import _check_time
from ident_opt.data.dataset import MAX_MAGNITUDE, Dataset, fittable
from ident_opt.errors import InputError, excerpt
from ident_opt.problem.spec import DataSpec, Problem

#: The shortest median sampling step a trial built in code may have [s] (10 MHz: far beyond any joint logger; the
#: derivative filters' design becomes singular long before 1e-300 s). Files have their own, stricter, rate check.
MIN_STEP_S = 1e-7


def checked_array(
    name: str, value: object, shape: tuple[int | None, ...], why: str = "", *, infinite: bool = False
) -> np.ndarray:
    """`value` as a float array of `shape` (None: any length along that axis; a vector is the one column of a
    shape (N, 1)) with every value finite (`infinite`: ±inf allowed, never NaN): the API's door for an array
    argument. An InputError naming `name` (as the caller writes it: "q", "fit: trials[0].tau") otherwise, never a
    silent conversion: strings, complex numbers and dates are refused, not cast; `why` says what the shape means."""
    try:
        raw = np.asarray(value)
        kind = raw.dtype.kind
        a = raw.astype(float, copy=False) if kind in "biufO" else None
    except (TypeError, ValueError, OverflowError):
        a = None
    if a is None:
        raise InputError(f"{name} must be an array of real numbers, got {excerpt(value)}")
    if len(shape) == 2 and shape[1] == 1 and a.ndim == 1:
        a = a.reshape(-1, 1)
    if a.ndim != len(shape) or any(want is not None and want != got for want, got in zip(shape, a.shape)):
        dims = ", ".join("N" if want is None else str(want) for want in shape)
        raise InputError(
            f"{name} must be an array of shape ({dims}{',' if len(shape) == 1 else ''}){why}, got {a.shape}"
        )
    bad = np.isnan(a) if infinite else ~np.isfinite(a)
    if bad.any():
        at = np.unravel_index(int(np.argmax(bad)), a.shape)
        where = ", ".join(str(int(i)) for i in at)
        allowed = "a number (±inf for no bound)" if infinite else "a finite number"
        raise InputError(f"{name}[{where}] is {excerpt(float(a[at]))}: every value must be {allowed}")
    return a


def checked_problem(problem: object, command: str) -> Problem:
    """`problem` when it is a parsed problem file (`ident_opt.load_problem`); an InputError naming it otherwise."""
    if not isinstance(problem, Problem):
        raise InputError(
            f"{command}: problem must be a parsed problem file (ident_opt.load_problem(path)), got {excerpt(problem)}"
        )
    return problem


def checked_trials(
    problem: Problem, trials: object, command: str, argument: str, *, required: bool = True, fit: bool = False
) -> list[Dataset]:
    """`trials` (a sequence of `Dataset`, or one) as a list, each checked against the problem's arm
    (`checked_trial`, named `argument[i]` in messages); none at all is an InputError when `required`. `fit`: they
    are about to be fitted, so the loader's `fittable` applies too (magnitudes, a constant torque)."""
    checked_problem(problem, command)
    name = f"{command}: {argument}"
    if trials is None:
        trials = []
    elif isinstance(trials, Dataset):
        trials = [trials]
    elif isinstance(trials, (str, bytes, os.PathLike)) or not isinstance(trials, Iterable):
        raise InputError(
            f"{name} must be a list of trials (ident_opt.Dataset: ident_opt.load_trials or ident_opt.trial make "
            f"them), got {excerpt(trials)}"
        )
    trials = list(trials)
    if required and not trials:
        raise InputError(
            f"{name} is empty: give at least one trial (ident_opt.load_trials reads files, ident_opt.trial "
            "takes arrays)"
        )
    checked = [checked_trial(problem.robot, d, f"{name}[{i}]") for i, d in enumerate(trials)]
    if fit:
        for d in checked:
            fittable(d)
    return checked


def checked_trial(robot: Robot, trial: object, name: str) -> Dataset:
    """`trial` when it is a `Dataset` of `robot`'s arm as the pipeline makes them: t (N,) strictly increasing
    (`_check_time`, the loader's own check), q, dq, ddq, tau (and the fit's filtered torque and the instruments,
    when there) (N, n), every value finite, at least 2 samples. A trial built in code is refused with an
    InputError naming `name` and the field, never truncated or broadcast; arrays given as lists come back as
    float arrays (the same trial object when nothing needed converting)."""
    if not isinstance(trial, Dataset):
        raise InputError(
            f"{name} must be a trial (ident_opt.Dataset: ident_opt.load_trials or ident_opt.trial make one), got "
            f"{type(trial).__name__} {excerpt(trial)}"
        )
    t = checked_array(f"{name}.t", trial.t, (None,), " (the sample times [s])")
    if len(t) < 2:
        raise InputError(f"{name} has {len(t)} sample(s): a trial needs at least 2")
    n, N = robot.n_joints, len(t)
    why = f" (one row per sample of t, one column per joint of {robot.described_as})"
    arrays: dict[str, object] = {"t": t}
    for field in ("q", "dq", "ddq", "tau", "tau_filtered"):
        value = getattr(trial, field)
        if value is not None or field != "tau_filtered":
            arrays[field] = checked_array(f"{name}.{field}", value, (N, n), why)
    if trial.instruments is not None:
        if not isinstance(trial.instruments, (tuple, list)) or len(trial.instruments) != 2:
            raise InputError(f"{name}.instruments must be None or the pair (dq, ddq) of the instruments")
        pair = tuple(checked_array(f"{name}.instruments[{i}]", v, (N, n), why) for i, v in enumerate(trial.instruments))
        arrays["instruments"] = trial.instruments if all(a is b for a, b in zip(pair, trial.instruments)) else pair
    _check_time(t, Path(name), DataSpec())
    _check_scales(arrays, name)
    if not isinstance(trial.source, str):
        raise InputError(f"{name}.source must be a string naming the trial, got {excerpt(trial.source)}")
    cutoff = trial.cutoff_hz
    if cutoff is not None and not (isinstance(cutoff, Real) and not isinstance(cutoff, bool) and 0 < cutoff < np.inf):
        raise InputError(
            f"{name}.cutoff_hz must be None (derivatives given) or a cut-off > 0 Hz, got {excerpt(cutoff)}"
        )
    if not isinstance(trial.extra, pd.DataFrame) or len(trial.extra) not in (0, N):
        rows = len(trial.extra) if isinstance(trial.extra, pd.DataFrame) else excerpt(trial.extra)
        raise InputError(f"{name}.extra must be a DataFrame with no rows or one row per sample ({N}), got {rows}")
    changed = {k: v for k, v in arrays.items() if v is not getattr(trial, k)}
    return replace(trial, **changed) if changed else trial


def _check_scales(arrays: dict[str, object], name: str) -> None:
    """A trial built in code within what double precision and the derivative filters handle: a median step of at
    least `MIN_STEP_S`, every signal within `MAX_MAGNITUDE` (the loader's own bound); an InputError naming it."""
    t = arrays["t"]
    step = float(np.median(np.diff(t)))
    if step < MIN_STEP_S:
        raise InputError(
            f"{name}.t steps by {step:.3g} s (median): below {MIN_STEP_S:g} s ({1 / MIN_STEP_S:g} Hz), beyond any "
            "logger; is t in seconds?"
        )
    pairs = [(k, v) for k, v in arrays.items() if k not in ("t", "instruments")]
    pairs += [(f"instruments[{i}]", v) for i, v in enumerate(arrays.get("instruments", ()))]
    for label, value in pairs:
        worst = float(np.abs(value).max()) if np.size(value) else 0.0
        if worst > MAX_MAGNITUDE:
            raise InputError(
                f"{name}.{label} reaches {worst:.3g} (SI units), beyond {MAX_MAGNITUDE:.0e}: no fit is possible in "
                "double precision"
            )
