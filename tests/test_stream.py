"""Streaming mode: same output as the replay, bad lines skipped, clean shutdown with final parameters."""

from __future__ import annotations

import copy
import io
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from ident_opt.adaptation.lines import BadLine, LineParser
from ident_opt.adaptation.start import offline_start, start_identifier
from ident_opt.adaptation.stream import serve
from ident_opt.data.dataset import chronological_split
from ident_opt.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = ROOT / "problems" / "tudor_2dof.toml"
COLS = ("t", "q1", "q2", "dq1", "dq2", "ddq1", "ddq2", "tau1", "tau2")


@pytest.fixture(scope="module")
def small(tmp_path_factory, exp1):
    """The first 1500 rows of exp1 (same file format) and its offline/online parts."""
    path = tmp_path_factory.mktemp("stream") / "exp1_small.csv"
    lines = (ROOT / "data" / "merit" / "exp1.csv").read_text().splitlines()[:1500]
    path.write_text("\n".join(lines) + "\n")
    trial = exp1.subset(np.arange(1500))
    tr, te = chronological_split(trial.n, 0.7)
    return path, trial.subset(tr), trial.subset(te)


def _rows(data, n):
    return [dict(zip(COLS, (data.t[i], *data.q[i], *data.dq[i], *data.ddq[i], *data.tau[i]))) for i in range(n)]


def test_parser_formats_and_bad_lines():
    p = LineParser()
    assert p.parse("t,q1,q2,dq1,dq2,ddq1,ddq2,tau1,tau2,extra\n") is None
    s = p.parse("0.1,1,2,3,4,5,6,7,8,x\n")
    assert s == {"t": 0.1, "q1": 1, "q2": 2, "dq1": 3, "dq2": 4, "ddq1": 5, "ddq2": 6, "tau1": 7, "tau2": 8}
    for bad in (
        "0.1,1,2,3,4,5,6,7,8\n",
        "0.1,1,2,oops,4,5,6,7,8,x\n",
        "0.1,1,2,nan,4,5,6,7,8,x\n",
        "0.1,1,2,3,4,5,6,7,,x\n",
    ):
        with pytest.raises(BadLine):
            p.parse(bad)
    j = LineParser()
    assert j.parse('{"q1": 1, "q2": 2, "dq1": 0, "dq2": 0, "ddq1": 0, "ddq2": 0}') == {
        "q1": 1,
        "q2": 2,
        "dq1": 0,
        "dq2": 0,
        "ddq1": 0,
        "ddq2": 0,
    }
    for bad in (
        "{not json",
        "[1, 2]",
        '{"q1": 1}',
        '{"q1": true, "q2": 2, "dq1": 0, "dq2": 0, "ddq1": 0, "ddq2": 0}',
        '{"q1": 1, "q2": 2, "dq1": 0, "dq2": 0, "ddq1": 0, "ddq2": "inf"}',
    ):
        with pytest.raises(BadLine):
            j.parse(bad)
    with pytest.raises(InputError):
        LineParser().parse("a,b,c\n")  # a header without the needed columns: the stream cannot be read


def test_serve_equals_replay_and_skips_bad_lines(physical_problem, small):
    from ident_opt.models.hybrid import make_gmr

    _, train, test = small
    start = offline_start("pbr", physical_problem, train)
    ident = start_identifier(start, train, make_gmr(physical_problem.residual, components=2))
    twin = copy.deepcopy(ident)
    rows = _rows(test, 250)
    text = io.StringIO()
    text.write(",".join(COLS) + "\n")
    for i, row in enumerate(rows):
        text.write(",".join(repr(float(row[c])) for c in COLS) + "\n")
        if i in (3, 100):
            text.write("0.5,garbage,1,2,3,4,5,6,7\n")  # malformed: skipped, the stream goes on
        if i == 150:
            text.write("1,2,3\n")
    out, err = io.StringIO(), io.StringIO()
    final = serve(ident, start.names, io.StringIO(text.getvalue()), out, err, snapshot_every=100)
    records = [json.loads(line) for line in out.getvalue().splitlines()]
    predictions = [r for r in records if "tau" in r]
    assert len(predictions) == 250
    assert [r["snapshot"]["n"] for r in records if "snapshot" in r] == [100, 200]
    errors = [json.loads(line) for line in err.getvalue().splitlines()]
    assert [e["line"] for e in errors] == [6, 104, 155] and all("error" in e for e in errors)
    for row, rec in zip(rows, predictions):
        p = twin.update(
            np.array([row["q1"], row["q2"]]),
            np.array([row["dq1"], row["dq2"]]),
            np.array([row["ddq1"], row["ddq2"]]),
            np.array([row["tau1"], row["tau2"]]),
        )
        assert rec["tau"] == p.tau.tolist() and rec["lower"] == p.lower.tolist()
        assert rec["upper"] == p.upper.tolist() and rec["t"] == row["t"]
    assert records[-1] == final
    assert list(final["final"]["parameters"].values()) == twin.theta.tolist()
    assert final["final"]["n"] == 250


def test_prediction_only_lines_do_not_update(physical_problem, small):
    _, train, test = small
    start = offline_start("dm_physical", physical_problem, train)
    ident = start_identifier(start, train)
    line = json.dumps({k: float(v) for k, v in _rows(test, 1)[0].items() if not k.startswith("tau")})
    out = io.StringIO()
    serve(ident, start.names, io.StringIO(line + "\n"), out, io.StringIO())
    records = [json.loads(x) for x in out.getvalue().splitlines()]
    assert records[0]["n"] == 0 and records[-1]["final"]["n"] == 0


def _start_stream(small, *extra):
    path, _, _ = small
    cmd = [
        sys.executable,
        "-m",
        "ident_opt",
        "online",
        "--problem",
        str(PROBLEM),
        "--data",
        str(path),
        "--stream",
        "--components",
        "2",
        *extra,
    ]
    return subprocess.Popen(
        cmd,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def test_cli_stream_equals_cli_replay(physical_problem, small, tmp_path):
    """The service's JSON-lines output equals the replay's predictions for the same samples."""
    from ident_opt.adaptation.replay import replay

    _, train, test = small
    n = 120
    result = replay(
        physical_problem, train, test.subset(np.arange(n)), keys=("pbr",), components=2, checks=0, progress=False
    )
    proc = _start_stream(
        small, "--model", "pbr+gmr", "--final", str(tmp_path / "final.json"), "--no-guard", "--outlier-k", "0"
    )
    lines = [json.dumps({k: float(v) for k, v in row.items()}) for row in _rows(test, n)]
    lines.insert(10, "{broken")
    out, err = proc.communicate("\n".join(lines) + "\n", timeout=120)
    assert proc.returncode == 0, err
    records = [json.loads(x) for x in out.splitlines()]
    taus = np.array([r["tau"] for r in records if "tau" in r])
    # The service's update runs in generated C (the same exact solve; rounding differs at 1e-14).
    np.testing.assert_allclose(taus, result.pred["pbr+gmr"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.array([r["std"] for r in records if "tau" in r]), result.std["pbr+gmr"], rtol=1e-9)
    final = json.loads((tmp_path / "final.json").read_text())
    assert final == records[-1]
    np.testing.assert_allclose(list(final["final"]["parameters"].values()), result.theta["pbr"][-1], rtol=1e-9)
    assert '"line": 11' in err


def _read_lines(proc: subprocess.Popen, k: int, timeout: float = 120.0) -> list[str]:
    """The next `k` lines of the service's stdout, or a failure (the process killed) when they do not come within
    `timeout` s: a bare readline would wait for ever on a service that never answers."""
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout.readline() for _ in range(k)), daemon=True)
    reader.start()
    reader.join(timeout)
    if reader.is_alive():
        proc.kill()
        pytest.fail(f"the stream answered {len(lines)} of {k} samples within {timeout:g} s")
    return lines


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_shuts_down_cleanly_with_final_parameters(small, sig):
    _, _, test = small
    proc = _start_stream(small, "--model", "pbr")
    for row in _rows(test, 5):
        proc.stdin.write(json.dumps({k: float(v) for k, v in row.items()}) + "\n")
    proc.stdin.flush()
    got = _read_lines(proc, 5)  # the service answered: it is waiting for input now
    assert all('"tau"' in g for g in got)
    time.sleep(0.2)
    proc.send_signal(sig)
    rest, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    final = json.loads(rest.splitlines()[-1])
    assert final["final"]["n"] == 5 and set(final["final"]["parameters"]) >= {"a1", "fc2"}
    assert "Traceback" not in err


def test_random_garbage_never_stops_the_stream(physical_problem, small):
    """Fuzz: arbitrary text lines between valid samples are reported and skipped, never fatal."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    _, train, test = small
    start = offline_start("dm_physical", physical_problem, train)
    rows = _rows(test, 3)
    valid = [json.dumps({k: float(v) for k, v in row.items()}) for row in rows]

    @settings(max_examples=60, deadline=None)
    @given(st.lists(st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=40), max_size=6))
    def check(garbage):
        garbage = [g.replace("\n", " ").replace("\r", " ") for g in garbage]
        lines = [valid[0], *garbage, valid[1], *garbage[::-1], valid[2]]
        ident = start_identifier(start, train)
        out, err = io.StringIO(), io.StringIO()
        serve(ident, start.names, io.StringIO("\n".join(lines) + "\n"), out, err)
        records = [json.loads(x) for x in out.getvalue().splitlines()]
        assert sum("tau" in r for r in records) == 3  # every valid sample answered, nothing else
        assert records[-1]["final"]["n"] == 3
        assert all("error" in json.loads(e) for e in err.getvalue().splitlines())

    check()


def test_currents_become_torques():
    p = LineParser(current_to_torque=(10.0, 2.0))
    p.parse("q1,q2,dq1,dq2,ddq1,ddq2,i1,i2\n")
    s = p.parse("0,0,0,0,0,0,0.5,-1.5\n")
    assert s["tau1"] == 5.0 and s["tau2"] == -3.0 and "i1" not in s
    with pytest.raises(BadLine):
        LineParser().parse('{"q1": 0, "q2": 0, "dq1": 0, "dq2": 0, "ddq1": 0, "ddq2": 0, "i1": 1, "i2": 1}')
    with pytest.raises(BadLine):
        LineParser(current_to_torque=(1.0, 1.0)).parse(
            '{"q1": 0, "q2": 0, "dq1": 0, "dq2": 0, "ddq1": 0, "ddq2": 0, "i1": 1, "i2": 1, "tau1": 0, "tau2": 0}'
        )
