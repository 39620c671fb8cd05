"""How close the simulator's calibrated default is to a real trial: both get the same treatment — the rigid
model (`RIGID`) fitted by OLS on the whole trial, then its residual τ − Y π̂ per joint: size (RMS [N m], nMSE),
spectrum (Welch), where its power sits — and the real trial's link-deflection channels (strain gauges) are set
beside the simulated spring deflection. "Before" is the simulated default without its background terms.
`ident_opt.report.calibration` writes it (`ident-opt calibrate`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import signal

from ident_opt.arm.datasheet import datasheet_pi
from ident_opt.arm.planar import RIGID
from ident_opt.data.dataset import Dataset
from ident_opt.data.loader import load_dataset
from ident_opt.effects import BACKGROUND, parse_effect
from ident_opt.errors import InputError
from ident_opt.fitting.ols import solve_ols
from ident_opt.fitting.stats import Stats
from ident_opt.problem.spec import Problem
from ident_opt.simulator.cache import spec_trial

#: The simulator's spring-deflection columns (one per elastic joint or link it simulates).
DEFLECTION = ("deflection1", "deflection2")
#: The residual's power bands of the report's table [Hz].
BANDS = ((0.0, 0.6), (0.6, 2.0), (2.0, 4.0), (4.0, 10.0), (10.0, 50.0))
#: Calibration targets for the default simulated trial (issue 3): rigid-fit residual RMS per joint within
#: ±25 % of the real trial's, and the share of its power below 0.6 Hz within ±10 percentage points of it.
RMS_TOLERANCE, LOW_SHARE_TOLERANCE, LOW_HZ = 0.25, 0.10, 0.6
#: The real trial's first rest [s]: how much torque a joint holds there, against what gravity needs.
FIRST_REST_S = 15.0


@dataclass
class Summary:
    """The rigid-fit residual of one trial and its spectrum."""

    label: str
    data: Dataset
    residual: np.ndarray  # (N, 2) [N m]
    f: np.ndarray  # Hz
    psd: np.ndarray  # (F, 2) [N² m² / Hz]
    strain_f: np.ndarray | None = None
    strain_psd: np.ndarray | None = None  # (F, k), each column normalised to unit peak


def summarise(label: str, data: Dataset, strain_columns: Sequence[str]) -> Summary:
    """OLS rigid fit on the whole trial, its residual and the residual's (and strain's) Welch spectra."""
    pi = solve_ols(Stats.from_data(RIGID, data.q, data.dq, data.ddq, data.tau))
    residual = data.tau - RIGID.predict(pi, data.q, data.dq, data.ddq)
    fs = data.rate_hz
    f, psd = signal.welch(residual, fs=fs, nperseg=1024, axis=0)
    out = Summary(label, data, residual, f, psd)
    cols = [c for c in strain_columns if c in data.extra]
    if cols:
        x = data.extra[cols].to_numpy(dtype=float)
        sf, sp = signal.welch(x - x.mean(0), fs=fs, nperseg=1024, axis=0)
        keep = sf > 0.5  # above the slow drift of the gauges
        out.strain_f, out.strain_psd = sf, sp / sp[keep].max(0)
    return out


def peak(f: np.ndarray, psd: np.ndarray, lo: float = 1.0, hi: float = 10.0) -> np.ndarray:
    """The frequency of the largest power strictly between `lo` and `hi` [Hz], per column."""
    band = (f > lo) & (f < hi)
    return f[band][np.argmax(psd[band], axis=0)]


def rms(s: Summary) -> np.ndarray:
    """Residual RMS per joint [N m]."""
    return np.sqrt((s.residual**2).mean(0))


def low_share(s: Summary) -> np.ndarray:
    """Share of the residual's (Welch) power below `LOW_HZ`, per joint."""
    return s.psd[s.f < LOW_HZ].sum(0) / s.psd.sum(0)


def band_share(s: Summary, lo: float, hi: float) -> np.ndarray:
    """Share of the residual's (Welch) power in [lo, hi) Hz, per joint."""
    return s.psd[(s.f >= lo) & (s.f < hi)].sum(0) / s.psd.sum(0)


@dataclass
class Calibration:
    """The summaries [real 1, real 2, sim seed s, sim seed s + 1, sim seed s without background terms], the
    simulated problem's effects, and joint 2's mean torque at the real trial's first rest beside what the
    (physical) datasheet's gravity needs there [N m]."""

    summaries: list[Summary]
    effects: tuple[str, ...]
    real_problem: str
    sim_problem: str
    holding: tuple[float, float]

    @property
    def real(self) -> Summary:
        return self.summaries[0]

    @property
    def sim(self) -> Summary:
        return self.summaries[2]

    @property
    def before(self) -> Summary:
        return self.summaries[4]


def calibrate(real: Problem, sim: Problem, channels: Sequence[str] = ()) -> Calibration:
    """`real`'s trials against `sim`'s default simulated trial (seeds s and s + 1 of its [simulate] section,
    and seed s without its background terms); `channels`: the real trials' link-deflection columns."""
    spec = sim.simulate
    trials = [load_dataset(p, real.data, real.robot) for p in real.data.trials]
    for name in channels:
        lacking = [t.source for t in trials if name not in t.extra]
        if lacking:
            known = ", ".join(map(str, trials[0].extra.columns)) or "none"
            raise InputError(
                f"--channel {name!r}: no such column in {lacking[0]} (its columns beyond t, q, dq, ddq, tau: {known})"
            )
    summaries = [summarise(f"exp{i + 1}", d, channels) for i, d in enumerate(trials)]
    catalogue_only = [e for e in spec.effects if parse_effect(e)[0] not in BACKGROUND]
    for label, seed, effects in (
        (f"sim s{spec.seed}", spec.seed, list(spec.effects)),
        (f"sim s{spec.seed + 1}", spec.seed + 1, list(spec.effects)),
        (f"before s{spec.seed}", spec.seed, catalogue_only),
    ):
        trial = spec_trial(sim.robot, spec, seed, effects)
        summaries.append(summarise(label, trial.dataset(), DEFLECTION))
    d = summaries[0].data
    rest = d.t < FIRST_REST_S
    gravity = RIGID.predict(RIGID.vector(datasheet_pi(real.robot, "physical")), d.q, 0 * d.dq, 0 * d.ddq)
    holding = (float(d.tau[rest, 1].mean()), float(gravity[rest, 1].mean()))
    return Calibration(summaries, tuple(spec.effects), str(real.path), str(sim.path), holding)
