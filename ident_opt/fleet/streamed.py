"""A fleet task's long file read in pieces: its statistics with memory that does not grow with its length.

A file of at least `STREAM_MIN_ROWS` rows (a Parquet file's metadata says; a CSV's size must allow it), with a
header naming t, q1…qn and tau1…taun (no logged derivatives, no currents), a cut-off given as a number in the
problem (not "auto", which reads a spectrum of the whole trial), without `--drop-invalid`, is read `CHUNK_ROWS` rows
at a time (Parquet by record batches, CSV by pandas' chunks) in three passes:

1. every column: its length, t strictly increasing, each value finite (and plausible, as the loader checks), the
   distinct time steps with their counts (a uniform log has a handful: t = k·dt rounded);
2. t and τ: the samples the loader keeps (a filter period from each end, `derivatives.settled`), the steps among
   them, each joint's torque range;
3. every column again, in pieces with their neighbours (`fleet.chunks`): the derivatives, the filtered torque and
   the instruments' derivatives as the loader and `Choice.at_cutoff` make them for the whole trial, reduced to the
   statistics (`Stats`, `InstrumentStats`) piece by piece (with a pass at the trial's own cut-off first when the
   robot's fit raises it and the loader's check of the estimated derivatives must see them).

The median step (the sampling rate the filters are designed at) is exact: the median of the counted distinct
steps. Anything the pieces cannot reproduce exactly, or that the loader would refuse or warn about (a gap, jitter,
too few samples, a value out of range), sends the file to the loader whole (`Whole`), which reads and judges it as
for every command: the same skip reason, word for word.
"""

from __future__ import annotations

import gzip
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq

from ident_opt.arm.planar import PI_NAMES
from ident_opt.columns import locate
from ident_opt.data.checks import PLAUSIBLE, PLAUSIBLE_RATE_HZ
from ident_opt.data.dataset import MAX_MAGNITUDE, convert, rest_note
from ident_opt.fitting.estimators import INSTRUMENTED
from ident_opt.fitting.iv import InstrumentStats
from ident_opt.fitting.recommend import Choice
from ident_opt.fitting.stats import Stats
from ident_opt.fleet import chunks, rests
from ident_opt.numerics.derivatives import CUTOFF_MAX_FRACTION, INSTRUMENT_RATIO, SETTLE_PERIODS

#: Rows read at a time, and outputs per piece.
CHUNK_ROWS = 8192
#: Rows whose regressors are built at once (the largest arrays of a piece's reduction).
REGRESSOR_ROWS = 2048
#: A shorter file is read whole: its pieces would be mostly neighbours.
STREAM_MIN_ROWS = 4 * CHUNK_ROWS
#: A uniform log's distinct time steps are few (rounding); more, and the file is read whole.
MAX_STEPS = 4096
#: The loader's tolerance of a uniform grid (`derivatives._uniform`): relative to the step, and to |t| at the end.
UNIFORM_STEP, UNIFORM_END = 1e-6, 1e-9


class Whole(Exception):
    """The file is read whole by the loader instead (module doc)."""


@dataclass(frozen=True)
class Layout:
    """Where a file's columns are: the label of t, of each qj, of each tauj, and each standard name's conversions
    ((scale, offset) of the problem's mapping, then the robot's)."""

    t: str
    q: tuple[str, ...]
    tau: tuple[str, ...]
    conversions: dict[str, list[tuple[float, float]]]


def _header(path: Path) -> tuple[list[str], int | None]:
    """(column names, rows: None for a CSV, whose rows are counted by reading it)."""
    if path.name.lower().endswith(".parquet"):
        meta = pq.ParquetFile(path)
        return list(meta.schema_arrow.names), meta.metadata.num_rows
    return [str(c) for c in pd.read_csv(path, nrows=0, skipinitialspace=True).columns], None


def _layout(path: Path, spec, robot) -> Layout:
    """The file's `Layout`, or `Whole` when it is not a plain log (module doc)."""
    if not path.name.lower().endswith((".parquet", ".csv", ".csv.gz")) or spec.derivative_cutoff_hz == "auto":
        raise Whole
    names, rows = _header(path)
    if rows is not None and rows < STREAM_MIN_ROWS:
        raise Whole
    if not spec.header:  # the loader's rule (`_header_row`): a first row of standard names is a header after all
        if not (spec.standard_by_name and {"t", "q1"} <= {n.strip() for n in names}):
            raise Whole
        spec = replace(spec, header=True)
    n = robot.n_joints
    found, conversions = locate(names, len(names), spec, n, str(path))
    wanted = ["t", *(f"q{j}" for j in range(1, n + 1)), *(f"tau{j}" for j in range(1, n + 1))]
    if any(k not in found for k in wanted) or any(k.startswith(("dq", "ddq", "i")) for k in found):
        raise Whole
    steps = {k: [conversions.get(k, (1.0, 0.0)), robot.column_map.get(k, (1.0, 0.0))] for k in wanted}
    label = {k: names[found[k]] for k in wanted}
    return Layout(
        label["t"], tuple(label[k] for k in wanted[1 : n + 1]), tuple(label[k] for k in wanted[n + 1 :]), steps
    )


def _small_csv(path: Path, n_joints: int) -> bool:
    """Whether a CSV is too small to hold `STREAM_MIN_ROWS` rows (each at least a digit and a comma per column)."""
    size = path.stat().st_size
    if path.name.lower().endswith(".gz"):
        with open(path, "rb") as fh:  # gzip's trailer: the uncompressed size modulo 2³²
            fh.seek(-4, 2)
            size = max(size, int.from_bytes(fh.read(4), "little"))
    return size < STREAM_MIN_ROWS * 2 * (1 + 2 * n_joints)


def _raw(path: Path, columns: list[str]) -> Iterator[pd.DataFrame]:
    """The file's `columns`, `CHUNK_ROWS` rows at a time, as text or numbers as stored."""
    if path.name.lower().endswith(".parquet"):
        # not pre-buffered: Arrow would read every row group's compressed columns before the first batch
        reader = pq.ParquetFile(path, pre_buffer=False, buffer_size=1 << 20)
        for batch in reader.iter_batches(batch_size=CHUNK_ROWS, columns=columns):
            yield batch.to_pandas()
        return
    opener = gzip.open if path.name.lower().endswith(".gz") else open
    with opener(path, "rt") as fh:  # as numbers: a cell that is not one stops the pieces (the loader names it)
        yield from pd.read_csv(fh, usecols=columns, dtype=float, skipinitialspace=True, chunksize=CHUNK_ROWS)


def blocks(path: Path, where: Layout, names: tuple[str, ...] = ("t", "q", "tau")) -> Iterator[dict[str, np.ndarray]]:
    """The file's t (N,), q (N, n), tau (N, n) (those of `names`) in SI units and the tool's convention, a piece at
    a time; a cell that is not a finite number: `Whole` (the loader names it)."""
    labels = {"t": [where.t], "q": list(where.q), "tau": list(where.tau)}
    standard = {"t": ["t"], "q": [f"q{j + 1}" for j in range(len(where.q))]}
    standard["tau"] = [f"tau{j + 1}" for j in range(len(where.tau))]
    columns = [c for k in names for c in labels[k]]
    for frame in _raw(path, columns):
        out = {}
        for k in names:
            values = []
            for label, name in zip(labels[k], standard[k]):
                v = pd.to_numeric(frame[label], errors="coerce").to_numpy(dtype=float)
                for scale, offset in where.conversions[name]:
                    v = convert(v, scale, offset)
                values.append(v)
            out[k] = values[0] if k == "t" else np.column_stack(values)
            if not np.isfinite(out[k]).all():
                raise Whole
        yield out


def median(steps: Counter) -> float:
    """The median of the counted `steps` as `np.median` gives it (the mean of the two middle ones for an even
    count)."""
    values = sorted(steps)
    total = sum(steps.values())
    middle = [(total - 1) // 2, total // 2]
    found, seen = [], 0
    for v in values:
        while len(found) < 2 and middle[len(found)] < seen + steps[v]:
            found.append(v)
        seen += steps[v]
    return float(np.mean(np.array(found)))


def _uniform(steps: Counter, t_end: float) -> float:
    """The median step [s] of a uniform grid (the loader's test), else `Whole` (a gap, jitter)."""
    if not steps or len(steps) > MAX_STEPS:
        raise Whole
    dt = median(steps)
    if max(abs(s - dt) for s in steps) > UNIFORM_STEP * max(dt, 1e-12) + UNIFORM_END * abs(t_end):
        raise Whole
    return dt


# ---------------------------------------------------------------------------------------------- passes 1 and 2
@dataclass
class Survey:
    """What the first two passes found: rows `n`, t's first and last values [s], the median step of the whole
    trial and of the kept samples [s], the kept rows [i0, i1) and the last kept t [s]."""

    n: int
    t0: float
    t_end: float
    dt: float
    i0: int = 0
    i1: int = 0
    dt_kept: float = 0.0
    t_kept_end: float = 0.0


def _count(steps: Counter, d: np.ndarray) -> None:
    values, counts = np.unique(d, return_counts=True)
    steps.update(dict(zip(values.tolist(), counts.tolist())))
    if len(steps) > MAX_STEPS:
        raise Whole


def _first_pass(path: Path, where: Layout, check: bool) -> Survey:
    """Pass 1 (module doc): the rows, t's range, its median step, and the loader's checks of t and the values."""
    n, last, t0, steps = 0, -np.inf, 0.0, Counter()
    for b in blocks(path, where):
        t = b["t"]
        if n == 0:
            t0 = float(t[0])
        d = np.diff(np.concatenate([[last], t])) if n else np.diff(t)
        if (d <= 0).any():
            raise Whole
        if check and any((np.abs(b[k]) > PLAUSIBLE[k]).any() for k in ("q", "tau")):
            raise Whole
        _count(steps, d)
        n, last = n + len(t), float(t[-1])
    if n < STREAM_MIN_ROWS:
        raise Whole
    dt = _uniform(steps, last)
    if check and not PLAUSIBLE_RATE_HZ[0] <= 1.0 / dt <= PLAUSIBLE_RATE_HZ[1]:
        raise Whole
    return Survey(n, t0, last, dt)


def _second_pass(path: Path, where: Layout, survey: Survey, cutoff_hz: float, min_samples: int) -> Survey:
    """Pass 2 (module doc): the samples kept a filter period from the ends (`derivatives.settled`), their median
    step, and the loader's checks of what is kept (enough samples, no joint's torque constant)."""
    settle = min(SETTLE_PERIODS / cutoff_hz, 0.25 * (survey.t_end - survey.t0))
    low, high = survey.t0 + settle, survey.t_end - settle
    i0 = i1 = start = 0
    steps, last_kept, lo, hi = Counter(), None, None, None
    for b in blocks(path, where, ("t", "tau")):
        t = b["t"]
        kept = (t >= low) & (t <= high)
        i0 += int((t < low).sum())
        i1 += int((t <= high).sum())
        if kept.any():
            tk, tau = t[kept], b["tau"][kept]
            _count(steps, np.diff(np.concatenate([[last_kept], tk])) if last_kept is not None else np.diff(tk))
            last_kept = float(tk[-1])
            lo = tau.min(axis=0) if lo is None else np.minimum(lo, tau.min(axis=0))
            hi = tau.max(axis=0) if hi is None else np.maximum(hi, tau.max(axis=0))
            if np.abs(tk).max() > MAX_MAGNITUDE or np.abs(tau).max() > MAX_MAGNITUDE:
                raise Whole
        start += len(t)
    if i1 - i0 < max(min_samples, 2) or lo is None or (hi - lo == 0).any():
        raise Whole
    return replace(survey, i0=i0, i1=i1, dt_kept=_uniform(steps, last_kept), t_kept_end=last_kept)


def _rows(source: Iterator[dict[str, np.ndarray]], r0: int, r1: int) -> Iterator[dict[str, np.ndarray]]:
    """The blocks of `source` cut to the rows [r0, r1)."""
    start = 0
    for b in source:
        n = len(b["t"])
        a, z = max(r0 - start, 0), min(r1 - start, n)
        if a < z:
            yield {k: v[a:z] for k, v in b.items()}
        start += n
        if start >= r1:
            return


# ---------------------------------------------------------------------------------------------- pass 3
def _derivative_checks(dq: np.ndarray, ddq: np.ndarray, kept: np.ndarray, check: bool) -> None:
    """The loader's checks of derivatives estimated at the trial's cut-off: plausible (unless allowed), and within
    what double precision can fit where kept (`data.fittable`)."""
    if check and ((np.abs(dq) > PLAUSIBLE["dq"]).any() or (np.abs(ddq) > PLAUSIBLE["ddq"]).any()):
        raise Whole
    if kept.any() and max(np.abs(dq[kept]).max(), np.abs(ddq[kept]).max()) > MAX_MAGNITUDE:
        raise Whole


def _kept(w: chunks.Window, r0: int, survey: Survey) -> np.ndarray:
    """Which of the piece's outputs the loader keeps (file rows [i0, i1))."""
    rows = r0 + np.arange(w.a, w.b)
    return (rows >= survey.i0) & (rows < survey.i1)


def _check_pass(path: Path, where: Layout, survey: Survey, cutoff_hz: float, check: bool) -> None:
    """The derivatives at the trial's own cut-off over the whole trial, checked as the loader checks them (when the
    robot's fit then raises the cut-off, pass 3 never sees them)."""
    fs = 1.0 / survey.dt
    for w in chunks.windows(blocks(path, where, ("t", "q")), CHUNK_ROWS, chunks.margin(fs, cutoff_hz)):
        dq, ddq = chunks.derivatives(w, "q", fs, cutoff_hz, survey.n)
        _derivative_checks(dq, ddq, _kept(w, 0, survey), check)


def _pieces(path: Path, where: Layout, survey: Survey, fs: float, cutoffs: tuple[float, ...], rows, check):
    """Each piece's kept samples, derivatives at the first of `cutoffs` [Hz] (the others: what else the piece must
    be long enough to filter) over the file rows `rows` (r0, r1): (q̇ (k, n), {"w": the piece, "kept", "dq", "ddq"});
    `check`: the loader's checks of the derivatives (None: none, another pass makes them)."""
    (r0, r1), cut = rows, cutoffs[0]
    for w in chunks.windows(_rows(blocks(path, where), r0, r1), CHUNK_ROWS, chunks.margin(fs, *cutoffs)):
        dq, ddq = chunks.derivatives(w, "q", fs, cut, r1 - r0)
        kept = _kept(w, r0, survey)
        if check is not None:
            _derivative_checks(dq, ddq, kept, check)
        if kept.any():
            v = dq[kept]
            yield v, {"w": w, "kept": kept, "dq": v, "ddq": ddq[kept]}


def _rest_speed(path: Path, where: Layout, survey: Survey, fs: float, cutoffs: tuple[float, ...], rows, check):
    """(n,) [rad/s]: each joint's rest speed over the kept samples (`rests.SpeedScale`: two passes)."""
    scale = None
    for dq, _ in _pieces(path, where, survey, fs, cutoffs, rows, check):
        scale = scale or rests.SpeedScale(dq.shape[1])
        scale.count(dq)
    for dq, _ in _pieces(path, where, survey, fs, cutoffs, rows, None):
        scale.collect(dq)
    return rests.speed_to_rest(scale.value())


def _block(a: dict, rest: np.ndarray, arm) -> Stats | InstrumentStats:
    """The statistics of a block of kept samples (arrays by name; `dq_z`, `ddq_z`: the instruments'), a joint at rest
    held at q̇ = 0 (`rest`)."""
    Y = arm.regressor(a["q"], np.where(rest, 0.0, a["dq"]), a["ddq"])
    if "dq_z" not in a:
        return Stats.from_regressor(Y, a["tau"])
    return InstrumentStats.from_regressors(
        Y, arm.regressor(a["q"], np.where(rest, 0.0, a["dq_z"]), a["ddq_z"]), a["tau"]
    )


def _reduce(
    path: Path,
    where: Layout,
    survey: Survey,
    arm,
    choice: Choice,
    cutoff_hz: float,
    check: bool,
    spec_rest_velocity: str,
):
    """Pass 3: the statistics of the kept samples at the choice's cut-off (`Choice.at_cutoff`: a raised cut-off
    differentiates the kept samples anew, as `recommend.raised` does), a joint at rest held at q̇ = 0 as the loader
    holds it (`rests`; unless the problem's `[data] rest_velocity` is "as_read"), the cut-off used [Hz] and each
    joint's count of samples held (None: none held)."""
    raised = choice.factor != 1
    if raised:
        _check_pass(path, where, survey, cutoff_hz, check)
        cut = min(choice.factor * cutoff_hz, CUTOFF_MAX_FRACTION * (1.0 / survey.dt_kept))
        rows, fs = (survey.i0, survey.i1), 1.0 / survey.dt_kept
    else:
        cut, rows, fs = cutoff_hz, (0, survey.n), 1.0 / survey.dt
    instrumented = choice.estimator in INSTRUMENTED
    cutoffs = (cut, INSTRUMENT_RATIO * cut) if instrumented else (cut,)
    # The loader's rule (`data.dataset.holds_rests`): these velocities are estimated, so "auto" holds them too.
    hold = spec_rest_velocity != "as_read"
    below = _rest_speed(path, where, survey, fs, cutoffs, rows, None if raised else check) if hold else None
    n = rows[1] - rows[0]

    # The loader's checks of the derivatives at the trial's cut-off: made by the rest speed's first pass when it runs,
    # here otherwise (a raised cut-off: `_check_pass` made them).
    checked_here = None if raised or hold else check

    def kept_arrays():  # each piece reduced to its kept samples' arrays at once: the piece itself is not held
        for dq, p in _pieces(path, where, survey, fs, cutoffs, rows, checked_here):
            w, kept = p["w"], p["kept"]
            arrays = {"q": w.arrays["q"][w.core][kept], "dq": dq, "ddq": p["ddq"]}
            arrays["tau"] = chunks.lowpassed(w, "tau", fs, cut, n)[kept]
            if instrumented:
                dq_z, ddq_z = chunks.derivatives(w, "q", fs, INSTRUMENT_RATIO * cut, n)
                arrays["dq_z"], arrays["ddq_z"] = dq_z[kept], ddq_z[kept]
                del dq_z, ddq_z
            del p, w
            yield dq, arrays

    total = None
    pieces = rests.held(kept_arrays(), below, survey.dt_kept) if hold else rests.unheld(kept_arrays())
    resting = 0  # per joint, the samples whose velocity is held at 0 (the loader's note, `data.dataset.rest_note`)
    for a, rest in pieces:
        resting = resting + (rest & (a["dq"] != 0)).sum(axis=0)
        for r in range(0, len(rest), REGRESSOR_ROWS):  # the regressors (rows × joints × parameters) a block at a time
            one = _block({k: x[r : r + REGRESSOR_ROWS] for k, x in a.items()}, rest[r : r + REGRESSOR_ROWS], arm)
            total = one if total is None else total + one
        del a, rest  # not alive while the next piece is read
    return total, cut, (resting if hold else None)


def statistics(path: Path, s, job, choice: Choice) -> tuple[Stats | InstrumentStats, int, list[str]]:
    """The statistics of the trial at `path` for the robot's `choice`, read in pieces (module doc), its kept
    samples and the loader's notes; `Whole` when the loader must read it."""
    spec, robot = s.problem.data, s.robot
    if job.drop_invalid:
        raise Whole
    where = _layout(path, spec, robot)
    if not path.name.lower().endswith(".parquet") and _small_csv(path, robot.n_joints):
        raise Whole
    check = not job.allow_implausible
    cutoff = float(spec.derivative_cutoff_hz)
    survey = _first_pass(path, where, check)
    survey = _second_pass(path, where, survey, cutoff, len(PI_NAMES))
    total, cut, resting = _reduce(path, where, survey, s.model, choice, cutoff, check, spec.rest_velocity)
    n = survey.i1 - survey.i0
    effective = n * min(1.0, 2 * cut / (1.0 / survey.dt_kept))  # `estimators._independent`
    if isinstance(total, InstrumentStats):
        total = replace(total, stats=replace(total.stats, effective=effective))
        finite = [total.A, total.c, total.K, total.stats.G, total.stats.b, total.stats.s]
    else:
        total = replace(total, effective=effective)
        finite = [total.G, total.b, total.s]
    if not all(np.isfinite(a).all() for a in finite):
        raise Whole
    notes = [
        f"derivatives estimated: 4th-order Butterworth at {cut:g} Hz, forward-backward, central differences; read "
        f"in pieces of {CHUNK_ROWS} rows",
        f"{survey.n - n} sample(s) within {1 / cutoff:.3g} s of the trial's ends left out: the zero-phase filter's "
        "edge error is still in their derivatives there",
    ]
    if resting is not None:
        notes.append(rest_note(spec.rest_velocity, np.asarray(resting) / n))
    return total, n, notes
