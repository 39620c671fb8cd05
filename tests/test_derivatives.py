"""Zero-phase derivatives at a trial's ends and across its gaps: the cubic edge extension keeps the curvature the
odd reflection destroys, the loader leaves out the samples still within a filter period of an end, and a gap —
however long — splits the trial into segments instead of being resampled."""

from __future__ import annotations

import time

import numpy as np
import pandas as pd
import pytest

from ident_opt.data.loader import load_dataset
from ident_opt.errors import InputError
from ident_opt.numerics.derivatives import estimate_derivatives, segments, settled
from ident_opt.problem import DataSpec


def sines(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """q (N, 2) [rad] and its exact ddq [rad/s²]: two sines below 2 Hz whose curvature is large at t = 0."""
    w1, w2 = 2 * np.pi * 0.7, 2 * np.pi * 1.9
    q = np.column_stack([np.sin(w1 * t + 1.3), 0.4 * np.cos(w2 * t)])
    ddq = np.column_stack([-(w1**2) * np.sin(w1 * t + 1.3), -0.4 * w2**2 * np.cos(w2 * t)])
    return q, ddq


def test_edges_keep_their_curvature():
    """One filter period in from either end, the acceleration is within 3 % of its peak (an odd reflection: 4–14 %);
    at the very first sample within 25 % (odd reflection: up to 57 %)."""
    rate, cutoff = 500.0, 5.0
    t = np.arange(0, 8, 1 / rate)
    q, ddq_true = sines(t)
    _, ddq, _ = estimate_derivatives(t, q, cutoff)
    error = np.abs(ddq - ddq_true) / np.abs(ddq_true).max(axis=0)
    one_period = int(rate / cutoff)
    assert error[one_period:-one_period].max() < 0.03
    assert error.max() < 0.25


def test_the_loader_leaves_out_the_unsettled_ends(tmp_path, physical_problem):
    rate, cutoff = 200.0, 4.0
    t = np.arange(0, 10, 1 / rate)
    q, _ = sines(t)
    frame = pd.DataFrame({"t": t, "q1": q[:, 0], "q2": q[:, 1], "tau1": q[:, 0], "tau2": q[:, 1]})
    frame.to_csv(tmp_path / "a.csv", index=False)
    d = load_dataset(tmp_path / "a.csv", DataSpec(derivative_cutoff_hz=cutoff), physical_problem.robot)
    assert d.t[0] >= 1 / cutoff - 1e-9 and d.t[-1] <= t[-1] - 1 / cutoff + 1e-9
    assert d.n == int(settled(t, cutoff).sum())
    kept = np.isin(t, d.t)
    assert np.allclose(d.q, q[kept]) and np.allclose(d.tau, q[kept])  # values untouched, only rows left out
    assert any("left out" in note for note in d.notes)


def test_a_gap_splits_the_trial_and_costs_nothing(tmp_path, physical_problem):
    """A 10⁶ s gap in the middle (a bag whose stamps jump): two segments, each differentiated on its own, read in
    well under a second (the whole span used to be resampled: minutes for 10⁵ s, 728 TiB asked for 10¹² s)."""
    rate = 100.0
    t = np.arange(0, 6, 1 / rate)
    t = np.concatenate([t, t + 1e6])
    q = np.concatenate([sines(np.arange(0, 6, 1 / rate))[0]] * 2)
    assert [s.stop - s.start for s in segments(t, 5.0)] == [600, 600]
    frame = pd.DataFrame({"t": t, "q1": q[:, 0], "q2": q[:, 1], "tau1": q[:, 0], "tau2": q[:, 1]})
    frame.to_csv(tmp_path / "gap.csv", index=False)
    start = time.perf_counter()
    d = load_dataset(
        tmp_path / "gap.csv", DataSpec(derivative_cutoff_hz=5.0), physical_problem.robot, allow_implausible=True
    )
    assert time.perf_counter() - start < 5.0  # generous for a loaded machine; was minutes to never
    assert "2 segments" in d.derivatives
    first = d.t < 1e5
    assert first.any() and (~first).any()
    # each side is estimated like a trial of its own: equal accelerations for equal motion
    assert np.allclose(d.ddq[first], d.ddq[~first], atol=1e-9)


def test_a_trial_too_short_to_settle(tmp_path, physical_problem):
    """Shorter than four filter periods: its middle half is kept; fewer samples than the command needs is an
    InputError naming the file and the filter period."""
    t = np.arange(0, 0.5, 1 / 100.0)
    q, _ = sines(t)
    frame = pd.DataFrame({"t": t, "q1": q[:, 0], "q2": q[:, 1], "tau1": q[:, 0], "tau2": q[:, 1]})
    frame.to_csv(tmp_path / "short.csv", index=False)
    d = load_dataset(tmp_path / "short.csv", DataSpec(derivative_cutoff_hz=1.0), physical_problem.robot)
    assert 20 <= d.n <= 30
    with pytest.raises(InputError, match=r"short\.csv.*filter period"):
        load_dataset(tmp_path / "short.csv", DataSpec(derivative_cutoff_hz=1.0), physical_problem.robot, min_samples=40)
