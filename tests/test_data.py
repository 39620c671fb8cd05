"""Data loading per docs/data-format.md: formats, remapping, currents, derivatives, splits, bad input."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ident_opt.cli import main
from ident_opt.data.dataset import chronological_split, shuffled_split
from ident_opt.data.loader import load_dataset
from ident_opt.numerics.derivatives import estimate_derivatives
from ident_opt.problem import DataSpec

from .conftest import PROBLEMS, kept


def minimal_problem(tmp_path: Path, extra: str = "") -> Path:
    base = (PROBLEMS / "tudor_2dof.toml").read_text()
    robot = base[base.index("[robot]") : base.index("# The real MERIt")]
    path = tmp_path / "p.toml"
    path.write_text('name = "t"\n' + robot + extra)
    return path


def trial_frame(n: int = 200, rate: float = 100.0) -> pd.DataFrame:
    t = np.arange(n) / rate
    return pd.DataFrame(
        {
            "t": t,
            "q1": 1.0 + 0.3 * np.sin(t),
            "q2": 0.2 * np.cos(2 * t),
            "tau1": np.sin(3 * t),
            "tau2": 0.1 * np.cos(t),
            "strain": np.arange(n, dtype=float),
        }
    )


def test_real_trial_mapping_and_currents(exp1, physical_problem):
    raw = pd.read_csv(physical_problem.data.trials[0], header=None)
    assert exp1.n == 8000 and exp1.rate_hz == pytest.approx(100.0)
    assert np.array_equal(exp1.q, raw[[2, 3]].to_numpy())
    assert np.array_equal(exp1.ddq, raw[[15, 16]].to_numpy())
    assert np.allclose(exp1.tau, raw[[8, 9]].to_numpy() * [4.48e-2 * 230, 1.29e-2 * 246])
    assert exp1.derivatives == "given"
    assert {"col10", "col11", "col12", "col13"} <= set(exp1.extra.columns)  # strain gauges kept


@pytest.mark.parametrize("suffix", [".csv", ".csv.gz", ".parquet", ".xlsx"])
def test_formats_round_trip(tmp_path, physical_problem, suffix):
    frame = trial_frame(60)
    path = tmp_path / f"trial{suffix}"
    if suffix == ".parquet":
        frame.to_parquet(path)
    elif suffix == ".xlsx":
        frame.to_excel(path, index=False)
    else:
        frame.to_csv(path, index=False)
    data = load_dataset(path, DataSpec(), physical_problem.robot)
    rows = kept(frame, data)
    assert 0 < len(rows) == data.n < len(frame)  # the unsettled ends left out, nothing else
    assert np.allclose(data.q, rows[["q1", "q2"]].to_numpy(), atol=1e-12)
    assert np.allclose(data.tau, rows[["tau1", "tau2"]].to_numpy(), atol=1e-12)
    assert list(data.extra.columns) == ["strain"]
    assert data.derivatives.startswith("estimated")


def test_renamed_columns(tmp_path, physical_problem):
    frame = trial_frame().rename(columns={"q1": "pos_axis2", "tau2": "torque_axis3"})
    path = tmp_path / "foreign.csv"
    frame.to_csv(path, index=False)
    spec = DataSpec(columns={"q1": "pos_axis2", "tau2": "torque_axis3"})
    data = load_dataset(path, spec, physical_problem.robot)
    assert np.allclose(data.q[:, 0], kept(frame, data)["pos_axis2"])


def test_derivatives_of_an_analytic_signal():
    """sin/cos motion at 1 kHz: the zero-phase estimate is within a stated bound (no lag)."""
    t = np.arange(0, 6, 1e-3)
    w = 2 * np.pi * 0.7
    q = np.column_stack([np.sin(w * t), 0.5 * np.cos(2 * w * t)])
    dq_true = np.column_stack([w * np.cos(w * t), -w * np.sin(2 * w * t)])
    ddq_true = np.column_stack([-(w**2) * np.sin(w * t), -2 * w**2 * np.cos(2 * w * t)])
    dq, ddq, how = estimate_derivatives(t, q, cutoff_hz=20.0)
    inner = slice(200, -200)  # filtfilt edge transients
    assert np.max(np.abs(dq - dq_true)[inner]) < 1e-3 * np.max(np.abs(dq_true))
    assert np.max(np.abs(ddq - ddq_true)[inner]) < 1e-2 * np.max(np.abs(ddq_true))
    assert "Butterworth" in how


def test_derivatives_with_nonuniform_sampling():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.8e-3, 1.2e-3, 5000))
    q = np.column_stack([np.sin(t), np.cos(t)])
    dq, ddq, how = estimate_derivatives(t, q, cutoff_hz=20.0)
    inner = slice(300, -300)
    assert "resampled" in how
    assert np.max(np.abs(dq[:, 0] - np.cos(t))[inner]) < 1e-3
    assert np.max(np.abs(ddq[:, 1] + np.cos(t))[inner]) < 1e-2


def test_splits():
    train, test = shuffled_split(1000, 0.7, seed=3)
    assert len(train) == 700 and len(test) == 300 and not set(train) & set(test)
    assert not np.array_equal(train, shuffled_split(1000, 0.7, seed=4)[0])
    assert np.array_equal(train, shuffled_split(1000, 0.7, seed=3)[0])
    train, test = chronological_split(1000, 0.7)
    assert train[-1] == 699 and test[0] == 700


# ------------------------------------------------------------------------------------------ bad input
def write(tmp_path: Path, frame: pd.DataFrame | str, name: str = "d.csv") -> Path:
    path = tmp_path / name
    if isinstance(frame, str):
        path.write_text(frame)
    else:
        frame.to_csv(path, index=False)
    return path


def with_cell(frame: pd.DataFrame, row: int, col: str, value) -> pd.DataFrame:
    frame = frame.astype(object)
    frame.loc[row, col] = value
    return frame


BAD = {
    "missing file": (None, ["not found"]),
    "empty file": ("", ["empty"]),
    "header only": ("t,q1,q2,tau1,tau2\n", ["no data rows"]),
    "wrong format": ("<xml/>", ["unsupported file type"]),
    "missing q2": (trial_frame().drop(columns="q2"), ["'q2'", "[data.columns]", "tau1"]),
    "non-numeric": (with_cell(trial_frame(), 17, "q1", "abc"), ["'q1'", "'abc'", "data row 18", "line 19"]),
    "NaN": (with_cell(trial_frame(), 5, "tau2", float("nan")), ["'tau2'", "data row 6"]),
    "inf": (with_cell(trial_frame(), 9, "q2", float("inf")), ["'q2'", "data row 10"]),
    "duplicate t": (
        with_cell(trial_frame(), 30, "t", 0.29),
        ["'t'", "not strictly increasing", "repeats", "data row 31"],
    ),
    "t goes back": (with_cell(trial_frame(), 40, "t", 0.1), ["'t'", "goes back", "data row 41"]),
    "too few samples": (trial_frame(5), ["only 5", "this command needs"]),
    "both pairs": (trial_frame().assign(i1=1.0, i2=1.0), ["both torques", "currents"]),
    "neither pair": (trial_frame().drop(columns=["tau1", "tau2"]), ["neither torques"]),
    "half a pair": (trial_frame().drop(columns=["tau2"]), ["'tau2'", "pairs"]),
    "degrees": (
        trial_frame().assign(q1=lambda f: np.degrees(f.q1) * 200),
        ["'q1'", "implausible", "--allow-implausible"],
    ),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_data_through_the_cli(tmp_path, capsys, case):
    content, words = BAD[case]
    problem = minimal_problem(tmp_path)
    name = "d.txt" if case == "wrong format" else "d.csv"
    path = tmp_path / "absent.csv" if content is None else write(tmp_path, content, name)
    before = hashlib.sha256(path.read_bytes()).hexdigest() if path.exists() else None
    out = tmp_path / "summary.json"
    status = main(["check", "--problem", str(problem), "--data", str(path), "--json", str(out)])
    err = capsys.readouterr().err
    assert status == 2
    assert "Traceback" not in err and str(path) in err
    for word in words:
        assert word in err, (word, err)
    assert not out.exists()  # nothing written half-way
    if before is not None:
        assert hashlib.sha256(path.read_bytes()).hexdigest() == before  # input never modified


def test_currents_without_a_mapping_are_converted(tmp_path, physical_problem):
    frame = trial_frame().rename(columns={"tau1": "i1", "tau2": "i2"})
    data = load_dataset(write(tmp_path, frame), DataSpec(), physical_problem.robot)
    assert np.allclose(data.tau[:, 0], kept(frame, data)["i1"] * 10.304)


def test_allow_implausible_and_drop_invalid(tmp_path, capsys):
    problem = minimal_problem(tmp_path)
    degrees = write(tmp_path, trial_frame().assign(q1=lambda f: np.degrees(f.q1) * 200))
    assert main(["check", "--problem", str(problem), "--data", str(degrees), "--allow-implausible"]) == 0
    dirty = with_cell(with_cell(trial_frame(), 17, "q1", "abc"), 30, "t", 0.29)
    path = write(tmp_path, dirty, "dirty.csv")
    out = tmp_path / "s.json"
    assert main(["check", "--problem", str(problem), "--data", str(path), "--drop-invalid", "--json", str(out)]) == 0
    captured = capsys.readouterr()
    assert "dropped 2 invalid row(s)" in captured.err
    assert '"dropped_rows": 2' in out.read_text()


def test_cli_process_exit_status_and_no_traceback(tmp_path):
    """The installed entry point as a separate process: exit 2 and a one-paragraph message."""
    problem = minimal_problem(tmp_path)
    path = write(tmp_path, with_cell(trial_frame(), 3, "q2", "x"))
    proc = subprocess.run(
        [sys.executable, "-m", "ident_opt", "check", "--problem", str(problem), "--data", str(path)],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and "'q2'" in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "ident_opt", "check", "--bogus"], capture_output=True, text=True)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr


cells = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=6),
    st.integers(-(10**12), 10**12).map(str),
    st.just(""),
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    header=st.lists(
        st.sampled_from(["t", "q1", "q2", "dq1", "tau1", "tau2", "i1", "i2", "x", ""]), min_size=0, max_size=7
    ),
    rows=st.lists(st.lists(cells, min_size=0, max_size=8), min_size=0, max_size=14),
    junk=st.binary(max_size=40),
)
def test_fuzz_malformed_csv_never_escapes_as_a_traceback(tmp_path, capsys, header, rows, junk):
    problem = minimal_problem(tmp_path)
    path = tmp_path / "fuzz.csv"
    text = ",".join(header) + "\n" + "\n".join(",".join(r) for r in rows)
    path.write_bytes(text.encode("utf-8", "surrogatepass") + junk)
    status = main(["check", "--problem", str(problem), "--data", str(path)])
    err = capsys.readouterr().err
    assert status in (0, 2)
    assert "Traceback" not in err
    if status == 2:
        assert str(path) in err


def test_dataset_subset_and_frame(exp1):
    part = exp1.subset(np.arange(10, 20))
    assert part.n == 10 and np.array_equal(part.q, exp1.q[10:20])
    frame = part.to_frame()
    assert list(frame.columns[:9]) == ["t", "q1", "q2", "dq1", "dq2", "ddq1", "ddq2", "tau1", "tau2"]
    assert replace(part, source="x").source == "x"
