"""The tables of the hidden-effect benchmarks (`benchmarks/confusion_matrix.py`, `confusion_arms.py`,
`unseen_plants.py`): how a trial's chain of causes and its estimates are written, the exact-set summary, and the
confusion matrix of hidden × named causes. Each benchmark keeps its own records and columns; these write them."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence

#: The exact-set summary's header and rule.
EXACT_SET_HEAD = (
    "| trials | count | exact set named | exact set, every estimate within tolerance |",
    "|---|---|---|---|",
)


def rounded(value):
    """`value` with every float (also inside dicts, lists and tuples, which become lists) to 4 decimals."""
    if isinstance(value, dict):
        return {k: rounded(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [rounded(v) for v in value]
    return round(value, 4) if isinstance(value, float) else value


def chain(named: Sequence[str]) -> str:
    """The causes named, in order ("a → b"), "none" for none."""
    return " → ".join(named) or "none"


def worst(errors: dict) -> str:
    """A trial's worst relative error as a table cell: "—" when no named cause had an estimate to judge."""
    return f"{max(errors.values()):.3f}" if errors else "—"


def share(count: int, total: int) -> str:
    """ "count (percent of total)", 0 % of nothing."""
    return f"{count} ({count / max(total, 1):.0%})"


def exact_set_summary(
    groups: Iterable[tuple[str, int, int, int]], total: str, clean: tuple[str, int, int]
) -> list[str]:
    """The exact-set table: a row per group of trials with hidden causes (label, trials, exact set named, exact set
    with every estimate within tolerance), their total (labelled `total`, with shares), and the clean trials
    (label, trials, how many named nothing) with their false alarms."""
    groups = list(groups)
    lines = [*EXACT_SET_HEAD, *(f"| {label} | {n} | {exact} | {within} |" for label, n, exact, within in groups)]
    n, exact, within = (sum(g[k] for g in groups) for k in (1, 2, 3))
    lines.append(f"| {total} | {n} | {share(exact, n)} | {share(within, n)} |")
    label, n_clean, exact_clean = clean
    lines.append(f"| {label} | {n_clean} | {exact_clean} | {n_clean - exact_clean} false alarms |")
    return lines


def confusion_matrix(
    corner: str,
    causes: Sequence[str],
    groups: Iterable[tuple[str, list[dict]]],
    named: Callable[[dict, str], bool],
    extra: tuple[Sequence[str], Callable[[str, list[dict]], Sequence[str]]] = ((), lambda label, rows: ()),
) -> list[str]:
    """Hidden × named: a row per (label, trials) of `groups`, a column per cause of `causes` counting the trials for
    which `named(trial, cause)` holds; `extra` = (the further columns' heads, a function of the row's label and
    trials giving their cells). `corner`: the top-left cell ("true \\ named")."""
    heads, cells = extra
    lines = [
        f"| {corner} | " + " | ".join(causes) + "".join(f" | {h}" for h in heads) + " |",
        "|---|" + "---|" * (len(causes) + len(heads)),
    ]
    for label, rows in groups:
        counts = [sum(bool(named(r, c)) for r in rows) for c in causes]
        lines.append(
            f"| {label} | " + " | ".join(map(str, counts)) + "".join(f" | {x}" for x in cells(label, rows)) + " |"
        )
    return lines


def believability(d) -> dict:
    """What a trial's diagnosis `d` (a `Diagnosis`) says beyond the causes named, for the tables below: its verdict,
    the causes the plausibility rule rejected, and the joints whose held-out nMSE the named model made worse by more
    than 5 % (a named model worse than the one before it on some joint)."""
    worse = [
        name for name, before, after in zip(d.joints, d.nmse_before, d.nmse_after) if d.causes and after > 1.05 * before
    ]
    return {"verdict": d.verdict, "rejected": sorted({r["cause"] for r in d.rejected}), "worse_on": worse}


def believability_lines(rows: Iterable[tuple[Sequence[str], dict]]) -> list[str]:
    """The plausibility section: per trial (hidden causes, `believability` record), how often the rule rejected a
    cause that was truly hidden and was then not named (it must stay right on the simulator), the verdicts, and the
    named models worse than the nominal one on some joint."""
    rows = list(rows)
    verdicts: dict[str, int] = {}
    for _, b in rows:
        verdicts[b["verdict"]] = verdicts.get(b["verdict"], 0) + 1
    lost = [(hidden, b) for hidden, b in rows if set(hidden) & set(b["rejected"]) - set(b.get("named", ()))]
    worse = [(hidden, b) for hidden, b in rows if b["worse_on"]]
    with_cause = sum(1 for hidden, _ in rows if hidden)
    out = [
        "## Plausibility and verdicts",
        "",
        f"Verdicts: {', '.join(f'{k} {v}' for k, v in sorted(verdicts.items()))} (of {len(rows)} trials).",
        "",
        f"A hidden cause the plausibility rule rejected and that was not named: {len(lost)} of {with_cause} trials "
        "with a cause" + (":" if lost else "."),
    ]
    out += [f"- {' + '.join(h)}: rejected {', '.join(b['rejected'])}; verdict {b['verdict']}" for h, b in lost]
    out += [
        "",
        f"A named model worse than the nominal one by more than 5 % on some joint: {len(worse)} of {len(rows)} trials"
        + (":" if worse else "."),
    ]
    out += [f"- {' + '.join(h) or 'clean'}: worse on {', '.join(b['worse_on'])}" for h, b in worse]
    return [*out, ""]
