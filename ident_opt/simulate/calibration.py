"""How close the simulator's calibrated default (problems/tudor_sim.toml) is to the real MERIt exp1 trial.

Both get the same treatment: the rigid model (`RIGID`, 9 parameters) fitted by OLS on the whole trial, then
its residual τ − Y π̂ per joint: size (RMS [N m], nMSE), spectrum (Welch), and where its power sits. The
strain gauges of the real trial (extra columns col10..col13) are compared with the simulated spring
deflection. Writes results/simulator_calibration.md and results/figures/simulator_calibration.png:

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
    styles = ["-", "--", "-", "--"]
    colours = ["C0", "C0", "C3", "C3"]
    for s, ls, c in zip(summaries, styles, colours):
        for j in range(2):
            ax[0, j].semilogy(s.f, s.psd[:, j], ls, color=c, label=s.label, lw=1)
        if s.strain_psd is not None:
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


def report(summaries: list[Summary], effects: tuple[str, ...], real_robot) -> str:
    """The Markdown report (numbers computed here, so the text always matches the table)."""
    real, sim = summaries[0], summaries[2]
    rms = lambda s: np.sqrt((s.residual**2).mean(0))  # noqa: E731
    ratio = rms(sim) / rms(real)
    low = lambda s: s.psd[s.f < 0.6].sum(0) / s.psd.sum(0)  # noqa: E731
    effect_list = "\n".join(f"- `{e}`" for e in effects)
    nmse2 = [s.residual[:, 1].var() / s.data.tau[:, 1].var() for s in (sim, real)]
    d = real.data
    first_rest = d.t < 15.0
    gravity2 = RIGID.predict(RIGID.vector(datasheet_pi(real_robot, "physical")), d.q, 0 * d.dq, 0 * d.ddq)[
        :, 1
    ]
    moving2 = np.abs(d.dq[:, 1]) > 0.05
    by_sign = [real.residual[moving2 & (np.sign(d.dq[:, 1]) == sg), 1].mean() for sg in (1, -1)]
    line = _peak(real.f, real.psd, 10.0, 20.0)[0]
    return f"""# Simulator calibration: the default simulated trial vs the real exp1

Reproduce: `.venv/bin/python -m ident_opt.simulate.calibration` (writes this file and
`figures/simulator_calibration.png`). Both the real MERIt trials (`problems/tudor_2dof.toml`) and the
simulated ones (`problems/tudor_sim.toml`, seeds 0 and 1) get the same treatment: the rigid model (9
parameters, physical gravity) fitted by OLS on the whole trial, then the residual τ − Y π̂ per joint.

The default effects of `problems/tudor_sim.toml`:

{effect_list}

plus the measurement model: white torque noise with the real trial's σ at rest (0.16 / 0.054 N·m, the
part of its spread that changes from sample to sample), a 4096-count encoder per motor revolution, 100 Hz
logging, dq/ddq estimated from the logged angles (zero-phase Butterworth at 15 Hz, central differences).

{table(summaries)}

![residual and strain spectra, real vs simulated](figures/simulator_calibration.png)

## How close it is

- **Spectrum, the part that matches.** The simulated residual has its 1–10 Hz peak where the real one
  has it on joint 1 ({_peak(sim.f, sim.psd)[0]:.2f} Hz vs {_peak(real.f, real.psd)[0]:.2f} Hz), and the
  simulated spring deflection peaks where the real strain gauges do
  ({_peak(sim.strain_f, sim.strain_psd)[0]:.2f} Hz vs {_peak(real.strain_f, real.strain_psd)[0]:.2f} Hz): the
  links' first mode. The share of time at rest is similar to exp2's (exp1 rests less).
- **Size: not matched.** The simulated rigid-fit residual is {ratio[0]:.0%} (joint 1) and {ratio[1]:.0%}
  (joint 2) of the real one's RMS ({rms(sim)[0]:.2f} / {rms(sim)[1]:.2f} vs {rms(real)[0]:.2f} /
  {rms(real)[1]:.2f} N·m). Joint 2 is far better explained by a rigid model in simulation (nMSE
  {nmse2[0]:.2f} vs {nmse2[1]:.2f}).
- **Where the missing residual is.** Below 0.6 Hz ({low(real)[0]:.0%} / {low(real)[1]:.0%} of the real
  residual's power, {low(sim)[0]:.0%} / {low(sim)[1]:.0%} of the simulated one's) and above 10 Hz while the
  arm moves. The real joint-2 residual is a slowly varying offset (its torque at rest in the first 15 s
  averages {d.tau[first_rest, 1].mean():.2f} N·m where the datasheet's gravity needs
  {gravity2[first_rest].mean():+.2f}) plus ±1 N·m excursions during moves that change little with the
  direction of motion (mean residual {by_sign[0]:.2f} N·m for dq2 > 0, {by_sign[1]:.2f} for dq2 < 0). Those
  look like holding torques left by stiction at rest, a torque/current bias, and friction that depends on
  load or pose. None of these is in the catalogue of `spec/diagnose.md`, and the sign-based friction of the
  truth model (kept so that the clean truth is exactly the identification model) has no stiction; adding
  them would make the default trial look more like exp1 but hide effects the diagnosis cannot name.
  Joint 1 also has a sharp {line:.1f} Hz line in the real residual that the simulator does not produce (a second
  mode or a drive resonance).
- **What to expect downstream.** On the default simulated trial the rigid fit explains joint 2 far better
  than on real data, and the 3 Hz elastic mode dominates what it misses; diagnosis results on simulated
  data are therefore cleaner than on exp1. The unseen-trial protocol (seed 0 vs seed 1) works as on exp1
  vs exp2: the same arm, a different sequence of moves.
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
    for seed in (spec.seed, spec.seed + 1):
        trial = simulate_trial(
            sim.robot,
            trajectory=spec.trajectory,
            duration=spec.duration,
            rate_hz=spec.rate_hz,
            seed=seed,
            effects=list(spec.effects),
            output=spec.output,
        )
        summaries.append(summarise(f"sim s{seed}", trial.dataset(), ["deflection1", "deflection2"]))
    out = Path(args.out)
    figure(summaries, out / "figures" / "simulator_calibration.png")
    text = report(summaries, spec.effects, real.robot)
    (out / "simulator_calibration.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
