"""The hidden-effect benchmarks' tables (`ident_opt.report.confusion`, shared by benchmarks/confusion_matrix.py,
confusion_arms.py and unseen_plants.py): rows written from a small fixed set of trial records, counted by hand; and
unseen_plants.py's saved trial logs render to exactly its committed reports."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from ident_opt.report.confusion import chain, confusion_matrix, exact_set_summary, rounded, share

ROOT = Path(__file__).resolve().parents[1]

#: Five trials: two hide a delay (one named exactly, one named payload then delay), one a payload (missed), two are
#: clean (one false alarm).
RECORDS = [
    {"hidden": ["delay"], "named": ["delay"], "exact": True, "within": True},
    {"hidden": ["delay"], "named": ["payload", "delay"], "exact": False, "within": False},
    {"hidden": ["payload"], "named": [], "exact": False, "within": False},
    {"hidden": [], "named": [], "exact": True, "within": True},
    {"hidden": [], "named": ["delay"], "exact": False, "within": False},
]


def test_chain_share_and_rounding():
    assert chain([]) == "none" and chain(["payload", "delay"]) == "payload → delay"
    assert share(2, 3) == "2 (67%)" and share(0, 0) == "0 (0%)"
    assert rounded({"a": [0.123456, (1.0000049, 2)], "b": "x"}) == {"a": [0.1235, [1.0, 2]], "b": "x"}


def test_exact_set_summary_counts_groups_their_total_and_false_alarms():
    hidden = [r for r in RECORDS if r["hidden"]]
    clean = [r for r in RECORDS if not r["hidden"]]
    groups = [
        (label, len(rows), sum(r["exact"] for r in rows), sum(r["within"] for r in rows))
        for label, rows in (("delay", hidden[:2]), ("payload", hidden[2:]))
    ]
    lines = exact_set_summary(groups, "all", ("clean", len(clean), sum(r["exact"] for r in clean)))
    assert lines == [
        "| trials | count | exact set named | exact set, every estimate within tolerance |",
        "|---|---|---|---|",
        "| delay | 2 | 1 | 1 |",
        "| payload | 1 | 0 | 0 |",
        "| all | 3 | 1 (33%) | 1 (33%) |",
        "| clean | 2 | 1 | 1 false alarms |",
    ]


def test_confusion_matrix_counts_each_cause_named_per_hidden_case():
    causes = ("none", "payload", "delay")
    groups = [(label, [r for r in RECORDS if (r["hidden"] or ["none"])[0] == label]) for label in causes]
    anywhere = confusion_matrix(
        "hidden \\ named",
        causes,
        groups,
        lambda r, c: (c in r["named"]) or (c == "none" and not r["named"]),
        (("trials", "exact"), lambda label, rows: (str(len(rows)), f"{sum(r['exact'] for r in rows)}/{len(rows)}")),
    )
    assert anywhere == [
        "| hidden \\ named | none | payload | delay | trials | exact |",
        "|---|---|---|---|---|---|",
        "| none | 1 | 0 | 1 | 2 | 1/2 |",
        "| payload | 1 | 0 | 0 | 1 | 0/1 |",
        "| delay | 0 | 1 | 2 | 2 | 1/2 |",
    ]
    first = confusion_matrix("true \\ named", causes, groups, lambda r, c: (r["named"] or ["none"])[0] == c)
    assert first[0] == "| true \\ named | none | payload | delay |" and first[1] == "|---|---|---|---|"
    assert first[2:] == ["| none | 1 | 0 | 1 |", "| payload | 1 | 0 | 0 |", "| delay | 0 | 1 | 1 |"]


@pytest.mark.parametrize("seeds", ["tuning", "unseen", "fresh"])
def test_unseen_plants_saved_trials_render_to_its_committed_report(seeds):
    """`benchmarks/unseen_plants.py --tables` from the saved trial log gives the committed report, to the byte."""
    spec = importlib.util.spec_from_file_location("unseen_plants", ROOT / "benchmarks" / "unseen_plants.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    results = script.saved_trials([ROOT / "results" / "diagnosis" / f"unseen_plants_{seeds}.jsonl"], seeds)
    committed = (ROOT / "results" / "diagnosis" / f"unseen_plants_{seeds}.md").read_text()
    command = committed.split("Regenerate: `")[1].split("`")[0]
    assert script.tables(results, command) == committed
