"""What `compare --against OTHER.json` adds (`ident_opt.runs`): compare_against.md (this run's fit beside the other
run's: parameters with their standard errors, the difference and its z, those beyond their errors in bold; the
held-out nMSE per joint of each), compare_against.csv and compare_against_errors.csv, and the terminal's lines."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from ident_opt import outputs
from ident_opt.report.tables import fmt, markdown_table, write_table
from ident_opt.runs import SideBySide

#: The files `write` puts in the output folder, the report first.
FILES = ("compare_against.md", "compare_against.csv", "compare_against_errors.csv")


def write(s: SideBySide, out: Path) -> list[str]:
    """The side-by-side files into `out`; returns their names (recorded with compare's)."""
    write_table(s.parameters, out / "compare_against.csv")
    write_table(s.errors.set_index(["held_out", "joint"]), out / "compare_against_errors.csv")
    outputs.write_text(out / "compare_against.md", to_markdown(s))
    return list(FILES)


def headline(s: SideBySide) -> str:
    """One sentence: how many parameters moved beyond their errors, and which."""
    n, shown_names = len(s.parameters), ", ".join(f"{name} (z {s.parameters.at[name, 'z']:+.1f})" for name in s.beyond)
    if not s.beyond:
        return f"no parameter of {n} moved beyond its errors (|z| > {s.threshold:g})"
    return f"{len(s.beyond)} of {n} parameters moved beyond their errors (|z| > {s.threshold:g}): {shown_names}"


def _value(value: float, se: float) -> str:
    return fmt(value) + (f" ± {fmt(se, 2)}" if se == se else "")  # se != se: NaN, no standard error


def parameter_rows(s: SideBySide) -> pd.DataFrame:
    """The parameters for people: value ± se of each run, the difference, z; a row beyond its errors in bold."""
    rows = []
    for name, r in s.parameters.iterrows():
        cells = [name, _value(r["this"], r["this_se"]), _value(r["other"], r["other_se"]), fmt(r["difference"])]
        cells.append(fmt(r["z"], 3))
        rows.append([f"**{c}**" for c in cells] if r["beyond"] else cells)
    return pd.DataFrame(rows, columns=["parameter", "this run", "other run", "difference", "z"])


def to_markdown(s: SideBySide) -> str:
    """compare_against.md."""
    lines = [
        f"# This run against {s.other.source}",
        "",
        *(f"- {note}" for note in s.notes),
        "",
        f"**{headline(s)}.** z = difference / √(se_this² + se_other²): the two runs are independent estimates; a "
        "parameter without a standard error in either run has no z.",
        "",
        "## Parameters",
        "",
        markdown_table(parameter_rows(s), index=False),
        "",
        "## Held-out nMSE per joint",
        "",
    ]
    if len(s.errors):
        errors = s.errors.rename(columns={"held_out": "held out on", "this": "this run", "other": "other run"})
        lines += [markdown_table(errors, index=False), "", "ratio: this run's over the other's (< 1: better here)."]
    else:
        lines += ["None to compare (see the notes above)."]
    return "\n".join(lines) + "\n"


def to_terminal(s: SideBySide) -> str:
    """The terminal's lines: the headline and, per held-out protocol or trial, nMSE per joint this → other."""
    lines = [f"Against {s.other.source} ({s.notes[0]}): {headline(s)}"]
    for where, rows in s.errors.groupby("held_out", sort=False):
        pairs = ", ".join(f"{r.joint} {r.this:.3g} (was {r.other:.3g})" for r in rows.itertuples())
        lines.append(f"  held-out nMSE, {where}: {pairs}")
    return "\n".join(lines)
