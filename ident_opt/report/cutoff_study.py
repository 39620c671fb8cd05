"""The cut-off study's report (`evaluation.cutoff_study`): a table per condition with the recommended fit's error
against the best cut-off in hindsight (per trial and per condition), the rows as CSV and JSON, and a figure of
the ratios."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd

from ident_opt import outputs
from ident_opt.evaluation.cutoff_study import Row, summary
from ident_opt.report import write_json
from ident_opt.report.figures import plt
from ident_opt.report.tables import markdown_table

#: The study's target: the recommended fit's median error at most this factor of the hindsight best, per condition.
TARGET = 1.3


def write(rows: list[Row], out: Path, label: str, seeds: tuple[int, ...], seconds: float) -> list[Path]:
    """`out`/cutoff_study_<label>.md, .csv (one row per trial), .json, and .png; returns the paths."""
    out.mkdir(parents=True, exist_ok=True)
    stem = out / f"cutoff_study_{label}"
    table = pd.DataFrame(summary(rows))
    per_trial = pd.DataFrame([dataclasses.asdict(r) | {"best_hz": r.best_hz, "error_best": r.error_best} for r in rows])
    with outputs.atomic_path(stem.with_suffix(".csv")) as tmp:
        per_trial.drop(columns=["grid_hz", "error_grid"]).to_csv(tmp, index=False)
    write_json(stem.with_suffix(".json"), {"seeds": list(seeds), "conditions": table.to_dict("records")})
    _figure(table, stem.with_suffix(".png"))
    outputs.write_text(stem.with_suffix(".md"), _markdown(table, label, seeds, seconds, stem.name))
    return [stem.with_suffix(s) for s in (".md", ".csv", ".json", ".png")]


def _shown(table: pd.DataFrame) -> pd.DataFrame:
    """The table's columns as the report shows them: in order, with their headings."""
    return table[
        [
            "kind",
            "rate_hz",
            "noise",
            "cutoff_hz",
            "best_hz",
            "recommended",
            "error_recommended",
            "error_best_per_condition",
            "ratio_per_condition",
            "error_best_per_trial",
            "ratio_per_trial",
            "error_cross_validated",
            "ratio_cross_validated_to_best",
            "ratio_to_cross_validated",
            "covered",
        ]
    ].rename(
        columns={
            "rate_hz": "rate [Hz]",
            "cutoff_hz": "auto cut-off [Hz]",
            "best_hz": "best cut-off [Hz]",
            "error_recommended": "recommended",
            "error_best_per_condition": "best (condition)",
            "ratio_per_condition": "ratio (condition)",
            "error_best_per_trial": "best (trial)",
            "ratio_per_trial": "ratio (trial)",
            "error_cross_validated": "cross-validated",
            "ratio_cross_validated_to_best": "cross-validated ÷ best (condition)",
            "ratio_to_cross_validated": "recommended ÷ cross-validated",
            "covered": "within 2 SE",
        }
    )


def _method_lines(label: str, seeds: tuple[int, ...], seconds: float) -> list[str]:
    """The title, how the study was made and what each column of the table means."""
    return [
        f"# Where the derivative cut-off rule stands ({label} seeds)",
        "",
        "Made by `make cutoff-study` (`benchmarks/cutoff_study.py`, `ident_opt/evaluation/cutoff_study.py`) in "
        f"{seconds:.0f} s; seeds {', '.join(map(str, seeds))}. Each row: 20 s trials of the DFKI C.0 arm's "
        "nominal model (friction made larger) in the study's own plant (`evaluate/cutoff_plant.py`: RK4 on the "
        "arm's M, C, G, F, a PD with feed-forward, encoder quantisation, white angle and torque noise), read "
        "back from CSV by the loader with the default settings. Errors are the median over the inertial, "
        "coupling and gravity parameters of |π̂ − π| / |π| (friction depends on how a plant models stiction, "
        "which no cut-off decides), medians over seeds.",
        "",
        '- **recommended**: the default pipeline (`derivative_cutoff_hz = "auto"`, the recommended fit).',
        "- **best (condition)**: the consistent fit at the one cut-off of a 12-point grid (0.5 Hz to a quarter of "
        "the rate) that is best across the condition's seeds, knowing the truth.",
        "- **best (trial)**: the same, the luckiest grid cut-off for each trial's noise draw (a stricter "
        "yardstick: the minimum of 12 noisy errors).",
        "- **cross-validated**: the yardstick of a rule that knew the condition but not the trial: for each "
        "seed, the grid cut-off best over the condition's other seeds, scored on that seed (median over seeds). "
        "The per-condition best is the least of 12 noisy medians chosen on the trials it is scored on; "
        "**cross-validated ÷ best (condition)** is how much of a ratio that luck alone makes.",
        "- **within 2 SE**: the share of the recommended fit's judged parameters whose truth lies within two "
        "of its standard errors.",
        "",
    ]


def _target_sentence(table: pd.DataFrame) -> str:
    """In how many conditions the target ratio holds, per condition, per trial and against the cross-validated one."""
    held = int((table["ratio_per_condition"] <= TARGET).sum())
    held_trial = int((table["ratio_per_trial"] <= TARGET).sum())
    oracle = int((table["ratio_cross_validated_to_best"] <= TARGET).sum())
    beside = int((table["ratio_to_cross_validated"] <= TARGET).sum())
    beats = int((table["ratio_to_cross_validated"] <= 1.0).sum())
    return (
        f"Target: ratio ≤ {TARGET} in every condition. Held per condition in {held} of {len(table)} conditions, "
        f"per trial in {held_trial} of {len(table)}. The cross-validated yardstick itself is within {TARGET}× "
        f"of the per-condition best in {oracle} of {len(table)} conditions; the recommended fit is within "
        f"{TARGET}× of the cross-validated yardstick in {beside} and at or below it in {beats}."
    )


def _markdown(table: pd.DataFrame, label: str, seeds: tuple[int, ...], seconds: float, stem: str) -> str:
    """The study's Markdown: how it was made, the target's tally, the table of conditions and the figure."""
    return "\n".join(
        [
            *_method_lines(label, seeds, seconds),
            _target_sentence(table),
            "",
            markdown_table(_shown(table), digits=3, index=False),
            "",
            f"![ratios]({stem}.png)",
            "",
        ]
    )


def _figure(table: pd.DataFrame, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(10, 4))
    labels = [f"{k} {r:g} Hz ×{n:g}" for k, r, n in zip(table["kind"], table["rate_hz"], table["noise"])]
    x = np.arange(len(table))
    ax.bar(x - 0.2, table["ratio_per_condition"], 0.4, label="vs best cut-off per condition")
    ax.bar(x + 0.2, table["ratio_per_trial"], 0.4, label="vs best cut-off per trial")
    ax.plot(x, table["ratio_cross_validated_to_best"], "k_", ms=8, label="cross-validated best vs best per condition")
    ax.axhline(TARGET, color="k", lw=0.8, ls="--", label=f"target {TARGET}")
    ax.set_yscale("log")
    ax.set_xticks(x, labels, rotation=90, fontsize=6)
    ax.set_ylabel("recommended error ÷ hindsight best")
    ax.legend(fontsize=7)
    fig.tight_layout()
    try:
        with outputs.atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=120, format="png")
    finally:
        plt.close(fig)
