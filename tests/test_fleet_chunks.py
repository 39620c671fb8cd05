"""A long trial filtered, differentiated and reduced in pieces (`fleet.chunks`, `fleet.streamed`): the overlap
from the filter's poles, the pieces equal to the whole trial's zero-phase estimates to 1e-12, a long log's
statistics equal to the loader's, an odd long log judged by the loader word for word, and a task's peak memory
flat in the file's length."""

from __future__ import annotations

import dataclasses
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from ident_opt.data.dataset import fittable
from ident_opt.data.loader import load_dataset
from ident_opt.errors import InputError
from ident_opt.fitting import estimators
from ident_opt.fitting.recommend import Choice
from ident_opt.fleet import chunks, streamed, tasks
from ident_opt.fleet.layout import FleetFile
from ident_opt.fleet.simulated import long_trial
from ident_opt.numerics.derivatives import estimate_derivatives, lowpass, zero_phase_sos
from tests.conftest import PROBLEMS

PLANAR = str((PROBLEMS / "tudor_2dof.toml").resolve())
RATE_HZ = 200.0


def test_the_overlap_is_where_the_start_up_transient_has_decayed():
    """After `transient_samples`, a filter started from the wrong state (rest, on a constant 1) and one started in
    its steady state differ by no more than `TRANSIENT` above their rounding floor (their difference long after);
    a third of the way there, by far more; a slower filter (lower cut-off, faster sampling) needs more samples."""
    lengths = []
    for fs, cutoff in ((100.0, 15.0), (200.0, 7.5), (1000.0, 15.0), (1000.0, 2.0)):
        sos = zero_phase_sos(cutoff, fs)
        L = chunks.transient_samples(sos)
        x = np.ones(3 * L)
        from_rest = signal.sosfilt(sos, x)
        steady, _ = signal.sosfilt(sos, x, zi=signal.sosfilt_zi(sos))
        gap = np.abs(from_rest - steady)
        floor = gap[2 * L :].max()  # rounding: the two steady states differ in their last bits
        assert floor < 1e-12 and gap[0] > 0.1, (fs, cutoff, L)
        assert gap[L : 2 * L].max() <= floor + chunks.TRANSIENT, (fs, cutoff, L)
        assert gap[L // 3] > 1e3 * (floor + chunks.TRANSIENT), (fs, cutoff, L)
        lengths.append(L)
    assert lengths == sorted(lengths)
    expected = 2 * max(chunks.transient_samples(zero_phase_sos(c, 100.0)) for c in (15.0, 7.5)) + 2
    assert chunks.margin(100.0, 15.0, 7.5) == expected


def _pieces(t: np.ndarray, q: np.ndarray, fs: float, cutoff: float, block: int, size: int):
    """Velocity, acceleration and low-passed q of the whole segment, computed piece by piece."""
    source = ({"t": t[i : i + block], "q": q[i : i + block]} for i in range(0, len(t), block))
    parts = []
    for w in chunks.windows(source, size, chunks.margin(fs, cutoff)):
        parts.append((*chunks.derivatives(w, "q", fs, cutoff, len(t)), chunks.lowpassed(w, "q", fs, cutoff, len(t))))
    return [np.concatenate(p) for p in zip(*parts)]


@pytest.mark.parametrize(("fs", "cutoff", "block", "size"), [(100.0, 15.0, 777, 4096), (200.0, 7.5, 5000, 2048)])
def test_pieces_equal_the_whole_trials_zero_phase_estimates(fs, cutoff, block, size):
    """Every sample, the trial's ends included (a piece at an end is extended as the whole trial is), to 1e-12 of
    the signal's size; blocks as read and pieces of unrelated lengths."""
    rng = np.random.default_rng(4)
    t = np.arange(30_011) / fs
    q = np.column_stack([np.sin(2 * np.pi * 0.3 * t) + 0.5 * np.sin(2 * np.pi * 1.7 * t + 1), np.cos(t)])
    q += 1e-4 * rng.standard_normal(q.shape)
    dq, ddq, _ = estimate_derivatives(t, q, cutoff)
    smooth = lowpass(t, q, cutoff)
    v, a, low = _pieces(t, q, fs, cutoff, block, size)
    for whole, piece in ((dq, v), (ddq, a), (smooth, low)):
        assert piece.shape == whole.shape
        assert np.abs(piece - whole).max() <= 1e-12 * np.abs(whole).max()
    # a wrong overlap is caught: half the margin leaves the transient in
    source = ({"t": t[i : i + block], "q": q[i : i + block]} for i in range(0, len(t), block))
    short = [chunks.derivatives(w, "q", fs, cutoff, len(t))[1] for w in chunks.windows(source, size, 8)]
    assert np.abs(np.concatenate(short) - ddq).max() > 1e-6 * np.abs(ddq).max()


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> Path:
    """Long logs of the planar arm: 10⁵ rows as Parquet (row groups of 2¹⁴) and as gzip'd CSV; 10⁴ and 3·10⁵ rows
    as CSV (for memory)."""
    folder = tmp_path_factory.mktemp("long")
    frame = long_trial(PLANAR, 100_000, RATE_HZ, seed=3)
    frame.to_parquet(folder / "long.parquet", index=False, row_group_size=1 << 14)
    frame.to_csv(folder / "long.csv.gz", index=False)
    for n in (10_000, 300_000):
        long_trial(PLANAR, n, RATE_HZ, seed=5).to_csv(folder / f"n{n}.csv", index=False)
    return folder


def _loader_statistics(path: Path, choice: Choice):
    s = tasks.setup(PLANAR)
    trial = load_dataset(path, s.problem.data, s.robot)
    fittable(trial)
    (trial,) = choice.at_cutoff([trial])
    return estimators.statistics(s.model, [trial], choice.estimator), trial.n


def _arrays(stats) -> list[np.ndarray]:
    if hasattr(stats, "A"):
        return [stats.A, stats.c, stats.K, *_arrays(stats.stats)]
    return [stats.G, stats.b, stats.s, np.array([stats.n, stats.effective])]


@pytest.mark.parametrize("name", ["long.parquet", "long.csv.gz"])
@pytest.mark.parametrize("choice", [Choice("robust", "", 1.0), Choice("ols", "", 1.5)])
def test_a_long_log_read_in_pieces_gives_the_loaders_statistics(logs, name, choice):
    s, job = tasks.setup(PLANAR), tasks.Job(PLANAR)
    got, n, notes = streamed.statistics(logs / name, s, job, choice)
    whole, n_whole = _loader_statistics(logs / name, choice)
    assert n == n_whole and "read in pieces" in notes[0]
    assert any(x.startswith("velocity read as 0 where a joint rests") for x in notes)  # said, as the loader says it
    for a, b in zip(_arrays(got), _arrays(whole), strict=True):
        assert np.abs(a - b).max() <= 1e-12 * np.abs(b).max()


def _file(path: Path) -> FleetFile:
    return FleetFile("R01", "2026-03-01", str(path), f"robot=R01/day=2026-03-01/{path.name}")


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        (lambda f: f.loc.__setitem__((60_000, "t"), f.loc[59_999, "t"]), "not strictly increasing"),
        (lambda f: f.loc.__setitem__((70_000, "q2"), np.nan), "q2"),
        (lambda f: f.loc.__setitem__((40_000, "tau1"), 1e7), "implausible"),
    ],
)
def test_an_odd_long_log_is_judged_by_the_loader_word_for_word(tmp_path, change, needle):
    frame = long_trial(PLANAR, 100_000, RATE_HZ, seed=6)
    change(frame)
    path = tmp_path / "odd.parquet"
    frame.to_parquet(path, index=False)
    s, job = tasks.setup(PLANAR), tasks.Job(PLANAR)
    with pytest.raises(streamed.Whole):
        streamed.statistics(path, s, job, Choice("ols", "", 1.0))
    result = tasks.file_stats(job, _file(path), tasks.RobotChoice("R01", Choice("ols", "", 1.0)))
    with pytest.raises(InputError) as loader:
        load_dataset(path, s.problem.data, s.robot)
    assert result.stats is None and needle in result.reason
    assert result.reason == str(loader.value).replace(f"{path}: ", "").splitlines()[0]


@pytest.mark.parametrize("rests", ["auto", "as_read"])
def test_implausible_estimated_velocities_send_a_long_log_to_the_loader_whatever_the_rest_rule(tmp_path, rests):
    """A 90 rad jump of q1 (each angle still plausible): its estimated velocity is not, which the loader refuses;
    the pieces check it in the rest rule's first pass, and without that pass (`rest_velocity = "as_read"`) in their
    own."""
    frame = long_trial(PLANAR, 100_000, RATE_HZ, seed=6)
    frame.loc[50_000:, "q1"] += 90.0
    path = tmp_path / "jump.parquet"
    frame.to_parquet(path, index=False)
    s, job = tasks.setup(PLANAR), tasks.Job(PLANAR)
    spec = dataclasses.replace(s.problem.data, rest_velocity=rests)
    s = dataclasses.replace(s, problem=dataclasses.replace(s.problem, data=spec))
    with pytest.raises(streamed.Whole):
        streamed.statistics(path, s, job, Choice("ols", "", 1.0))


def _peak(job: tasks.Job, path: Path, choice: tasks.RobotChoice) -> tuple[int, tasks.FileStats]:
    tasks.file_stats(job, _file(path), choice)  # caches warm (the problem, the filters' designs)
    tracemalloc.start()
    try:
        result = tasks.file_stats(job, _file(path), choice)
        return tracemalloc.get_traced_memory()[1], result
    finally:
        tracemalloc.stop()


def test_a_tasks_peak_memory_is_flat_in_the_files_length(logs):
    """A file task on 10⁴ and on 3·10⁵ samples (CSV: every buffer in Python's or NumPy's allocator, which
    tracemalloc sees): the longer one's peak within 1.5 × the shorter one's."""
    job, choice = tasks.Job(PLANAR), tasks.RobotChoice("R01", Choice("robust", "", 1.0))
    short, a = _peak(job, logs / "n10000.csv", choice)
    long, b = _peak(job, logs / "n300000.csv", choice)
    assert a.stats is not None and b.stats is not None and b.samples > 29 * a.samples
    assert long <= 1.5 * short, (short, long)
