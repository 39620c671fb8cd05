"""Tables for people and programs: Markdown (no extra dependency) and CSV from a pandas DataFrame."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from ident_opt import outputs


def fmt(value: object, digits: int = 4) -> str:
    """A number with `digits` significant digits (scientific when very large or small); text as is."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return str(value)
    if value != value:  # NaN
        return "–"
    return f"{value:.{digits}g}"


def markdown_table(frame: pd.DataFrame, digits: int = 4, index: bool = True) -> str:
    """`frame` as a GitHub-flavoured Markdown table (index levels become the first columns)."""
    frame = frame.reset_index() if index else frame
    header = [str(c) for c in frame.columns]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    for row in frame.itertuples(index=False):
        lines.append("| " + " | ".join(fmt(v, digits) for v in row) + " |")
    return "\n".join(lines)


def write_table(frame: pd.DataFrame, path: Path) -> None:
    """Write `frame` as CSV at `path` (full precision)."""
    with outputs.atomic_path(path) as tmp:
        frame.to_csv(tmp, float_format="%.10g")
