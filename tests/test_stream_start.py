"""The stream's first samples when the derivatives are estimated (issue 32): a stray time among them (a second
sample 1e-300 s after the first, one sample at t = 1000 or 1e300, a first step of 10 s or of 1 µs) is left out and
reported instead of setting the rate, so the stream updates as the clean one does; a byte-order mark before the
header is read as the batch loader reads it; currents without torque constants are a parse error naming the joints'
tables; a rate the causal filter cannot serve is exit status 2 at once (no filter built), never a hang."""

from __future__ import annotations

import copy
import io
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ident_opt.adaptation.lines import BadLine, LineParser, Mapping
from ident_opt.adaptation.start import offline_start, start_identifier
from ident_opt.adaptation.stream import currents_to_torques, serve
from ident_opt.data.dataset import chronological_split
from ident_opt.numerics.causal import CausalDerivatives, RateError
from ident_opt.problem import load_problem
from tests.test_fuzz import EXAMPLES, FUZZ, LOG
from tests.test_fuzz import _strict_text as _strict

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = ROOT / "problems" / "tudor_2dof.toml"
HEADER = "t,q1,q2,tau1,tau2"


@pytest.fixture(scope="module")
def setup(physical_problem, exp1):
    trial = exp1.subset(np.arange(1500))
    tr, te = chronological_split(trial.n, 0.7)
    train, test = trial.subset(tr), trial.subset(te)
    start = offline_start("pbr", physical_problem, train)
    return start, start_identifier(start, train), test


def _rows(test, times=None) -> list[str]:
    t = test.t - test.t[0] if times is None else times
    return [",".join(repr(float(v)) for v in (t[i], *test.q[i], *test.tau[i])) for i in range(test.n)]


def _serve(setup, lines: list[str]):
    start, ident, _ = setup
    out, err = io.StringIO(), io.StringIO()
    final = serve(copy.deepcopy(ident), start.names, io.StringIO("\n".join(lines) + "\n"), out, err, 0)["final"]
    errors = [json.loads(x) for x in err.getvalue().splitlines()]
    return final, errors


@pytest.fixture(scope="module")
def clean(setup):
    return _serve(setup, [HEADER, *_rows(setup[2])])


def test_clean_stream_updates_every_completed_sample(setup, clean):
    final, errors = clean
    n = setup[2].n
    assert errors == [] and final["updates"] + final["outliers"] + final["derivatives"]["lost"] == n
    assert final["derivatives"]["lost"] == 2 * final["derivatives"]["delay_samples"]


@pytest.mark.parametrize(
    "case",
    ["second 1e-300 s after the first", "first step 10 s", "first step 1 µs", "t = 1000 first", "t = 1e300 first"],
)
def test_a_stray_first_time_costs_a_sample_or_two(setup, clean, case):
    test = setup[2]
    t = test.t - test.t[0]
    rows = _rows(test)
    if case.startswith("second"):
        rows[1] = rows[1].replace(repr(float(t[1])), repr(1e-300), 1)
    elif case.startswith("first step"):
        shift = 10.0 if "10 s" in case else 1e-6 - t[1]
        rows = _rows(test, np.r_[t[0], t[1:] + shift])
    else:
        rows.insert(1, ",".join([repr(float(case.split("= ")[1].split()[0])), *rows[1].split(",")[1:]]))
    final, errors = _serve(setup, [HEADER, *rows])
    assert all(e["kind"] == "time" for e in errors), errors
    assert len(errors) <= 1
    if case.startswith("t ="):
        assert errors and errors[0]["line"] == 3  # the header is line 1, the stray sample line 3
    reference = clean[0]["updates"]
    assert reference - 3 <= final["updates"] <= reference


@pytest.mark.parametrize("stray", [1000.0, 1e300])
def test_one_stray_time_mid_stream_is_left_out(setup, clean, stray):
    rows = _rows(setup[2])
    rows.insert(200, ",".join([repr(stray), *rows[200].split(",")[1:]]))
    final, errors = _serve(setup, [HEADER, *rows])
    assert [e["line"] for e in errors] == [202] and errors[0]["kind"] == "time"
    assert final["updates"] == clean[0]["updates"] and final["derivatives"]["restarts"] == 0


def test_a_real_gap_restarts_the_window(setup, clean):
    test = setup[2]
    t = test.t - test.t[0]
    final, errors = _serve(setup, [HEADER, *_rows(test, np.where(np.arange(test.n) < 200, t, t + 50.0))])
    assert errors == [] and final["derivatives"]["restarts"] == 1
    assert final["updates"] == clean[0]["updates"] - final["derivatives"]["delay_samples"] * 2


def test_byte_order_mark_before_the_header(setup, clean):
    final, errors = _serve(setup, ["\ufeff" + HEADER, *_rows(setup[2])])
    assert errors == [] and final["updates"] == clean[0]["updates"]


def test_currents_without_torque_constants_name_the_joints_tables():
    kuka = load_problem(ROOT / "problems" / "kuka_lwr4.toml")
    scale, why = currents_to_torques(kuka.robot)
    assert scale is None and "[robot.lwr_0_joint] gives no torque_constant" in why
    parser = LineParser(mapping=Mapping.from_spec(kuka.data, kuka.robot), currents_refused=why)
    names = ["t", *(f"q{j}" for j in range(1, 8)), *(f"i{j}" for j in range(1, 8))]
    assert parser.parse(",".join(names)) is None
    with pytest.raises(BadLine) as info:
        parser.parse(",".join(["0.1"] * len(names)))
    assert info.value.kind == "parse" and "[robot.lwr_6_joint]" in str(info.value)


def test_a_rate_beyond_the_filter_is_refused_before_building_it():
    d = CausalDerivatives(15.0)
    with pytest.raises(RateError) as info:
        for k in range(10):
            d.push({"t": 1e-6 * k, "q1": 0.0, "q2": 0.0})
    assert "taps" in str(info.value) and d.k2 is None


def test_cli_a_microsecond_stream_exits_2_at_once(tmp_path):
    rows = (ROOT / "data" / "merit" / "exp1.csv").read_text().splitlines()[:1500]
    data = tmp_path / "small.csv"
    data.write_text("\n".join(rows) + "\n")
    stream = HEADER + "\n" + "".join(f"{1e-6 * k!r},0.5,0.1,1.0,0.2\n" for k in range(200))
    cmd = [sys.executable, "-m", "ident_opt", "online", "--problem", str(PROBLEM), "--data", str(data)]
    done = subprocess.run(
        [*cmd, "--stream", "--model", "pbr"], input=stream, capture_output=True, text=True, cwd=ROOT, timeout=300
    )
    assert done.returncode == 2, done.stderr[-2000:]
    assert "Traceback" not in done.stderr and "taps" in done.stderr and done.stdout == ""


# ---------------------------------------------------------------------------------------------- fuzz
HOSTILE_TIMES = ["1e-300", "1e300", "1000", "-1", "same", "+10", "+1e-6", "+0.5", "nan", "1e309", "drop", "twice"]


def _mutated_start(rows: list[str], choices: list[tuple[int, str]]) -> list[str]:
    """The clean rows with the times of some of the first ten replaced (or the row dropped, or sent twice)."""
    rows = list(rows)
    for index, how in sorted(choices, reverse=True):
        cells = rows[index].split(",")
        t = float(cells[0])
        if how == "drop":
            del rows[index]
            continue
        if how == "twice":
            rows.insert(index, rows[index])
            continue
        value = {"same": repr(float(rows[index - 1].split(",")[0])) if index else "0.0"}.get(how, how)
        if how.startswith("+"):
            value = repr(t + float(how[1:]))
        rows[index] = ",".join([value, *cells[1:]])
    return rows


@settings(FUZZ, max_examples=EXAMPLES if os.environ.get("IDENT_OPT_FUZZ_EXAMPLES") else 30)
@given(choices=st.lists(st.tuples(st.integers(0, 9), st.sampled_from(HOSTILE_TIMES)), min_size=1, max_size=4))
def test_fuzz_stream_start(setup, clean, choices):
    """Hostile times among the first ten samples: every line answered or reported (never `internal`), strict JSON,
    the stream bounded in time (well under a minute) and in loss (the clean updates less at most a dozen)."""
    lines = [HEADER, *_mutated_start(_rows(setup[2]), choices)]
    start, ident, _ = setup
    out, err = io.StringIO(), io.StringIO()
    began = time.monotonic()
    final = serve(copy.deepcopy(ident), start.names, io.StringIO("\n".join(lines) + "\n"), out, err, 0)["final"]
    elapsed = time.monotonic() - began
    problems = [f"internal error: {e}" for e in map(json.loads, err.getvalue().splitlines()) if e["kind"] == "internal"]
    problems += [f"NaN or invalid JSON line on stdout: {x[:80]}" for x in out.getvalue().splitlines() if not _strict(x)]
    if elapsed > 60:
        problems.append(f"hang: {elapsed:.0f} s")
    if final["updates"] < clean[0]["updates"] - 12:
        problems.append(f"lost updates: {final['updates']} of {clean[0]['updates']}")
    outcome = {"kind": "stream-start", "argv": [str(c) for c in choices], "status": 0, "message": ""}
    outcome["problems"] = problems
    if LOG:
        with open(LOG, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(outcome) + "\n")
    assert not problems, outcome
