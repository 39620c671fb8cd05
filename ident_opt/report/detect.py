"""What `ident-opt detect` writes (`docs/contacts.md`): per data trial `<stem>.csv` (t, alarm, tau_ext1 … tau_extn)
and `<stem>.png` (τ_ext per joint with its thresholds and the alarm spans), and the terminal's summary."""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")  # files only, never a window

import matplotlib.pyplot as plt

from ident_opt import outputs
from ident_opt.contact.detect import Detection, TrialDetection
from ident_opt.report import record, verdicts
from ident_opt.report.figures import _save, text

#: Compression suffixes left out of a trial's stem (measurements_1.csv.gz → measurements_1).
COMPRESSED = (".gz", ".bz2", ".xz", ".zst", ".zip")


def stems(detection: Detection) -> list[str]:
    """Each data trial's file stem, made unique (a second trial of the same stem gets `_2`, …)."""
    out: list[str] = []
    for trial in detection.trials:
        path = Path(trial.source)
        path = path.with_suffix("") if path.suffix in COMPRESSED else path
        stem = path.stem or "trial"
        candidate, k = stem, 2
        while candidate in out:
            candidate, k = f"{stem}_{k}", k + 1
        out.append(candidate)
    return out


def csv_text(trial: TrialDetection) -> str:
    """The trial's CSV: t [s], alarm (0/1), tau_ext1 … tau_extn [N m]; full precision."""
    n = trial.tau_ext.shape[1]
    header = ",".join(["t", "alarm", *(f"tau_ext{j + 1}" for j in range(n))])
    table = np.column_stack([trial.t, trial.alarm.astype(float), trial.tau_ext])
    buffer = io.StringIO()
    np.savetxt(buffer, table, delimiter=",", fmt=["%.17g", "%d", *(["%.17g"] * n)], header=header, comments="")
    return buffer.getvalue()


def figure(trial: TrialDetection, detection: Detection, path: Path) -> Path:
    """τ_ext per joint [N m] against time, ± its threshold at each sample (moving or resting), alarms shaded."""
    n = trial.tau_ext.shape[1]
    fig, axes = plt.subplots(n, 1, figsize=(10, 1.6 * n + 1), sharex=True, squeeze=False)
    limits = detection.thresholds.limits(trial.dq)
    for j, ax in enumerate(axes[:, 0]):
        ax.plot(trial.t, trial.tau_ext[:, j], color="black", lw=0.7, label="τ_ext")
        ax.plot(trial.t, limits[:, j], color="tab:red", lw=0.6, label="threshold")
        ax.plot(trial.t, -limits[:, j], color="tab:red", lw=0.6)
        for a in trial.alarms:
            ax.axvspan(a.start, a.end, color="tab:orange", alpha=0.3, lw=0)
        ax.set_ylabel(f"joint {j + 1} [N m]")
    axes[0, 0].legend(loc="upper right", fontsize=7)
    axes[0, 0].set_title(f"{text(Path(trial.source).name)}: {len(trial.alarms)} alarm(s) (shaded)")
    axes[-1, 0].set_xlabel("t [s]")
    fig.tight_layout()
    return _save(fig, path)


def write(detection: Detection, out: Path, joint_names: tuple[str, ...] = ()) -> list[str]:
    """The CSV and the figure of every data trial in `out` (atomically), and the folder's index (its page says the
    alarms first, `joint_names` naming the joints); the names of the trials' files written."""
    written = []
    for trial, stem in zip(detection.trials, stems(detection)):
        outputs.write_text(out / f"{stem}.csv", csv_text(trial))
        figure(trial, detection, out / f"{stem}.png")
        written += [f"{stem}.csv", f"{stem}.png"]
    figures_first = [f for f in written if f.endswith(".png")] + [f for f in written if f.endswith(".csv")]
    verdict = verdicts.detect_verdict(detection, joint_names)
    record(
        out,
        "detect",
        "contact detection: τ_ext per joint, its thresholds and the alarms",
        figures_first,
        verdict=verdict,
    )
    return written


def summary(detection: Detection) -> str:
    """Lines for the terminal: the fit, the thresholds, the held-out false alarms, each trial's alarms."""
    lines = [f"fit: {detection.estimator} ({detection.why})"]
    th = detection.thresholds
    for j in range(th.n):
        lines.append(
            f"  joint {j + 1}: threshold {th.moving[j]:.3g} N m moving, {th.resting[j]:.3g} N m at rest "
            f"(|dq| < {th.rest_speed[j]:.3g} rad/s)"
        )
    lines.append(f"  persistence {th.persistence} samples, settling {th.settling:g} s after a release")
    for c in detection.calibration:
        lines.append(f"calibration {c['source']}: {c['false_alarms_per_minute']:.2f} false alarms/min held out")
    for trial in detection.trials:
        lines.append(f"{trial.source}: {len(trial.alarms)} alarm(s)")
        lines += [f"  {a.start:.3f}–{a.end:.3f} s, joint {a.joint}, peak {a.peak:.3g} N m" for a in trial.alarms]
    return "\n".join(lines)
