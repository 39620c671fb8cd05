"""How close the simulator's calibrated default (problems/tudor_sim.toml) is to the real MERIt exp1 trial.

Both get the same treatment: the rigid model (`RIGID`, 9 parameters) fitted by OLS on the whole trial, then
its residual τ − Y π̂ per joint: size (RMS [N m], nMSE), spectrum (Welch), and where its power sits. The
strain gauges of the real trial (extra columns col10..col13) are compared with the simulated spring
deflection; "before" is the default without its background terms. Writes results/simulator_calibration.md
and results/figures/simulator_calibration.png:

    .venv/bin/python -m ident_opt.simulate.calibration
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import signal

from ident_opt.data import Dataset, load_dataset
from ident_opt.datasheet import datasheet_pi
from ident_opt.effects import BACKGROUND, parse_effect
from ident_opt.identify.ols import solve_ols
from ident_opt.identify.stats import Stats
from ident_opt.problem import load_problem
from ident_opt.robot import RIGID
from ident_opt.simulate.trial import simulate_trial

ROOT = Path(__file__).resolve().parents[2]
BANDS = ((0.0, 0.6), (0.6, 2.0), (2.0, 4.0), (4.0, 10.0), (10.0, 50.0))  # Hz


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


def summarise(label: str, data: Dataset, strain_columns: list[str]) -> Summary:
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


def _peak(f: np.ndarray, psd: np.ndarray, lo: float = 1.0, hi: float = 10.0) -> np.ndarray:
    band = (f > lo) & (f < hi)
    return f[band][np.argmax(psd[band], axis=0)]


def rows(s: Summary) -> dict[str, list[str]]:
    """The table rows of one trial: per-joint numbers as text."""
    d, r = s.data, s.residual
    total = s.psd.sum(0)
    out = {
        "residual RMS [N m]": [f"{v:.3f}" for v in np.sqrt((r**2).mean(0))],
        "nMSE (÷ variance)": [f"{v:.3f}" for v in r.var(0) / d.tau.var(0)],
        "torque std [N m]": [f"{v:.2f}" for v in d.tau.std(0)],
    }
    for lo, hi in BANDS:
        m = (s.f >= lo) & (s.f < hi)
        out[f"residual power in {lo:g}–{hi:g} Hz"] = [f"{v:.0%}" for v in s.psd[m].sum(0) / total]
    out["residual peak in 1–10 Hz [Hz]"] = [f"{v:.2f}" for v in _peak(s.f, s.psd)]
    rest = (np.abs(d.dq) < 0.02).all(1).mean()
    out["at rest (both |dq| < 0.02 rad/s)"] = [f"{rest:.0%}", ""]
    if s.strain_psd is not None:
        peaks = _peak(s.strain_f, s.strain_psd)
        out["strain / deflection peak [Hz]"] = [", ".join(f"{p:.2f}" for p in peaks), ""]
    return out


def figure(summaries: list[Summary], path: Path) -> None:
    """Residual spectra per joint, strain spectra, and a residual trace: real vs simulated."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 2, figsize=(11, 7.5))
    styles = ["-", "--", "-", "--", ":"]
    colours = ["C0", "C0", "C3", "C3", "0.5"]
    for s, ls, c in zip(summaries, styles, colours):
        for j in range(2):
            ax[0, j].semilogy(s.f, s.psd[:, j], ls, color=c, label=s.label, lw=1)
        if s.strain_psd is not None and not s.label.startswith("before"):
            ax[1, 0].semilogy(s.strain_f, s.strain_psd.mean(1), ls, color=c, label=s.label, lw=1)
    for j in range(2):
        ax[0, j].set(
            xlim=(0, 20),
            xlabel="frequency [Hz]",
            ylabel="PSD [N² m² / Hz]",
            title=f"joint {j + 1}: rigid-fit residual spectrum",
        )
        ax[0, j].legend(fontsize=8)
    ax[1, 0].set(
        xlim=(0.5, 20),
        ylim=(1e-5, 2),
        xlabel="frequency [Hz]",
        ylabel="PSD (unit peak above 0.5 Hz)",
        title="strain gauges (real, mean of 4) vs spring deflection (sim)",
    )
    ax[1, 0].legend(fontsize=8)
    for s, c in ((summaries[0], "C0"), (summaries[2], "C3")):
        t = s.data.t
        window = (t >= 15) & (t < 45)
        ax[1, 1].plot(t[window], s.residual[window, 1], color=c, lw=0.8, label=s.label)
    ax[1, 1].set(xlabel="t [s]", ylabel="residual τ2 − Y π̂ [N m]", title="joint 2 residual, 15–45 s")
    ax[1, 1].legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def table(summaries: list[Summary]) -> str:
    """One Markdown table: real and simulated trials side by side, per joint."""
    tables = [rows(s) for s in summaries]
    head = "| | " + " | ".join(f"{s.label} j1 | {s.label} j2" for s in summaries) + " |"
    lines = [head, "|" + "---|" * (1 + 2 * len(summaries))]
    for key in tables[0]:
        cells = [v for t in tables for v in t.get(key, ["", ""])]
        lines.append(f"| {key} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


#: Calibration targets for the default simulated trial (issue 3): rigid-fit residual RMS per joint within
#: ±25 % of exp1's, and the share of its power below 0.6 Hz within ±10 percentage points of exp1's.
RMS_TOLERANCE, LOW_SHARE_TOLERANCE, LOW_HZ = 0.25, 0.10, 0.6


def rms(s: Summary) -> np.ndarray:
    """Residual RMS per joint [N m]."""
    return np.sqrt((s.residual**2).mean(0))


def low_share(s: Summary) -> np.ndarray:
    """Share of the residual's (Welch) power below `LOW_HZ`, per joint."""
    return s.psd[s.f < LOW_HZ].sum(0) / s.psd.sum(0)


def targets(real: Summary, sims: list[Summary]) -> str:
    """A Markdown table: each simulated trial's RMS and low-frequency share against exp1's, and the verdict."""
    lines = [
        "| trial | RMS j1 [N m] | RMS j2 [N m] | below 0.6 Hz j1 | below 0.6 Hz j2 | within targets |",
        "|---|---|---|---|---|---|",
    ]
    lo, hi = rms(real) * (1 - RMS_TOLERANCE), rms(real) * (1 + RMS_TOLERANCE)
    share = low_share(real)
    lines.append(
        f"| {real.label} (target) | {lo[0]:.2f}–{hi[0]:.2f} | {lo[1]:.2f}–{hi[1]:.2f} | "
        f"{share[0] - LOW_SHARE_TOLERANCE:.0%}–{share[0] + LOW_SHARE_TOLERANCE:.0%} | "
        f"{share[1] - LOW_SHARE_TOLERANCE:.0%}–{share[1] + LOW_SHARE_TOLERANCE:.0%} | |"
    )
    for s in sims:
        r, sh = rms(s), low_share(s)
        ratio = r / rms(real) - 1
        ok = np.all(np.abs(ratio) <= RMS_TOLERANCE) and np.all(np.abs(sh - share) <= LOW_SHARE_TOLERANCE)
        lines.append(
            f"| {s.label} | {r[0]:.3f} ({ratio[0]:+.0%}) | {r[1]:.3f} ({ratio[1]:+.0%}) | "
            f"{sh[0]:.0%} ({100 * (sh[0] - share[0]):+.0f} pt) | {sh[1]:.0%} ({100 * (sh[1] - share[1]):+.0f} pt) | "
            f"{'yes' if ok else 'no'} |"
        )
    return "\n".join(lines)


def report(summaries: list[Summary], effects: tuple[str, ...], real_robot) -> str:
    """The Markdown report (numbers computed here, so the text always matches the table).

    `summaries` = [exp1, exp2, sim seed s, sim seed s + 1, sim seed s without the background terms]."""
    real, sim, before = summaries[0], summaries[2], summaries[4]
    catalogue = "\n".join(f"- `{e}`" for e in effects if parse_effect(e)[0] not in BACKGROUND)
    background = "\n".join(f"- `{e}`" for e in effects if parse_effect(e)[0] in BACKGROUND)
    d = real.data
    first_rest = d.t < 15.0
    gravity = RIGID.predict(RIGID.vector(datasheet_pi(real_robot, "physical")), d.q, 0 * d.dq, 0 * d.ddq)
    band = lambda s, lo, hi: s.psd[(s.f >= lo) & (s.f < hi)].sum(0) / s.psd.sum(0)  # noqa: E731
    mid_real, mid_sim = band(real, 0.6, 2.0), band(sim, 0.6, 2.0)
    hf_real, hf_sim = band(real, 10.0, 50.0), band(sim, 10.0, 50.0)
    line_real, line_sim = _peak(real.f, real.psd, 35.0, 50.0), _peak(sim.f, sim.psd, 35.0, 50.0)
    nmse = lambda s: s.residual.var(0) / s.data.tau.var(0)  # noqa: E731
    std = lambda s: s.data.tau.std(0)  # noqa: E731
    return f"""# Simulator calibration: the default simulated trial vs the real exp1

Reproduce: `.venv/bin/python -m ident_opt.simulate.calibration` (writes this file and
`figures/simulator_calibration.png`). Both the real MERIt trials (`problems/tudor_2dof.toml`) and the
simulated ones (`problems/tudor_sim.toml`, seeds 0 and 1) get the same treatment: the rigid model (9
parameters, physical gravity) fitted by OLS on the whole trial, then the residual τ − Y π̂ per joint.
"before" is seed 0 with the catalogue effects only (the default until the background terms were added).

The default effects of `problems/tudor_sim.toml`, from the diagnosis catalogue (`spec/diagnose.md`):

{catalogue}

and background realism terms that no diagnosis is asked to name (`ident_opt/simulate/background.py`; their
values go to the truth's `background`, not its `effects`):

{background}

plus the measurement model: white torque noise with the real trial's σ at rest (0.16 / 0.054 N·m, the
part of its spread that changes from sample to sample), a 4096-count encoder per motor revolution, 100 Hz
logging, dq/ddq estimated from the logged angles (zero-phase Butterworth at 15 Hz, central differences).

## Targets (issue 3)

Rigid-fit residual RMS per joint within ±{RMS_TOLERANCE:.0%} of exp1's; share of its power below {LOW_HZ:g} Hz
within ±{100 * LOW_SHARE_TOLERANCE:.0f} percentage points of exp1's.

{targets(real, summaries[4:5] + summaries[2:4])}

## Everything, side by side

{table(summaries)}

![residual and strain spectra, real vs simulated](figures/simulator_calibration.png)

## How close it is

- **Size and slow content: matched.** The rigid-fit residual went from {rms(before)[0]:.2f} / {rms(before)[1]:.2f}
  to {rms(sim)[0]:.2f} / {rms(sim)[1]:.2f} N·m (exp1: {rms(real)[0]:.2f} / {rms(real)[1]:.2f}), and its share
  of power below {LOW_HZ:g} Hz from {low_share(before)[0]:.0%} / {low_share(before)[1]:.0%} to
  {low_share(sim)[0]:.0%} / {low_share(sim)[1]:.0%} (exp1: {low_share(real)[0]:.0%} / {low_share(real)[1]:.0%}).
  The slow part comes from stiction (at rest a joint holds the torque its last motion left, about ±Fb; exp1's
  joint 2 holds {d.tau[first_rest, 1].mean():.2f} N·m in the first 15 s where gravity needs
  {gravity[first_rest, 1].mean():+.2f}) and from the drift (an Ornstein-Uhlenbeck torque, 4 s correlation time).
- **Content during moves.** The current ripple (once per motor revolution, ∝ speed) puts a line where exp1 has
  one (strongest peak in 35–50 Hz): {line_sim[0]:.1f} Hz on joint 1 (exp1 {line_real[0]:.1f} Hz) and, aliased at
  100 Hz logging,
  {line_sim[1]:.1f} Hz on joint 2 (exp1 {line_real[1]:.1f} Hz). Power above 10 Hz: {hf_sim[0]:.0%} / {hf_sim[1]:.0%}
  of the residual (exp1 {hf_real[0]:.0%} / {hf_real[1]:.0%}).
- **Spectrum, the link mode.** The 1–10 Hz residual peak of joint 1 stays at the links' first mode
  ({_peak(sim.f, sim.psd)[0]:.2f} Hz vs exp1's {_peak(real.f, real.psd)[0]:.2f} Hz), and the simulated spring
  deflection peaks where the real strain gauges do ({_peak(sim.strain_f, sim.strain_psd)[0]:.2f} Hz vs
  {_peak(real.strain_f, real.strain_psd)[0]:.2f} Hz).
- **Not matched.** The 0.6–2 Hz band holds {mid_sim[0]:.0%} / {mid_sim[1]:.0%} of the simulated residual's
  power against exp1's {mid_real[0]:.0%} / {mid_real[1]:.0%}; joint 2's torque varies more than the real one's
  (std {std(sim)[1]:.2f} vs {std(real)[1]:.2f} N·m), so its nMSE stays lower ({nmse(sim)[1]:.2f} vs
  {nmse(real)[1]:.2f}); the sharp {_peak(real.f, real.psd, 10.0, 20.0)[0]:.1f} Hz line of exp1's joint 1 (strongest
  during moves, and in the strain gauges too: likely the links' second mode) is not produced; exp1's 31 Hz
  electrical line is not modelled; and exp1 rests less than the simulated trial.
- **What to expect downstream.** The diagnosis sees, besides the effect it is asked about, residual content
  that no catalogue cause explains (holding torques, drift, ripple), as on real data; the clean trial and the
  catalogue effects are unchanged (a trial without background terms is bit-for-bit the old one).
"""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "results"), help="results folder")
    args = parser.parse_args(argv)
    real = load_problem(ROOT / "problems" / "tudor_2dof.toml")
    sim = load_problem(ROOT / "problems" / "tudor_sim.toml")
    spec = sim.simulate
    strain_real = ["col10", "col11", "col12", "col13"]
    summaries = [
        summarise(f"exp{i + 1}", load_dataset(p, real.data, real.robot), strain_real)
        for i, p in enumerate(real.data.trials)
    ]
    catalogue_only = [e for e in spec.effects if parse_effect(e)[0] not in BACKGROUND]
    for label, seed, effects in (
        (f"sim s{spec.seed}", spec.seed, list(spec.effects)),
        (f"sim s{spec.seed + 1}", spec.seed + 1, list(spec.effects)),
        (f"before s{spec.seed}", spec.seed, catalogue_only),
    ):
        trial = simulate_trial(
            sim.robot,
            trajectory=spec.trajectory,
            duration=spec.duration,
            rate_hz=spec.rate_hz,
            seed=seed,
            effects=effects,
            output=spec.output,
        )
        summaries.append(summarise(label, trial.dataset(), ["deflection1", "deflection2"]))
    out = Path(args.out)
    figure(summaries, out / "figures" / "simulator_calibration.png")
    text = report(summaries, spec.effects, real.robot)
    (out / "simulator_calibration.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
