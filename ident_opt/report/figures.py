"""Every figure of the reports: each function draws one PNG from a study's data and returns its path.

The identify figures follow the paper, one per figure of it, drawn from a fitted split (`SplitResult`: the
models fitted on one training part and their predictions on its test part; time axes show the test samples
in time order). Colours follow the paper: measured torque black, parametric prediction red, GMR-corrected
green. Then the seed heatmap (identify, compare), the audit's torque figure, the online parameter trajectories
and the simulator calibration.
"""

from __future__ import annotations

from pathlib import Path
from statistics import NormalDist

import matplotlib
import numpy as np

matplotlib.use("Agg")  # files only, never a window

import matplotlib.pyplot as plt
from matplotlib.ticker import MaxNLocator

from ident_opt import outputs
from ident_opt.paper.protocols import SplitResult
from ident_opt.paper.seeds import SplitResults, deviation_from_mean

MEASURED, PARAMETRIC, CORRECTED = "black", "tab:red", "tab:green"
#: The paper's three models, in its order, with its names.
PAPER_MODELS = (
    ("rr", "Model 1: ridge regression (RR)"),
    ("dm", "Model 2: datasheet dynamics (DM)"),
    ("pbr", "Model 3: physics-based regression (PBR)"),
)


def text(value: object) -> str:
    """`value` (a file name) as literal text in a figure: a "$" escaped, so that matplotlib never reads a name such
    as `$x^$.csv` as mathematics (which fails to parse and would stop the report)."""
    return str(value).replace("$", r"\$")


def _save(fig, path: Path, dpi: int = 110, metadata: dict[str, str] | None = None, bbox: str | None = None) -> Path:
    try:
        with outputs.atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, format=path.suffix.lstrip(".") or "png", metadata=metadata, bbox_inches=bbox)
    finally:
        plt.close(fig)
    return path


def torque_figure(split: SplitResult, joint: int, path: Path, models=PAPER_MODELS, title: str = "") -> Path:
    """Measured vs predicted torque of one joint (0-based) over time, one panel per model."""

    def draw(ax, t, tau, parametric, corrected, key):
        ax.plot(t, tau, color=MEASURED, lw=0.8, label="measured")
        ax.plot(t, parametric, color=PARAMETRIC, lw=0.8, label=f"{key} (parametric)")
        ax.plot(t, corrected, color=CORRECTED, lw=0.8, label=f"{key} + GMR")

    title = title or f"Joint {joint + 1} torque predictions (test samples)"
    return _model_panels(split, joint, path, models, draw, (2.6, False), f"τ{joint + 1} [N·m]", title)


def error_figure(split: SplitResult, joint: int, path: Path, models=PAPER_MODELS, title: str = "") -> Path:
    """Torque error (measured − predicted) of one joint over time: parametric red, with GMR green."""

    def draw(ax, t, tau, parametric, corrected, key):
        ax.plot(t, tau - parametric, color=PARAMETRIC, lw=0.7, label=f"{key}")
        ax.plot(t, tau - corrected, color=CORRECTED, lw=0.7, label=f"{key} + GMR")
        ax.axhline(0, color="gray", lw=0.5)

    title = title or f"Joint {joint + 1} torque error, measured − predicted (test samples)"
    return _model_panels(split, joint, path, models, draw, (2.4, True), f"error τ{joint + 1} [N·m]", title)


def _model_panels(split: SplitResult, joint: int, path: Path, models, draw, layout, ylabel: str, title: str) -> Path:
    """One panel per model over the test samples' time: `draw(ax, t, τ, parametric, GMR-corrected, KEY)`
    plots joint `joint`'s curves; `layout` = (panel height [in], shared y axis); a one-row legend."""
    t, tau = split.test.t, split.test.tau[:, joint]
    height, sharey = layout
    fig, axes = plt.subplots(
        len(models), 1, figsize=(11, height * len(models)), sharex=True, sharey=sharey, squeeze=False
    )
    for ax, (key, name) in zip(axes[:, 0], models):
        draw(ax, t, tau, split.predictions[key][:, joint], split.predictions[key + "+gmr"][:, joint], key.upper())
        ax.set_title(name, fontsize=10)
        ax.set_ylabel(ylabel)
        ax.legend(loc="upper right", fontsize=8, ncol=len(ax.get_legend_handles_labels()[1]))
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, path)


def parity_figure(split: SplitResult, path: Path, models=PAPER_MODELS, title: str = "") -> Path:
    """Predicted vs measured torque: joints in rows, models in columns (for two joints, the paper's 2×3 parity
    plots)."""
    n = split.test.tau.shape[1]
    fig, axes = plt.subplots(n, len(models), figsize=(4.2 * len(models), 4 * n), squeeze=False)
    for j in range(n):
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
    z = NormalDist().inv_cdf(0.5 + level / 2)
    t = split.test.t
    sel = np.ones(len(t), bool) if window is None else (t >= window[0]) & (t <= window[1])
    mean, std = split.predictions[key + "+gmr"], split.std[key + "+gmr"]
    cover = split.coverage[key + "+gmr"]
    n = split.test.tau.shape[1]
    fig, axes = plt.subplots(n, 1, figsize=(11, 3.25 * n), sharex=True, squeeze=False)
    axes = axes[:, 0]
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


def seed_heatmap(study: SplitResults, path: str | Path, estimator: str = "ols") -> Path:
    """The paper's "grouped parameters regressed across 10 seeds" figure: deviation from the mean (%)
    per seed and parameter, with each parameter's mean printed under its name. Writes a PNG."""
    dev = deviation_from_mean(study, estimator)
    mean = study.pi[estimator].mean(0)
    lim = max(float(np.abs(dev.to_numpy()).max()), 1e-9)
    fig, ax = plt.subplots(figsize=(1.0 + 0.85 * dev.shape[1], 1.2 + 0.42 * dev.shape[0]))
    im = ax.imshow(dev.to_numpy(), cmap="RdBu_r", vmin=-lim, vmax=lim, aspect="auto")
    ax.set_xticks(range(dev.shape[1]), [f"{n}\n{m:.3g}" for n, m in zip(dev.columns, mean)], fontsize=8)
    ax.set_yticks(range(dev.shape[0]), [str(s) for s in dev.index], fontsize=8)
    ax.set_ylabel("seed")
    for (r, c), v in np.ndenumerate(dev.to_numpy()):
        ax.text(c, r, f"{v:.1f}", ha="center", va="center", fontsize=6)
    fig.colorbar(im, ax=ax, label="deviation from the mean over seeds [%]")
    ax.set_title(
        f"{estimator}: grouped parameters across {dev.shape[0]} shuffled 70/30 splits (column label: mean)", fontsize=9
    )
    fig.tight_layout()
    return _save(fig, Path(path), dpi=130)


def audit_torque_figure(trial, predictions: dict[str, np.ndarray], path: Path) -> Path:
    """Measured vs predicted torque over time, both joints, both datasheet conventions (no fitting)."""
    fig, axes = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    for j, ax in enumerate(axes):
        ax.plot(trial.t, trial.tau[:, j], color="black", lw=1.0, label="measured")
        ax.plot(
            trial.t,
            predictions["dm_paper (printed G)"][:, j],
            color="tab:red",
            lw=1.0,
            label="datasheet, paper convention",
        )
        ax.plot(
            trial.t, predictions["dm_physical"][:, j], color="tab:blue", lw=1.0, label="datasheet, physical convention"
        )
        ax.set_ylabel(f"joint {j + 1} torque [N·m]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle("Datasheet models without fitting vs measured torque")
    fig.tight_layout()
    return _save(fig, path, dpi=120)


def online_trajectories_figure(
    names: tuple[str, ...], theta: dict, theta0: dict, path: Path, title: str | None = None
) -> Path:
    """Parameters over an online replay, one panel per parameter: `theta` model key -> (N, P) trajectory,
    `theta0` model key -> the offline values (P,) drawn dotted; `title` (default: the planar arm's units)."""
    cols = 3
    rows = int(np.ceil(len(names) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(11, 2.4 * rows), sharex=True)
    for p, (ax, name) in enumerate(zip(axes.flat, names)):
        for key, trajectory in theta.items():
            ax.plot(np.arange(1, len(trajectory) + 1), trajectory[:, p], label=key, lw=1.2)
            ax.axhline(theta0[key][p], color="0.6", lw=0.6, ls=":")
        ax.set_title(name, fontsize=9)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(names) :]:
        ax.set_visible(False)
    axes.flat[0].legend(fontsize=7)
    fig.supxlabel("online samples")
    fig.suptitle(title or "Online parameter trajectories (dotted: offline fit); a kg·m², b N·m, fv N·m·s/rad, fc N·m")
    fig.tight_layout()
    return _save(fig, path, dpi=120)


def calibration_figure(summaries: list, path: Path) -> Path:
    """The simulator calibration: residual spectra per joint, strain spectra, and a residual trace, real vs
    simulated (`paper.calibration.Summary` each: [exp1, exp2, sim, sim, before])."""
    fig, ax = plt.subplots(2, 2, figsize=(11, 7.5))
    styles = ["-", "--", "-", "--", ":"]
    colours = ["C0", "C0", "C3", "C3", "0.5"]
    for s, ls, c in zip(summaries, styles, colours):
        for j in range(2):
            ax[0, j].loglog(s.f, s.psd[:, j], ls, color=c, label=s.label, lw=1)
        if s.strain_psd is not None and not s.label.startswith("before"):
            ax[1, 0].loglog(s.strain_f, s.strain_psd.mean(1), ls, color=c, label=s.label, lw=1)
    for j in range(2):
        ax[0, j].set(
            xlim=(0.1, 20),
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
    return _save(fig, path)


def daily_figure(
    days: list[str],
    panels: list[dict],
    shaded_days: int,
    band_label: str,
    title: str,
    path: Path,
    metadata: dict[str, str] | None = None,
) -> Path:
    """Parameters day by day (`ident-opt fleet`, one robot): one panel per dict of `panels` (name, values and se
    (D,), mean (or None), band (D,) half-width, moved: bool, since: the first day of its change or None), each day's
    value ± one standard error, the mean and its band shaded, the first `shaded_days` (the baseline) tinted. The
    x axis counts days from the first (at most 6 dates labelled: date axes cost seconds per figure). `metadata`: PNG
    text kept in the file."""
    cols = 3 if len(panels) > 4 else max(len(panels), 1)
    rows = -(-len(panels) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 2.5 * rows), squeeze=False, sharex=True)
    ordinal = np.array([np.datetime64(d, "D").astype(int) for d in days])
    x = ordinal - ordinal[0]
    ticks = np.unique(np.linspace(0, len(x) - 1, min(len(x), 6)).round().astype(int))
    for ax, p in zip(axes.flat, panels):
        colour = PARAMETRIC if p["moved"] else "tab:blue"
        ax.errorbar(x, p["values"], yerr=p["se"], fmt="o-", ms=3, lw=0.8, color=colour)
        if p["mean"] is not None:
            ax.fill_between(x, p["mean"] - p["band"], p["mean"] + p["band"], color="0.85", zorder=0, label=band_label)
            ax.axhline(p["mean"], color="0.4", lw=0.8)
            ax.axvspan(x[0], x[min(shaded_days, len(x)) - 1], color="tab:green", alpha=0.08, zorder=0)
        if p["since"] is not None:
            ax.axvline(np.datetime64(p["since"], "D").astype(int) - ordinal[0], color=PARAMETRIC, ls="--", lw=0.8)
        # y given: matplotlib then skips placing the title above the ticks' bounding boxes (a third of the draw)
        ax.set_title(p["name"] + (" (moved)" if p["moved"] else ""), fontsize=9, y=1.0, pad=3)
        ax.yaxis.set_major_locator(MaxNLocator(4))  # fewer ticks: each tick is several artists to make and draw
        ax.tick_params(labelsize=7)
        ax.set_xticks(x[ticks], [days[i][5:] for i in ticks])
    for ax in list(axes.flat)[len(panels) :]:
        ax.set_visible(False)
    if len(x) == 1:  # one day: a span of zero width would leave matplotlib to guess the axis
        axes.flat[0].set_xlim(-1, 1)
    if axes.flat[0].get_legend_handles_labels()[0]:  # no band (a robot not tested): no legend, and no warning
        axes.flat[0].legend(fontsize=7)
    height = 2.5 * rows  # inches
    fig.suptitle(title, fontsize=11, y=1 - 0.1 / height, va="top")
    # fixed margins: tight_layout would cost a third of the figure's time, once per robot of a fleet
    fig.subplots_adjust(left=0.06, right=0.99, bottom=0.25 / height, top=1 - 0.65 / height, wspace=0.28, hspace=0.5)
    return _save(fig, path, dpi=90, metadata=metadata)


#: Up to this many changes are written beside their rows in the fleet overview; more are marked only.
MAX_MARK_TEXTS = 40


def z_overview_figure(
    rows: list[str], columns: list[str], z: np.ndarray, marks: dict[int, str], clip: float, title: str, path: Path
) -> Path:
    """A fleet at a glance: z (R, C) of each row's (a robot's) columns (its tested parameters) as colours clipped to
    ±`clip`, NaN grey; `marks` {row: text} written at the right of the marked rows (their change; only a mark
    beyond `MAX_MARK_TEXTS`). One image, so its cost does not grow with the fleet as one figure per robot does."""
    height = min(max(1.6 + 0.16 * len(rows), 2.6), 40.0)  # inches: 0.16 per robot, capped for huge fleets
    texts = len(marks) <= MAX_MARK_TEXTS
    room = 2.9 if texts else 1.1  # inches right of the matrix: the changes written (2 in), the colour bar
    width = 0.45 * len(columns) + 2.1 + room
    fig = plt.figure(figsize=(width, height))
    # fixed margins (inches): names left, rotated parameter names below, the marks and the colour bar right
    left, right, bottom, top = 0.7 / width, 1 - room / width, 0.9 / height, 1 - 0.45 / height
    ax = fig.add_axes((left, bottom, right - left, top - bottom))
    bar = fig.add_axes((1 - 0.75 / width, bottom, 0.15 / width, top - bottom))
    cmap = plt.get_cmap("RdBu_r").with_extremes(bad="0.85")
    image = ax.imshow(np.ma.masked_invalid(z), cmap=cmap, vmin=-clip, vmax=clip, aspect="auto", interpolation="none")
    ax.set_xticks(range(len(columns)), columns, rotation=60, ha="right", fontsize=7)
    step = max(1, len(rows) // 60)  # at most ~60 robot names on the axis; the marked ones always
    shown_rows = sorted(set(range(0, len(rows), step)) | set(marks))
    ax.set_yticks(shown_rows, [rows[i] for i in shown_rows], fontsize=6)
    if texts:
        for i, text in marks.items():
            ax.annotate(text, (1.0, i), xycoords=("axes fraction", "data"), xytext=(4, 0), textcoords="offset points",
                        va="center", fontsize=6, color=PARAMETRIC)  # fmt: skip
    else:  # text is what costs (a second per hundred labels): a mark, the changes being in the report's table
        ax.plot(np.full(len(marks), len(columns) - 0.3), list(marks), ">", color=PARAMETRIC, ms=3, clip_on=False)
    fig.colorbar(image, cax=bar, label=f"z on the latest day (clipped to ±{clip:g})")
    ax.set_title(title, fontsize=9)
    return _save(fig, path, dpi=90)


def parameters_figure(
    names: list[str],
    fits: dict[str, tuple[np.ndarray, np.ndarray]],
    nominal: np.ndarray | None,
    title: str,
    path: Path,
    max_rows: int = 40,
) -> Path:
    """Each parameter under each fit with ±2 standard errors, one row per parameter (the first `max_rows`), one
    axes: `fits` {label: (values (P,), se (P,), NaN where none)}, `nominal` (P,) the nominal values (a black bar).
    Parameters differ in unit and size, so each row is scaled by its own largest |value| + 2 SE over the fits: the
    figure shows where the fits agree within their errors and where one (a constraint, the noise) moved."""
    rows = min(len(names), max_rows)
    values = np.array([f[0][:rows] for f in fits.values()])
    se = np.nan_to_num(np.array([f[1][:rows] for f in fits.values()]))
    scale = np.nanmax(np.abs(values) + 2 * se, axis=0)
    scale = np.where(np.isfinite(scale) & (scale > 0), scale, 1.0)
    fig, ax = plt.subplots(figsize=(8.0, 1.2 + 0.28 * rows))
    offsets = np.linspace(-0.3, 0.3, len(fits)) if len(fits) > 1 else np.zeros(1)
    y = np.arange(rows)
    for k, label in enumerate(fits):
        ax.errorbar(values[k] / scale, y + offsets[k], xerr=2 * se[k] / scale, fmt="o", ms=3, lw=0.9, label=label)
    if nominal is not None:
        ax.plot(nominal[:rows] / scale, y, "|", color="black", ms=12, mew=1.5, label="nominal")
    ax.axvline(0.0, color="0.6", lw=0.6)
    ax.set_yticks(y, names[:rows], fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel("value / (largest |value| + 2 SE of the row)", fontsize=8)
    shown_rows = f" (the first {rows} of {len(names)}; all in the CSV)" if rows < len(names) else ""
    ax.set_title(title + shown_rows, fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # beside the rows, never over them
    fig.tight_layout()
    return _save(fig, path, dpi=90)
