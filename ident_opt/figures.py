"""The figures of `ident-opt identify`: one per figure of the paper, drawn from a fitted split.

Colours follow the paper: measured torque black, parametric prediction red, GMR-corrected green. Every
function takes a `SplitResult` (the models fitted on one training part and their predictions on its test
part), writes one PNG and returns its path. Time axes show the test samples in time order.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ident_opt.protocols import SplitResult

MEASURED, PARAMETRIC, CORRECTED = "black", "tab:red", "tab:green"
#: The paper's three models, in its order, with its names.
PAPER_MODELS = (
    ("rr", "Model 1: ridge regression (RR)"),
    ("dm", "Model 2: datasheet dynamics (DM)"),
    ("pbr", "Model 3: physics-based regression (PBR)"),
)


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    _plt().close(fig)
    return path


def torque_figure(split: SplitResult, joint: int, path: Path, models=PAPER_MODELS, title: str = "") -> Path:
    """Measured vs predicted torque of one joint (0 or 1) over time, one panel per model."""
    plt = _plt()
    t, tau = split.test.t, split.test.tau[:, joint]
    fig, axes = plt.subplots(len(models), 1, figsize=(11, 2.6 * len(models)), sharex=True, squeeze=False)
    for ax, (key, name) in zip(axes[:, 0], models):
        ax.plot(t, tau, color=MEASURED, lw=0.8, label="measured")
        ax.plot(t, split.predictions[key][:, joint], color=PARAMETRIC, lw=0.8, label=f"{key.upper()} (parametric)")
        ax.plot(t, split.predictions[key + "+gmr"][:, joint], color=CORRECTED, lw=0.8, label=f"{key.upper()} + GMR")
        ax.set_title(name, fontsize=10)
        ax.set_ylabel(f"τ{joint + 1} [N·m]")
        ax.legend(loc="upper right", fontsize=8, ncol=3)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(title or f"Joint {joint + 1} torque predictions (test samples)")
    fig.tight_layout()
    return _save(fig, path)


def error_figure(split: SplitResult, joint: int, path: Path, models=PAPER_MODELS, title: str = "") -> Path:
    """Torque error (measured − predicted) of one joint over time: parametric red, with GMR green."""
    plt = _plt()
    t, tau = split.test.t, split.test.tau[:, joint]
    fig, axes = plt.subplots(len(models), 1, figsize=(11, 2.4 * len(models)), sharex=True, sharey=True, squeeze=False)
    for ax, (key, name) in zip(axes[:, 0], models):
        ax.plot(t, tau - split.predictions[key][:, joint], color=PARAMETRIC, lw=0.7, label=f"{key.upper()}")
        ax.plot(
            t, tau - split.predictions[key + "+gmr"][:, joint], color=CORRECTED, lw=0.7, label=f"{key.upper()} + GMR"
        )
        ax.axhline(0, color="gray", lw=0.5)
        ax.set_title(name, fontsize=10)
        ax.set_ylabel(f"error τ{joint + 1} [N·m]")
        ax.legend(loc="upper right", fontsize=8, ncol=2)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(title or f"Joint {joint + 1} torque error, measured − predicted (test samples)")
    fig.tight_layout()
    return _save(fig, path)


def parity_figure(split: SplitResult, path: Path, models=PAPER_MODELS, title: str = "") -> Path:
    """Predicted vs measured torque: joints in rows, models in columns (the paper's 2×3 parity plots)."""
    plt = _plt()
    fig, axes = plt.subplots(2, len(models), figsize=(4.2 * len(models), 8), squeeze=False)
    for j in range(2):
        tau = split.test.tau[:, j]
        lo, hi = float(tau.min()), float(tau.max())
        pad = 0.1 * (hi - lo)
        for c, (key, name) in enumerate(models):
            ax = axes[j, c]
            ax.scatter(tau, split.predictions[key][:, j], s=3, color=PARAMETRIC, alpha=0.35, label=key.upper())
            ax.scatter(
                tau,
                split.predictions[key + "+gmr"][:, j],
                s=3,
                color=CORRECTED,
                alpha=0.35,
                label=f"{key.upper()} + GMR",
            )
            ax.plot([lo - pad, hi + pad], [lo - pad, hi + pad], color=MEASURED, lw=0.8, label="ideal")
            ax.set_xlim(lo - pad, hi + pad)
            ax.set_xlabel(f"measured τ{j + 1} [N·m]")
            ax.set_ylabel(f"predicted τ{j + 1} [N·m]")
            ax.set_title(f"{name.split(': ')[0]}, joint {j + 1}", fontsize=10)
            ax.legend(loc="upper left", fontsize=8, markerscale=3)
    fig.suptitle(title or "Parity plots (test samples)")
    fig.tight_layout()
    return _save(fig, path)


def interval_figure(
    split: SplitResult,
    path: Path,
    key: str = "pbr",
    level: float = 0.95,
    window: tuple[float, float] | None = None,
    title: str = "",
) -> Path:
    """The hybrid's prediction with its `level` predictive interval (GMR mixture variance) per joint."""
    from scipy.stats import norm

    plt = _plt()
    z = float(norm.ppf(0.5 + level / 2))
    t = split.test.t
    sel = np.ones(len(t), bool) if window is None else (t >= window[0]) & (t <= window[1])
    mean, std = split.predictions[key + "+gmr"], split.std[key + "+gmr"]
    cover = split.coverage[key + "+gmr"]
    fig, axes = plt.subplots(2, 1, figsize=(11, 6.5), sharex=True)
    for j, ax in enumerate(axes):
        ax.fill_between(
            t[sel],
            (mean - z * std)[sel, j],
            (mean + z * std)[sel, j],
            color=CORRECTED,
            alpha=0.25,
            lw=0,
            label=f"{level:.0%} interval (covers {cover[j]:.1%} of test samples)",
        )
        ax.plot(t[sel], split.test.tau[sel, j], color=MEASURED, lw=0.8, label="measured")
        ax.plot(t[sel], mean[sel, j], color=CORRECTED, lw=0.8, label=f"{key.upper()} + GMR")
        ax.set_ylabel(f"τ{j + 1} [N·m]")
        ax.set_title(f"Joint {j + 1}", fontsize=10)
        ax.legend(loc="upper right", fontsize=8, ncol=3)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title or f"{key.upper()} + GMR with {level:.0%} predictive intervals (test samples)")
    fig.tight_layout()
    return _save(fig, path)


def seed_figure(trial, problem, path: Path) -> Path:
    """The paper's seed heatmap (grouped parameters over its 10 shuffles), via the identification code."""
    from ident_opt.identify.seeds import seed_heatmap, seed_study
    from ident_opt.robot import RIGID

    return Path(seed_heatmap(seed_study(trial, RIGID, problem.split), path))
