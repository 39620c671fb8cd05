"""Numbers and joints in words, as every report and every cause's sentence (`Effect.sentence`) writes them. Plain
Python: the effect catalogue loads it for `--help` without NumPy."""

from __future__ import annotations

import math

#: What a report writes for a number the data did not resolve (NaN: e.g. no velocity reversal to measure a jump
#: at, a joint whose forward simulation is not reported), as the report's other tables do for an empty cell.
NOT_RESOLVED = "—"
#: A per-joint number below this share of the list's largest is shown as 0: solver round-off (a friction level the
#: consistent fit holds at its bound comes out at ~1e-11 N m beside levels of 1 N m).
ROUND_OFF = 1e-9


def num(x: float, unit: str = "", digits: int = 3) -> str:
    """A number to `digits` significant digits, with its unit; `NOT_RESOLVED` for NaN (never "nan")."""
    if not math.isfinite(x):
        return NOT_RESOLVED
    return f"{x:.{digits}g}{(' ' + unit) if unit else ''}"


def pair(xs, unit: str = "") -> str:
    """Per-joint numbers as "[a, b] unit" (round-off next to the others as 0, `ROUND_OFF`)."""
    values = [float(x) for x in xs]
    scale = max((abs(v) for v in values if math.isfinite(v)), default=0.0)
    shown = (num(0.0 if abs(v) < ROUND_OFF * scale else v) for v in values)
    return "[" + ", ".join(shown) + "]" + (f" {unit}" if unit else "")


def joint(names, j: int) -> str:
    """Joint j (0-based) as the reports name it: "joint 1" on the planar arm (joints named joint1, joint2), its name
    (the URDF's) otherwise; `names` the arm's joints' names in order."""
    names = list(names or [])
    if j < len(names) and names[j] != f"joint{j + 1}":
        return names[j]
    return f"joint {j + 1}"


def polish_note(detail: dict | None, key: str, unit: str) -> str:
    """' (IPOPT polish of the grid search's answer: a → b unit)' from a fitted candidate's `detail` (its "polish"
    record), or '' when there was no polish."""
    nlp = (detail or {}).get("polish")
    if not nlp:
        return ""
    show = pair if isinstance(nlp["before"][key], list | tuple) else num
    verdict = "kept" if nlp["kept"] else "not kept: it did not lower the training objective"
    before, after = show(nlp["before"][key]), show(nlp["after"][key], unit)
    return f" (IPOPT polish of the grid search's {key}: {before} → {after}, {verdict})"
