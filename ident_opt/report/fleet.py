"""What `ident-opt fleet` writes: fleet.md (the fleet table a maintenance engineer reads: robot, change, joint,
since, size, confidence; the run's numbers; skipped files; warnings), fleet_changes.csv, the daily series for
dashboards (fleet_series.csv and fleet_series.parquet: one row per robot, day and parameter), for alerting
changes.jsonl and metrics.prom (`fleet.alerts`), the fleet at a glance (figures/fleet_overview.png: each robot's
tested parameters' latest z against its baseline, changes marked), a figure per robot with a change
(figures/fleet_<robot>.png: each tested parameter's daily values with their standard errors and the baseline's
band), the JSON of the contract (`docs/cli.md`, fleet) and the terminal summary.

A robot's figure costs about a second (twelve panels drawn by matplotlib), the whole of a day-added run's fleet work
for a handful of robots: `Figures` decides which are drawn. By default (`new`) a robot's figure is drawn when it has
a change that its figure in the folder does not show yet (the change's cause, joint, first day and parameters are
kept in the PNG's metadata); a change already drawn keeps its figure (its title names the last day it shows). So a
day added redraws only what the day changed, and a run from scratch draws every change."""

from __future__ import annotations

import io
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.csv as pa_csv
from PIL import Image

from ident_opt import outputs
from ident_opt.fleet import alerts
from ident_opt.fleet.changes import BAND_Z, DAY_Z, RUN_DAYS, WINDOW_Z
from ident_opt.fleet.layout import file_stem
from ident_opt.fleet.result import FleetResult, RobotResult
from ident_opt.report import record, verdicts, write_json
from ident_opt.report.figures import daily_figure, z_overview_figure
from ident_opt.report.tables import markdown_table, write_table

#: The files every run writes (figures besides, one per robot).
FILES = ("fleet.md", "fleet_changes.csv", "fleet_series.csv", "fleet_series.parquet")
#: At most this many panels per robot's figure: the moved parameters first, then the others in order.
MAX_PANELS = 12
#: Which robots' figures a run draws (module doc): `new` (a change its figure does not show yet), `all` (every
#: robot, about a second each), `none`. The fleet overview is drawn unless `none`.
Figures = Literal["new", "all", "none"]
FIGURE_CHOICES: tuple[str, ...] = ("new", "all", "none")
#: The PNG text key under which a robot's figure keeps the change it shows.
SHOWS = "ident-opt-change"
#: The fleet overview's z colour scale is clipped to ± this.
Z_CLIP = 6.0


def payload(result: FleetResult) -> dict:
    """The `fleet --json` payload (`docs/cli.md`): the fit the robot-days got and why, robots (days, parameters, se,
    their fit, and the tested parameters with their test), changes, skipped, fleet, warnings."""
    return {
        "problem": result.problem,
        "logs": result.logs,
        "estimator": result.estimator,
        "recommended_why": result.why,
        "baseline_days": result.baseline_days,
        "robots": {name: _robot(result, r) for name, r in result.robots.items()},
        "changes": [c.as_dict() for c in result.changes],
        "skipped": result.skipped,
        "fleet": result.fleet,
        "tested_definitions": result.definitions,
        "warnings": [w.as_dict() for w in result.warnings],
    }


def _series(values: np.ndarray) -> list[float | None]:
    return [float(v) if np.isfinite(v) else None for v in values]


def _robot(result: FleetResult, r: RobotResult) -> dict:
    out = {
        "days": r.days,
        "files": r.files,
        "samples": r.samples,
        "parameters": {name: _series(r.pi[:, i]) for i, name in enumerate(result.names)},
        "se": {name: _series(r.se[:, i]) for i, name in enumerate(result.names)},
    }
    if r.choice is not None:
        rec = r.choice.choice
        out.update(estimator=rec.estimator, recommended_why=rec.why, cutoff_factor=rec.factor, judged_on=r.choice.day)
    tested = {}
    for q, name in enumerate(result.tested_names):
        entry = {"values": _series(r.tested.values[:, q]), "se": _series(r.tested.se[:, q])}
        if r.test is not None:
            entry.update(z=_series(r.test.z[:, q]), baseline=float(r.test.mean[q]), scatter=float(r.test.sigma[q]))
        tested[name] = entry
    out["tested"] = tested
    return out


def series_frame(result: FleetResult) -> pd.DataFrame:
    """Every daily value as a row: robot, day, kind ("fit": the fit's parameter; "tested": an identifiable one, with
    its baseline, band and z), parameter, value, se, baseline, band_low, band_high, z."""
    parts = []
    for r in result.robots.values():
        D = len(r.days)
        if not D:
            continue
        days = np.repeat(r.days, len(result.names))
        parts.append(
            pd.DataFrame(
                {
                    "robot": r.robot,
                    "day": days,
                    "kind": "fit",
                    "parameter": np.tile(result.names, D),
                    "value": r.pi.ravel(),
                    "se": r.se.ravel(),
                }
            )
        )
        Q = len(result.tested_names)
        tested = {
            "robot": r.robot,
            "day": np.repeat(r.days, Q),
            "kind": "tested",
            "parameter": np.tile(result.tested_names, D),
            "value": r.tested.values.ravel(),
            "se": r.tested.se.ravel(),
        }
        if r.test is not None:
            mean = np.tile(r.test.mean, D)
            tested.update(
                baseline=mean,
                band_low=mean - r.test.band.ravel(),
                band_high=mean + r.test.band.ravel(),
                z=r.test.z.ravel(),
            )
        parts.append(pd.DataFrame(tested))
    columns = ["robot", "day", "kind", "parameter", "value", "se", "baseline", "band_low", "band_high", "z"]
    frame = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=columns)
    return frame.reindex(columns=columns)


def changes_frame(result: FleetResult) -> pd.DataFrame:
    """The fleet table: robot, change (its cause), joint, since (first day), size, confidence, and the rest."""
    rows = [
        {
            "robot": c.robot,
            "change": c.cause,
            "joint": c.joint if c.joint is not None else "–",
            "since": c.first_day,
            "size": _size(c),
            "confidence": f"z {c.z:+.1f}, explains {c.explained:.0%}",
            "pattern": c.pattern,
            "parameters": ", ".join(c.parameters),
            "detected": c.detected,
        }
        for c in result.changes
    ]
    columns = ["robot", "change", "joint", "since", "size", "confidence", "pattern", "parameters", "detected"]
    return pd.DataFrame(rows, columns=columns)


def _size(change) -> str:
    """A change's size in words: the drive's factor, else the lead parameter's relative change."""
    if change.scale is not None:
        return f"torque × {change.scale:.3f}"
    return f"{change.size:+.0%} {change.lead}"


def write(
    result: FleetResult,
    out: Path,
    json_path: str | Path | None,
    command: str,
    progress: Callable[[list], Iterable] | None = None,
    figures: Figures = "new",
) -> list[Path]:
    """Every file into `out` (the overview and the robots' figures under figures/, as `figures` decides), the JSON
    to `json_path`; returns the files. `progress`: wraps the list of robot figures to draw (e.g. a tqdm bar)."""
    data = payload(result)
    series = series_frame(result)
    table = changes_frame(result)
    write_table(table.set_index("robot"), out / "fleet_changes.csv")
    with outputs.atomic_path(out / "fleet_series.csv") as tmp:  # Arrow's writer: a fleet's series, 10x pandas' speed
        pa_csv.write_csv(pa.Table.from_pandas(series, preserve_index=False), tmp)
    buffer = io.BytesIO()
    series.to_parquet(buffer, index=False)
    outputs.write_bytes(out / "fleet_series.parquet", buffer.getvalue())
    drawn, kept = _robot_figures(result, out / "figures", figures, progress)
    overview = [overview_figure(result, out / "figures" / "fleet_overview.png")] if figures != "none" else []
    outputs.write_text(out / "fleet.md", markdown(result, table, command, overview + drawn, kept, out))
    files = [out / f for f in FILES] + alerts.write(result, out) + overview + drawn + kept
    verdict = verdicts.fleet_verdict(result)
    record(out, "fleet", "fleet: every robot identified every day, and what changed", files, verdict=verdict)
    write_json(json_path, data)
    return files


def _shows(change) -> str:
    """What a robot's figure of `change` shows, as kept in its PNG (`SHOWS`): a redraw is due when this differs."""
    return f"{change.cause}|{change.joint}|{change.first_day}|{','.join(change.parameters)}"


def _drawn_shows(path: Path) -> str | None:
    """The change a figure already in the folder shows (its `SHOWS` text), None when there is none or it cannot be
    read (then it is drawn again)."""
    try:
        with Image.open(path) as image:  # the text chunks before the image data: read without decoding the image
            shows = image.info.get(SHOWS)
            return shows if isinstance(shows, str) else None
    except (OSError, ValueError, AttributeError):
        return None


def _robot_figures(
    result: FleetResult, folder: Path, figures: Figures, progress: Callable[[list], Iterable] | None
) -> tuple[list[Path], list[Path]]:
    """(figures drawn, figures kept): per robot with days, as `figures` decides (module doc)."""
    change_of = {c.robot: c for c in result.changes}
    due, kept = [], []
    for r in result.robots.values():
        path = folder / f"fleet_{file_stem(r.robot)}.png"
        change = change_of.get(r.robot)
        if not r.days or figures == "none" or (figures == "new" and change is None):
            continue
        if figures == "new" and path.is_file() and _drawn_shows(path) == _shows(change):
            kept.append(path)
        else:
            due.append((r, path))
    drawn = [robot_figure(result, r, path) for r, path in (progress(due) if progress is not None else due)]
    return drawn, kept


def markdown(
    result: FleetResult, table: pd.DataFrame, command: str, figures: list[Path], kept: list[Path], out: Path
) -> str:
    """fleet.md: the run, the fleet table, the robots with no change, skipped files, warnings, the figures drawn by
    this run and those of changes drawn by an earlier one (`kept`)."""
    f = result.fleet
    unchanged = [name for name, r in result.robots.items() if r.test is not None and not r.test.moved]
    untested = [name for name, r in result.robots.items() if r.test is None]
    lines = [
        "# Fleet: what changed",
        "",
        f"`{command}`",
        "",
        f"{result.arm}; {f['robots']} robots, {f['robot_days']} robot-days, {f['files']} files, {f['samples']:,} "
        f"samples; {f['workers']} worker(s) on {f['engine']} (scheduler: {f['scheduler']}), {f['seconds']:.1f} s in "
        f"all, {_rate(f)} samples/s through the cluster.",
        "",
        f"Each robot-day's fit (the series of `fleet_series`, kind `fit`): **{result.estimator}**: {result.why}. "
        "The recommended fit is judged once per robot, on its first readable day, and kept for all its days so that "
        "its series compare like with like.",
        "",
        f"A parameter has changed when {RUN_DAYS} or more consecutive days after a robot's first "
        f"{result.baseline_days} (its baseline) lie more than {DAY_Z:g} scatter units from its baseline mean on one "
        f"side, and their mean more than {WINDOW_Z:g} standard errors; the scatter is the fleet's day-to-day scatter "
        "of that parameter, wider on days whose motion excites it less. The cause is "
        "the one (wear: a joint's friction; payload: a body on the last link; drive: one factor on a joint's torque) "
        "that explains most of the change in the pooled data from its first day on; `other` when none explains "
        "most of it.",
        "",
        "## Changes",
        "",
        markdown_table(table, index=False) if len(table) else "No change in any robot.",
        "",
        f"No change: {', '.join(unchanged) or 'none'}.",
    ]
    if untested:
        lines += ["", f"Not tested (too few fitted days): {', '.join(untested)}."]
    if result.skipped:
        skipped = pd.DataFrame(result.skipped, columns=["file", "reason"])
        lines += ["", f"## Skipped files ({len(skipped)})", "", markdown_table(skipped, index=False)]
    if result.warnings:
        lines += ["", "## Warnings", "", *(f"- `{w.code}`: {w.message}" for w in result.warnings)]
    lines += [
        "",
        "## Files",
        "",
        "- `fleet_changes.csv`: the table above; `fleet_series.csv`, `fleet_series.parquet`: every robot's daily "
        "values (kind `fit`: the fit's parameters with standard errors; kind `tested`: the identifiable parameters "
        "tested, with the baseline, the band and z)",
        *(f"- [{p.name}]({p.relative_to(out).as_posix()})" for p in figures),
        *(f"- [{p.name}]({p.relative_to(out).as_posix()}) (drawn by an earlier run, same change)" for p in kept),
        "",
    ]
    return "\n".join(lines)


def _rate(fleet: dict) -> str:
    rate = fleet.get("samples_per_second")
    return f"{rate:,.0f}" if rate else "–"


def _panels(result: FleetResult, r: RobotResult) -> list[int]:
    """The tested parameters drawn for a robot: those that moved, then the others, at most `MAX_PANELS`."""
    moved = sorted(r.test.moved) if r.test is not None else []
    rest = [q for q in range(len(result.tested_names)) if q not in moved]
    return (moved + rest)[:MAX_PANELS]


def robot_figure(result: FleetResult, r: RobotResult, path: Path) -> Path:
    """One robot's tested parameters day by day with the baseline's band and the first day of its change
    (`figures.daily_figure`)."""
    change = next((c for c in result.changes if c.robot == r.robot), None)
    panels = []
    for q in _panels(result, r):
        name = result.tested_names[q]
        panels.append(
            {
                "name": name,
                "values": r.tested.values[:, q],
                "se": r.tested.se[:, q],
                "mean": r.test.mean[q] if r.test is not None else None,
                "band": r.test.band[:, q] if r.test is not None else None,
                "moved": r.test is not None and q in r.test.moved,
                "since": change.first_day if change is not None and name in change.parameters else None,
            }
        )
    title = f"robot {r.robot}: " + (_headline(change) if change else "no change") + f" (days to {r.days[-1]})"
    metadata = {SHOWS: _shows(change)} if change is not None else None
    return daily_figure(r.days, panels, result.baseline_days, f"baseline ± {BAND_Z:g} σ", title, path, metadata)


def overview_figure(result: FleetResult, path: Path) -> Path:
    """The fleet at a glance (`figures.z_overview_figure`): per robot (rows) each tested parameter's z on its
    latest day against its baseline (grey: not tested or not determined), the robots with a change marked."""
    names = list(result.robots)
    z = np.full((len(names), len(result.tested_names)), np.nan)
    for i, r in enumerate(result.robots.values()):
        if r.test is not None and r.days:
            z[i] = r.test.z[-1]
    change_of = {c.robot: c for c in result.changes}
    marks = {i: _headline(change_of[name]) for i, name in enumerate(names) if name in change_of}
    last = max((r.days[-1] for r in result.robots.values() if r.days), default="–")
    title = f"{len(names)} robots to {last}: z of each tested parameter on the latest day; {len(marks)} changed"
    return z_overview_figure(names, list(result.tested_names), z, marks, Z_CLIP, title, path)


def _headline(change) -> str:
    """ "wear of joint 2 since 2026-03-14" and the like."""
    where = f" of joint {change.joint}" if change.joint else ""
    return f"{change.cause}{where} since {change.first_day}"


def recommended_line(result: FleetResult) -> str:
    """The terminal's line on the fit the robot-days got (stderr, as `codegen` says its fit)."""
    return f"ident-opt fleet: each robot-day's fit: {result.estimator} ({result.why})"


def terminal(result: FleetResult, out: Path, json_path) -> str:
    """The run in a line, the changes, the files."""
    f = result.fleet
    lines = [
        f"ident-opt fleet: {f['robots']} robots, {f['robot_days']} robot-days, {f['files']} files, "
        f"{f['samples']:,} samples in {f['seconds']:.1f} s ({f['workers']} workers, {f['scheduler']}; "
        f"{_rate(f)} samples/s); {len(result.skipped)} skipped",
    ]
    if result.changes:
        lines.append(f"{'robot':<10}{'change':<9}{'joint':<7}{'since':<12}{'size':<26}confidence")
        for _, row in changes_frame(result).iterrows():
            lines.append(
                f"{row['robot']:<10}{row['change']:<9}{row['joint']!s:<7}{row['since']:<12}{row['size']:<26}"
                f"{row['confidence']}"
            )
    else:
        lines.append("no change in any robot")
    lines.append(f"wrote {out / 'fleet.md'} (and the series, figures)" + (f", {json_path}" if json_path else ""))
    return "\n".join(lines)
