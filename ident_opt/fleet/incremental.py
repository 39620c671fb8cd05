"""Phase 1 of a fleet run with its store (`fleet.store`): only what the store does not hold goes to the cluster.

1. Every file's content is hashed (SHA-256 of its bytes, on the client, a few threads: reading is cheap next to a
   task's derivatives and fit), except a local file whose stamp (size, modification and change times, inode) is as
   stored: its stored hash stands (`stamp`), so a daily run reads the bytes of its new files only.
2. Choices: a robot whose first `baseline_days` + `SPARE_DAYS` days hold the same files (names and hashes) as when
   its choice was stored keeps it; the others are chosen on the cluster (`tasks.choose`).
3. Files: a stored file with the same hash, reduced for the same fit (estimator and cut-off factor), keeps its
   statistics; the others are read on the cluster (`tasks.file_stats`). Days: a robot-day whose files and fit are as
   when its fit was stored keeps it; the others are summed and fitted on the cluster (`tasks.day_stats`,
   `tasks.fit_day`), their stored files' statistics read from the store and sent along.
4. On the client: the robot's baseline model (stored, when its first days' files and its fit are as then; else from
   those days' statistics, `tasks.baseline`) and each day's torque scales (stored, when the day's files, its fit and
   the baseline's files are as then; else from the day's statistics, `tasks.scales`). The same functions on the
   same numbers in the same order as a run with an empty store: the result is the same.

A stored file's statistics are read from the store only where step 3 or 4 (or phase 2, a change's files) needs them
(`Files`): a day added reads the statistics of its robots' changes, not of the whole history.

A file whose bytes changed since they were stored is read again, with a warning naming it; a stored file gone from
the layout is dropped from the store (and so from the series), with a warning.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import fsspec

from ident_opt.fleet import layout, store, tasks
from ident_opt.fleet.engine import Engine
from ident_opt.warnings import ResultWarning

#: The baseline model may look this many days past the baseline for days with statistics (unreadable days).
SPARE_DAYS = 3
#: Files are hashed in blocks of this many bytes [B], by this many threads.
HASH_BLOCK, HASH_THREADS = 1 << 20, 4
#: A run whose store holds files and that has at most this many left to read (a day added to a fleet of as many
#: robots) runs its local cluster's workers as threads in this process: starting and closing worker processes takes
#: 5–6 s on 2 cores, more than threads lose to the GIL on such a day's work (≈ 40 CPU-ms a file: at 2 workers
#: threads stay ahead up to about 500 files, at many workers about 200; results/fleet_scale_200.md). An existing
#: cluster (`--scheduler`) is used as it is.
SMALL_RUN = 250
#: A warning names at most this many files.
NAMED = 5


class Files:
    """Every file's statistics, by name: those this run computed (held) and those the store holds (read when asked
    for, `store.read_files`)."""

    def __init__(self, stored: store.Stored, made: dict[str, tasks.FileStats]):
        self.stored, self.made = stored, made

    def get(self, files: list[layout.FleetFile]) -> list[tasks.FileStats]:
        """The statistics of `files`, in their order."""
        read = store.read_files(self.stored, [f for f in files if f.name not in self.made])
        found = {r.file.name: r for r in read}
        return [self.made[f.name] if f.name in self.made else found[f.name] for f in files]

    def day(self, files: list[layout.FleetFile], day: str | None = None) -> tasks.DayStats:
        """The sum of `files`' statistics (`tasks.day_stats`)."""
        return tasks.day_stats(*self.get(files), day=day)


@dataclass
class Phase1:
    """What phase 1 gathered: the choices, day fits, baselines and scales (as `run._series` takes them), every
    file's statistics (`Files`: phase 2 pools them), what to write back to the store, the counts of files computed,
    taken from the store, changed and gone, the samples read, the cluster's wall seconds, its workers and address,
    and the warnings."""

    gathered: list
    files: Files
    update: store.Update
    counts: dict[str, int]
    samples_read: int
    engine_seconds: float
    cluster: tuple[int, str]
    warnings: list[ResultWarning] = field(default_factory=list)


def _sha256(url: str) -> str | None:
    """The SHA-256 of the file at `url`, None when it cannot be read (its task says why)."""
    digest = hashlib.sha256()
    try:
        with fsspec.open(url, "rb") as handle:
            while block := handle.read(HASH_BLOCK):
                digest.update(block)
    except (OSError, ValueError):
        return None
    return digest.hexdigest()


def stamp(url: str) -> str | None:
    """A local file's size, modification and change times [ns] and inode, as JSON; None elsewhere. Writing a file's
    bytes always moves its change time, which no tool can set back (`touch`, `cp -p` and `rsync -t` set only the
    modification time): an unchanged stamp is an unchanged file (git's rule for its index)."""
    path = layout.local_root(url)
    try:
        st = os.stat(path) if path is not None else None
    except OSError:
        return None
    return None if st is None else json.dumps([st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino])


def content_hashes(found: layout.Layout, stored: store.Stored) -> tuple[dict, dict]:
    """({name: SHA-256 of the file's bytes, None when unreadable (never taken from the store)}, {name: stamp}): the
    stored hash of a file whose stamp is as stored, every other file read and hashed (a few threads)."""
    stamps = {f.name: stamp(f.url) for f in found.files}
    hashes: dict[str, str | None] = {}
    for f in found.files:
        row = stored.files.get(f.name)
        if row is not None and stamps[f.name] is not None and row.stamp == stamps[f.name]:
            hashes[f.name] = row.sha256
    todo = [f for f in found.files if f.name not in hashes]
    with ThreadPoolExecutor(HASH_THREADS) as pool:
        hashes.update(zip((f.name for f in todo), pool.map(_sha256, (f.url for f in todo))))
    return hashes, stamps


def _files_key(files: list[layout.FleetFile], hashes: dict[str, str | None]) -> list:
    return [(f.name, hashes[f.name]) for f in files]


def _known(job: tasks.Job, found: layout.Layout, stored: store.Stored, hashes, K: int) -> tuple[dict, dict]:
    """({robot: stored choice that stands}, {robot: digest of the files its choice is judged on})."""
    judged, known = {}, {}
    for robot in found.robots:
        first = [_files_key(found.files_of(robot, d), hashes) for d in found.days(robot)[: K + SPARE_DAYS]]
        judged[robot] = store.digest(job.estimator, first)
        kept = stored.choices.get(robot)
        if kept is not None and kept[0] == judged[robot] and None not in {h for day in first for _, h in day}:
            known[robot] = kept[1]
    return known, judged


def _choose(engine: Engine, job: tasks.Job, found: layout.Layout, known: dict, judged: dict, K: int, progress):
    """Each robot's choice, stored or made on the cluster, and {robot: (judged digest, choice)} of those made."""

    def submit(client, robot: str) -> tuple[list, list]:
        first = [found.files_of(robot, day) for day in found.days(robot)[: K + SPARE_DAYS]]
        return [client.submit(tasks.choose, job, robot, *first)], []

    todo = [r for r in found.robots if r not in known]
    made = {c.robot: c for c in engine.run(todo, submit, len(todo), progress, "fleet: choosing each robot's fit")}
    return {**known, **made}, {r: (judged[r], c) for r, c in made.items()}


def _to_read(found: layout.Layout, stored: store.Stored, hashes, known: dict) -> int:
    """At most how many files the cluster will read: those the store holds under another hash or not at all, and
    every file of a robot whose fit is chosen anew."""
    return sum(
        f.robot not in known or f.name not in stored.files or stored.files[f.name].sha256 != hashes[f.name]
        for f in found.files
    )


def _kept_file(row: store.StoredFile | None, sha: str | None, choice: tasks.RobotChoice) -> bool:
    """Whether a stored file still stands: the same bytes, reduced for the same fit."""
    if row is None or sha is None:
        return False
    return row.sha256 == sha and (row.estimator, row.factor) == (choice.choice.estimator, choice.choice.factor)


def _day_digest(files: list[layout.FleetFile], hashes, choice: tasks.RobotChoice) -> str:
    return store.digest(choice.choice.estimator, choice.choice.factor, _files_key(files, hashes))


def _plan(found: layout.Layout, stored: store.Stored, hashes, choices) -> tuple[set, dict, dict, dict]:
    """(names of the stored files whose statistics stand; stored fits that stand, by (robot, day); fits to make, by
    (robot, day): their digest; every day's digest, "" for a day with a file that could not be hashed)."""
    kept, fits, todo, digests = set(), {}, {}, {}
    for robot in found.robots:
        choice = choices[robot]
        for day in found.days(robot):
            files = found.files_of(robot, day)
            kept.update(f.name for f in files if _kept_file(stored.files.get(f.name), hashes[f.name], choice))
            dg = _day_digest(files, hashes, choice)
            unhashed = any(hashes[f.name] is None for f in files)
            digests[robot, day] = "" if unhashed else dg
            known = stored.fits.get((robot, day))
            if known is not None and known[0] == dg and not unhashed and all(f.name in kept for f in files):
                fits[robot, day] = known[1]
            else:
                todo[robot, day] = dg
    return kept, fits, todo, digests


def _submit_files(job: tasks.Job, found: layout.Layout, stored: store.Stored, kept: set, todo: dict, choices):
    """A robot's phase-1 tasks: its files not in the store (gathered), and each day to fit: the sum of its files'
    statistics (stored ones read and sent along) and its fit (gathered)."""

    def submit(client, robot: str) -> tuple[list, list]:
        choice = choices[robot]
        gathered, others = [], []
        for day in found.days(robot):
            files = found.files_of(robot, day)
            made = {f.name: client.submit(tasks.file_stats, job, f, choice) for f in files if f.name not in kept}
            gathered += made.values()
            if (robot, day) in todo:
                read = iter(store.read_files(stored, [f for f in files if f.name in kept]))
                stats = [made[f.name] if f.name in made else next(read) for f in files]
                summed = client.submit(tasks.day_stats, *stats)
                gathered.append(client.submit(tasks.fit_day, job, summed, choice))
                others.append(summed)
        return gathered, others

    return submit


def _days_and_baselines(
    job: tasks.Job, found: layout.Layout, files: Files, K: int, stored: store.Stored, keys: dict, digests: dict
) -> tuple[list, dict, dict]:
    """On the client: per robot, its baseline model (the stored one when the files of its first days and its fit
    are as when it was stored: `keys`, robot → digest) and each day's scales (the stored ones when, besides, the
    day's files are as then: `digests`, (robot, day) → digest) (module doc, 4); and {robot: (digest, baseline)},
    {(robot, day): (digest, scales)} of those made anew."""
    out: list = []
    made: dict[str, tuple[str, tasks.Baseline]] = {}
    made_scales: dict[tuple[str, str], tuple[str, tasks.Scales | None]] = {}
    for robot in found.robots:
        days = found.days(robot)
        kept = stored.baselines.get(robot)
        if kept is not None and keys[robot] and kept[0] == keys[robot]:
            base = kept[1]
        else:
            base = tasks.baseline(job, *(files.day(found.files_of(robot, d)) for d in days[: K + SPARE_DAYS]), count=K)
            if base is not None and keys[robot]:  # "": an unreadable file among its first days, never stored
                made[robot] = (keys[robot], base)
        out.append(base)
        for day in days:
            # "" (an unhashed file, or among the baseline's): computed, never stored
            dg = store.digest(keys[robot], digests[robot, day]) if keys[robot] and digests[robot, day] else ""
            known = stored.scales.get((robot, day))
            if dg and known is not None and known[0] == dg:
                out.append(known[1])
                continue
            found_scales = tasks.scales(job, files.day(found.files_of(robot, day)), base)
            out.append(found_scales)
            if dg:
                made_scales[robot, day] = (dg, found_scales)
    return out, made, made_scales


def _baseline_keys(found: layout.Layout, hashes, choices: dict, K: int) -> dict[str, str]:
    """Per robot, a digest of what its baseline model depends on: K, its fit, the files of its first days."""
    keys = {}
    for robot in found.robots:
        first = [_files_key(found.files_of(robot, d), hashes) for d in found.days(robot)[: K + SPARE_DAYS]]
        c = choices[robot].choice
        unhashed = any(h is None for day in first for _, h in day)
        keys[robot] = "" if unhashed else store.digest(K, c.estimator, c.factor, first)
    return keys


def _store_warnings(found: layout.Layout, stored: store.Stored, hashes) -> tuple[list, list, list[ResultWarning]]:
    """(names of stored files whose bytes changed, names of stored files gone, the warnings saying so)."""
    present = {f.name for f in found.files}
    changed = [n for n in sorted(present) if n in stored.files and stored.files[n].sha256 != hashes[n]]
    gone = sorted(set(stored.files) - present)
    warnings = []
    for names, code, what in (
        (changed, "store_changed", "changed since they were stored: read again"),
        (gone, "store_gone", "stored by an earlier run, gone from --logs: dropped from the store and the series"),
    ):
        if names:
            listed = ", ".join(names[:NAMED]) + (" …" if len(names) > NAMED else "")
            warnings.append(ResultWarning(code, f"{len(names)} file(s) {what} ({listed})"))
    return changed, gone, warnings


def phase1(
    open_engine: Callable[[bool], Engine],
    job: tasks.Job,
    found: layout.Layout,
    stored: store.Stored,
    baseline_days: int,
    progress: bool,
) -> Phase1:
    """Phase 1 with the store (module doc), on the engine `open_engine(small)` opens (`small`: `SMALL_RUN`)."""
    hashes, stamps = content_hashes(found, stored)
    known, judged = _known(job, found, stored, hashes, baseline_days)
    small = bool(stored.files) and _to_read(found, stored, hashes, known) <= SMALL_RUN  # a day added, say
    with open_engine(small) as engine:
        engine.check(tasks.ready, job.problem)
        start = time.perf_counter()
        choices, new_choices = _choose(engine, job, found, known, judged, baseline_days, progress)
        kept, fits, todo, digests = _plan(found, stored, hashes, choices)
        total = len(found.files) - len(kept) + 2 * len(todo)
        submit = _submit_files(job, found, stored, kept, todo, choices)
        made = engine.run(found.robots, submit, total, progress, "fleet: statistics and fits")
        engine_seconds = time.perf_counter() - start
        cluster = (engine.workers, engine.address)
    new_files = {m.file.name: m for m in made if isinstance(m, tasks.FileStats)}
    new_fits = {(m.robot, m.day): m for m in made if isinstance(m, tasks.DayFit)}
    files = Files(stored, new_files)
    changed, gone, warnings = _store_warnings(found, stored, hashes)
    keys = _baseline_keys(found, hashes, choices, baseline_days)
    gathered, baselines, scales = _days_and_baselines(job, found, files, baseline_days, stored, keys, digests)
    update = store.Update(
        files={n: (hashes[n], stamps[n], choices[r.file.robot].choice, r) for n, r in new_files.items() if hashes[n]},
        gone=gone,
        gone_days=sorted(set(stored.fits) - {(r, d) for r in found.robots for d in found.days(r)}),
        choices=new_choices,
        fits={key: (todo[key], fit) for key, fit in new_fits.items()},
        baselines=baselines,
        scales=scales,
        stamps={n: stamps[n] for n in kept if stamps[n] != stored.files[n].stamp},
    )
    counts = {"files_new": len(new_files), "files_cached": len(kept), "files_changed": len(changed)}
    counts["files_gone"] = len(gone)
    gathered += [*choices.values(), *fits.values(), *new_fits.values()]
    samples_read = sum(f.samples for f in new_files.values())
    return Phase1(gathered, files, update, counts, samples_read, engine_seconds, cluster, warnings)
