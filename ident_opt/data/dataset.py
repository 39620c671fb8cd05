"""A trial as arrays (`Dataset`: t, q, dq, ddq, τ in SI units), and what is done with trials once read: derivatives
estimated again at another cut-off (`refiltered`), pools (`concat`), splits, and the check that a trial can be
fitted. Reading one is `ident_opt.data.loader`."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from ident_opt.errors import InputError
from ident_opt.numerics import signals
from ident_opt.numerics.derivatives import estimate_derivatives, instrument_derivatives, lowpass, segments


@dataclass
class Dataset:
    """One trial: time [s], joint angles [rad], velocities [rad/s], accelerations [rad/s²], torques [N m]."""

    source: str
    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    tau: np.ndarray
    extra: pd.DataFrame = field(default_factory=pd.DataFrame)
    derivatives: str = "given"
    dropped_rows: int = 0
    notes: list[str] = field(default_factory=list)
    cutoff_hz: float | None = None  # the derivative filter's cut-off actually used (None: derivatives given)
    #: τ through the same zero-phase low-pass as the angles (parallel filtering), for fits; None: τ as logged
    tau_filtered: np.ndarray | None = None
    #: (dq, ddq) of the instruments of IV, estimated at a lower cut-off than the regressor's
    #: (`derivatives.instrument_derivatives`); None when not estimated
    instruments: tuple[np.ndarray, np.ndarray] | None = None
    #: Whether a resting joint's velocity is held at 0 (`at_rest`; the problem's `[data] rest_velocity` resolved
    #: for this trial by the loader): derivatives estimated again (`refiltered`) are held alike.
    rests_held: bool = False

    @property
    def tau_fit(self) -> np.ndarray:
        """The torque fits use [N m]: filtered like the regressor's inputs when derivatives were estimated, so
        a fit compares like with like. Scores always use the measured `tau`."""
        return self.tau if self.tau_filtered is None else self.tau_filtered

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def rate_hz(self) -> float:
        """Median sampling rate [Hz]."""
        return float(1.0 / np.median(np.diff(self.t))) if self.n > 1 else float("nan")

    def subset(self, index: np.ndarray) -> Dataset:
        """The samples at `index` (an index array or boolean mask), in that order."""
        return replace(
            self,
            t=self.t[index],
            q=self.q[index],
            dq=self.dq[index],
            ddq=self.ddq[index],
            tau=self.tau[index],
            tau_filtered=None if self.tau_filtered is None else self.tau_filtered[index],
            instruments=None if self.instruments is None else tuple(x[index] for x in self.instruments),
            # a trial built in code may have no extra columns at all (an empty frame with no rows)
            extra=self.extra.iloc[np.arange(self.n)[index]].reset_index(drop=True) if len(self.extra) else self.extra,
        )

    def to_frame(self) -> pd.DataFrame:
        """The trial in the data format's column names (torques, not currents)."""
        cols = {"t": self.t}
        for name, arr in (("q", self.q), ("dq", self.dq), ("ddq", self.ddq), ("tau", self.tau)):
            cols.update({f"{name}{j + 1}": arr[:, j] for j in range(arr.shape[1])})
        return pd.concat([pd.DataFrame(cols), self.extra.reset_index(drop=True)], axis=1)


# ---------------------------------------------------------------------------------------------- reading
def in_source_convention(frame: pd.DataFrame, column_map: dict[str, tuple[float, float]]) -> pd.DataFrame:
    """A trial in the tool's convention written back in the data's own (the inverse of a robot's `column_map`:
    value = (value_tool − offset) / scale), so that reading it again maps it to what it was."""
    out = frame.copy()
    for name, (scale, offset) in column_map.items():
        if name in out:
            out[name] = (out[name] - offset) / scale
    return out


def convert(values: np.ndarray, scale: float, offset: float) -> np.ndarray:
    """A mapped column's conversion on the way in: scale × raw + offset (`[data.columns]`)."""
    return values if (scale, offset) == (1.0, 0.0) else scale * values + offset


def refiltered(d: Dataset, cutoff_hz: float) -> Dataset:
    """The trial with its derivatives (and the fit's filtered torque) estimated again at `cutoff_hz` [Hz], from
    its angles (and its logged velocities, if the file had them); logged accelerations stay as they are; a joint at
    rest held at 0 where the trial's were (`Dataset.rests_held`)."""
    logged_dq = d.dq if "velocities as logged" in d.derivatives else None
    dq, ddq, how = estimate_derivatives(d.t, d.q, cutoff_hz, logged_dq)
    if "accelerations as logged" in d.derivatives:
        ddq = d.ddq
    again = replace(
        d,
        dq=dq,
        ddq=ddq,
        derivatives=how,
        cutoff_hz=cutoff_hz,
        tau_filtered=lowpass(d.t, d.tau, cutoff_hz),
        instruments=instrument_derivatives(d.t, d.q, cutoff_hz),
    )
    return at_rest(again) if d.rests_held else again


def concat(trials: list[Dataset]) -> Dataset:
    """Several trials as one sample set (a pool): their samples one after the other, each with the derivatives
    estimated in its own file (no filter ran across a join). t is shifted to keep increasing [s]; statistics of
    the pool equal the sum of each trial's."""
    if len(trials) == 1:
        return trials[0]
    shifted, offset = [], 0.0
    for d in trials:
        shifted.append(d.t - d.t[0] + offset)
        offset = shifted[-1][-1] + float(np.median(np.diff(d.t)))
    filtered = [d.tau_fit for d in trials]
    cutoffs = {d.cutoff_hz for d in trials}
    return Dataset(
        " + ".join([trials[0].source, *(Path(d.source).name for d in trials[1:])]),  # the first in full
        np.concatenate(shifted),
        *(np.concatenate([getattr(d, k) for d in trials]) for k in ("q", "dq", "ddq", "tau")),
        extra=pd.concat([d.extra for d in trials], ignore_index=True),
        derivatives="; ".join(dict.fromkeys(d.derivatives for d in trials)),
        dropped_rows=sum(d.dropped_rows for d in trials),
        cutoff_hz=cutoffs.pop() if len(cutoffs) == 1 else None,
        tau_filtered=np.concatenate(filtered),
        instruments=None
        if any(d.instruments is None for d in trials)
        else tuple(np.concatenate([d.instruments[i] for d in trials]) for i in (0, 1)),
        rests_held=all(d.rests_held for d in trials),
    )


#: The largest |value| (SI units) of q, dq, ddq or τ that a fit can take: the regressor's products of four
#: such values stay far from overflow. Far beyond any arm (1e8 rad/s, 1e8 N·m), so --allow-implausible keeps it.
MAX_MAGNITUDE = 1e8


def fittable(trial, fit: bool = True) -> None:
    """InputError when `trial` cannot be fitted in double precision (a value beyond `MAX_MAGNITUDE`) or, with
    `fit`, when a joint's torque never varies (its NMSE would be 0/0); without `fit` the latter is a warning."""
    for name, values in (("q", trial.q), ("dq", trial.dq), ("ddq", trial.ddq), ("tau", trial.tau)):
        worst = float(abs(values).max()) if values.size else 0.0
        if not worst <= MAX_MAGNITUDE:
            raise InputError(
                f"{trial.source}: |{name}| reaches {worst:.3g} (SI units), beyond {MAX_MAGNITUDE:.0e}: no fit is "
                "possible in double precision; check the column's unit (--allow-implausible does not lift this)"
            )
    for j in range(trial.tau.shape[1]):
        column = trial.tau[:, j]
        if column.size and float(column.max() - column.min()) == 0.0:
            message = (
                f"{trial.source}: the torque of joint {j + 1} is constant ({float(column[0]):g} N·m in every row): "
                "nothing to identify on that joint, and its NMSE would be 0/0; check the column mapping"
            )
            if fit:
                raise InputError(message)
            print(f"warning: {message}", file=sys.stderr)


# ---------------------------------------------------------------------------------------------- splits
def shuffled_split(n: int, train_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The paper's protocol: shuffle the samples, then train on `train_fraction` of them."""
    from sklearn.model_selection import train_test_split  # here: scikit-learn takes a second to import

    _nonempty_parts(n, int(train_fraction * n))
    train, test = train_test_split(np.arange(n), train_size=train_fraction, random_state=seed, shuffle=True)
    return np.sort(train), np.sort(test)


def chronological_split(n: int, train_fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """The honest protocol within one trial: the first part in time trains, the rest tests."""
    cut = round(train_fraction * n)
    _nonempty_parts(n, cut)
    return np.arange(cut), np.arange(cut, n)


def _nonempty_parts(n: int, n_train: int) -> None:
    """InputError when a split of `n` samples with `n_train` training samples leaves a part empty."""
    if not 0 < n_train < n:
        raise InputError(
            f"a split of {n} samples into {n_train} training and {n - n_train} test samples leaves a part empty; "
            "give more samples or a [split] train_fraction nearer 0.5"
        )


def at_rest(trial: Dataset, window_s: float = signals.HOLD_WINDOW_S) -> Dataset:
    """The trial with the velocity of a joint at rest read as exactly 0 (its instruments' velocity too), each
    gap-free segment read alone (`derivatives.segments`, as its derivatives are): what the loader does where the
    problem's `[data] rest_velocity` says so (`holds_rests`), and the diagnosis always.

    Coulomb friction at rest is set-valued (stiction holds whatever the controller pushes, up to the breakaway
    level), and the sign of an estimated velocity at rest is noise: a model's fc·sgn(q̇) there is a random ±fc. A fit
    that reads it shrinks fc to hedge (simulated arm4, about half its samples at rest: least squares read 0.30, 0.42,
    0.21, 0.045 N·m for Coulomb levels 1.0, 1.5, 0.8, 0.15; with rests held, the true levels within 0.5 %), and a
    prediction that reads it predicts ±fc at random (results/slow_samples.md). A joint is at rest at a sample
    (`signals.resting`) when |q̇| is below REST_FRACTION of its speed scale (95th percentile of |q̇|) there and stays
    below it for `window_s` before or after: the loader's `HOLD_WINDOW_S` (50 ms: a stop, with the filter's ringing
    just before a start or after it, and not a smooth reversal, whose friction flips), the diagnosis's
    `REST_WINDOW_S` (10 ms: it leaves every brief slow stretch out of its comparisons). Holding again with the same
    or a shorter window changes nothing outside the newly held samples: the zeros replace samples below the
    threshold, which leaves the 95th percentile where it was."""
    if trial.n < 2:
        return replace(trial, rests_held=True)
    rest = np.zeros(trial.dq.shape, dtype=bool)
    for seg in segments(trial.t, trial.cutoff_hz):
        if seg.stop - seg.start >= 2:
            rest[seg] = signals.resting(trial.dq[seg], float(np.median(np.diff(trial.t[seg]))), window_s)
    instruments = trial.instruments
    if instruments is not None:
        instruments = (np.where(rest, 0.0, instruments[0]), instruments[1])
    return replace(trial, dq=np.where(rest, 0.0, trial.dq), instruments=instruments, rests_held=True)


def holds_rests(rest_velocity: str, trial: Dataset) -> bool:
    """Whether the loader holds `trial`'s resting velocities at 0 under `[data] rest_velocity` (`DataSpec`): "zero"
    always, "as_read" never, "auto" where the loader estimated the velocities (`Dataset.derivatives` says how)."""
    if rest_velocity == "auto":
        return trial.cutoff_hz is not None and "velocities as logged" not in trial.derivatives
    return rest_velocity == "zero"


def rest_note(rest_velocity: str, shares: np.ndarray) -> str:
    """The trial's note that its resting velocities were held at 0 (`at_rest`), with each joint's share of samples
    at rest (`shares`, (n,)), for `check` and the reports."""
    listed = ", ".join(f"{s:.0%}" for s in shares)
    return f"velocity read as 0 where a joint rests ([data] rest_velocity = {rest_velocity!r}): {listed} of the samples"
