"""The stream's guards: implausible, overflowing, non-UTF-8 and outlying samples are reported and update
nothing; output is strict JSON; a header error is exit status 2 with one message."""

from __future__ import annotations

import copy
import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ident_opt.adaptation.start import offline_start, start_identifier
from ident_opt.adaptation.stream import StreamOptions, serve
from ident_opt.data.dataset import chronological_split

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = ROOT / "problems" / "tudor_2dof.toml"
COLS = ("t", "q1", "q2", "dq1", "dq2", "ddq1", "ddq2", "tau1", "tau2")


def _strict(text: str) -> list[dict]:
    """Parse JSON lines, refusing NaN and ±Infinity (what a strict JSON reader does)."""

    def refuse(name):
        raise ValueError(f"non-strict JSON constant {name}")

    return [json.loads(line, parse_constant=refuse) for line in text.splitlines()]


@pytest.fixture(scope="module")
def setup(physical_problem, exp1):
    trial = exp1.subset(np.arange(1500))
    tr, te = chronological_split(trial.n, 0.7)
    train, test = trial.subset(tr), trial.subset(te)
    start = offline_start("pbr", physical_problem, train)
    return start, start_identifier(start, train), test


def _line(test, i, **override) -> str:
    row = dict(zip(COLS, (test.t[i], *test.q[i], *test.dq[i], *test.ddq[i], *test.tau[i])))
    row = {k: float(v) for k, v in row.items()}
    row.update(override)
    return json.dumps(row)


def _run(setup, lines: list[str | bytes]):
    start, ident, _ = setup
    ident = copy.deepcopy(ident)
    binary = any(isinstance(x, bytes) for x in lines)
    data = b"".join((x if isinstance(x, bytes) else x.encode()) + b"\n" for x in lines)
    instream = io.BytesIO(data) if binary else io.StringIO(data.decode())
    out, err = io.StringIO(), io.StringIO()
    final = serve(ident, start.names, instream, out, err)
    return final["final"], _strict(out.getvalue()), _strict(err.getvalue())


def test_bad_samples_are_skipped_and_change_nothing(setup):
    _, _, test = setup
    clean = [_line(test, i) for i in range(60)]
    ref, _, _ = _run(setup, clean)
    bad = [
        _line(test, 60, ddq1=1e8),  # beyond the loader's plausibility limit
        _line(test, 60, tau1=1e300),
        '{"t": 1, "q1": ' + "9" * 400 + ', "q2": 0, "dq1": 0, "dq2": 0, "ddq1": 0, "ddq2": 0}',  # overflows
        '{"t": 1, "q1": 1e999, "q2": 0, "dq1": 0, "dq2": 0, "ddq1": 0, "ddq2": 0}',
        '{"t": 1, "q1": NaN, "q2": 0, "dq1": 0, "dq2": 0, "ddq1": 0, "ddq2": 0}',
        b'{"t": 1, "q1": 0.1\xff\xfe, "q2": 0}',  # not UTF-8
        "[" * 100000,  # deep nesting
    ]
    lines = clean[:30] + bad + clean[30:]
    final, records, errors = _run(setup, lines)
    assert final["parameters"] == ref["parameters"] and final["n"] == 60
    assert len(errors) == len(bad) and [e["line"] for e in errors] == list(range(31, 31 + len(bad)))
    kinds = [e["kind"] for e in errors]
    assert kinds[:2] == ["implausible", "implausible"] and kinds[5] == "encoding"
    assert final["skipped"]["implausible"] == 2 and final["lines"] == len(lines)
    assert sum("tau" in r for r in records) == 60


def test_outlier_updates_nothing_and_is_counted(setup):
    _, _, test = setup
    clean = [_line(test, i) for i in range(60)]
    ref, _, _ = _run(setup, clean)
    spike = _line(test, 30, tau1=float(test.tau[30, 0]) + 500.0)  # plausible (< 1e5) but 500 N m off
    final, records, _ = _run(setup, [*clean[:30], spike, *clean[30:]])
    assert final["parameters"] == ref["parameters"] and final["outliers"] == 1
    flagged = [r for r in records if r.get("outlier")]
    assert len(flagged) == 1 and flagged[0]["n"] == 30
    # Without the test, the spike moves the parameters.
    start, ident, _ = setup
    unguarded = copy.deepcopy(ident)
    lines = "\n".join([*clean[:30], spike, *clean[30:]]) + "\n"
    out = serve(
        unguarded, start.names, io.StringIO(lines), io.StringIO(), io.StringIO(), options=StreamOptions(outlier_k=0)
    )
    assert out["final"]["parameters"] != ref["parameters"]


def test_header_error_exits_2_with_one_message(tmp_path):
    rows = (ROOT / "data" / "merit" / "exp1.csv").read_text().splitlines()[:1500]
    data = tmp_path / "small.csv"
    data.write_text("\n".join(rows) + "\n")
    cmd = [sys.executable, "-m", "ident_opt", "online", "--problem", str(PROBLEM), "--data", str(data)]
    done = subprocess.run(
        [*cmd, "--stream", "--model", "pbr"],
        input="a,b,c\n1,2,3\n" * 50,
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    assert done.returncode == 2
    assert done.stdout == ""
    errors = [line for line in done.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and "stream:" in errors[0] and "q2" in errors[0]
