"""The fleet's store (`--store`): what each file gave, kept between runs in one SQLite file (the standard library's
`sqlite3`: embedded, no server), so that a daily run reads only the new or changed files.

Per file: its name in the layout, robot, day, the SHA-256 of its bytes, the fit it was reduced for (estimator and
cut-off factor: the statistics depend on them), its sufficient statistics (`Stats`, and `InstrumentStats` for the
robust fit: float64 arrays as raw little-endian bytes after a JSON header of their shapes, `_pack`: read back bit
for bit, never unpickled), its samples, the loader's
notes, the skip reason. Per robot: the fit its days get (`tasks.RobotChoice`) with a digest of the files it was
judged on, and its baseline model (`tasks.Baseline`) with a digest of the files of its first days. Per robot-day:
its fit (`tasks.DayFit`) with a digest of the day's files and the choice, and its torque scales (`tasks.Scales`) with
a digest of the day's files, the choice and the baseline's files. A file's stamp (size, modification and
change times, inode) lets a run take its stored hash without reading it again (`incremental.content_hashes`).

A store belongs to one *model key* (`model_key`: the parameters, the estimator asked, the loader's switches, the
derivative cut-off setting, the problem file's SHA-256, `STORE_FORMAT`). A store written under another key is
refused (`InputError`, exit 2, naming the store and what differs): its statistics would not add up with this run's.
A run reads the small rows (hashes, choices, fits, baselines, scales) at its start and a file's statistics only
when it needs them (`read_files`: the files of the days it fits, of a baseline it makes, of a change it tests), so a
day added reads a few of the stored statistics, not all of them.

Everything a run learnt is written in one transaction at its end: an interrupted run leaves the store as it was.
A store is not rolled back with a failed command's reports (what it holds stays true of its files); a store the
failed run would have created is removed with them.
"""

from __future__ import annotations

import hashlib
import json
import sqlite3
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ident_opt import outputs
from ident_opt.errors import InputError
from ident_opt.fitting import recommend
from ident_opt.fitting.iv import InstrumentStats
from ident_opt.fitting.stats import Stats
from ident_opt.fleet import tasks
from ident_opt.fleet.layout import FleetFile
from ident_opt.paths import refuse_special
from ident_opt.warnings import ResultWarning

#: The version of what the store holds (tables and the statistics' encoding): a store of another is refused.
STORE_FORMAT = 1
#: The default store's name in the output folder.
DEFAULT_NAME = "fleet.db"
#: The URL form of a store: `sqlite:///relative/path.db` or `sqlite:////absolute/path.db` (SQLAlchemy's).
SQLITE_URL = "sqlite:///"

SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS files (
    name TEXT PRIMARY KEY, robot TEXT NOT NULL, day TEXT NOT NULL, sha256 TEXT NOT NULL, stamp TEXT,
    estimator TEXT NOT NULL, factor REAL NOT NULL, meta TEXT NOT NULL, arrays BLOB);
CREATE TABLE IF NOT EXISTS choices (robot TEXT PRIMARY KEY, judged TEXT NOT NULL, meta TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS fits (
    robot TEXT NOT NULL, day TEXT NOT NULL, digest TEXT NOT NULL, meta TEXT NOT NULL, arrays BLOB NOT NULL,
    PRIMARY KEY (robot, day));
CREATE TABLE IF NOT EXISTS baselines (
    robot TEXT PRIMARY KEY, digest TEXT NOT NULL, meta TEXT NOT NULL, arrays BLOB NOT NULL);
CREATE TABLE IF NOT EXISTS scales (
    robot TEXT NOT NULL, day TEXT NOT NULL, digest TEXT NOT NULL, arrays BLOB, PRIMARY KEY (robot, day));
"""


@dataclass(frozen=True)
class StoreLocation:
    """Where a run's store lives: a local file (`path`), or nowhere (None: a store in memory, forgotten after the
    run), and how the user gave it (`given`, for messages)."""

    path: Path | None
    given: str


def location(value: str | Path | StoreLocation | None) -> StoreLocation:
    """The store `value` names: a path, a `sqlite:///path` URL, or None (in memory); another URL is an
    InputError."""
    if isinstance(value, StoreLocation):
        return value
    if value is None:
        return StoreLocation(None, "(in memory)")
    text = str(value)
    if text.startswith(SQLITE_URL):
        path = text[len(SQLITE_URL) :]
    elif "://" in text:
        raise InputError(f"--store {text}: a store is a local SQLite file, given as a path or sqlite:///path")
    else:
        path = text
    if not path:
        raise InputError(f"--store {text}: no file named")
    return StoreLocation(Path(path).expanduser(), text)


def model_key(setup: tasks.Setup, job: tasks.Job) -> dict:
    """What every stored statistic depends on besides its file's bytes (module doc)."""
    problem = Path(job.problem)
    return {
        "format": STORE_FORMAT,
        "parameters": list(setup.model.names),
        "tested": list(setup.tested),
        "joints": list(setup.robot.joint_names),
        "estimator": job.estimator or "recommended per robot",
        "allow_implausible": job.allow_implausible,
        "drop_invalid": job.drop_invalid,
        "derivative_cutoff_hz": setup.problem.data.derivative_cutoff_hz,
        "problem_sha256": hashlib.sha256(problem.read_bytes()).hexdigest(),
    }


def digest(*parts: object) -> str:
    """A SHA-256 of `parts` written as JSON: the key of a choice (the files judged) or of a day's fit."""
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()


# ---------------------------------------------------------------------------------------------- encoding
def _pack(arrays: dict[str, np.ndarray]) -> bytes:
    """Named float64 arrays as bytes: a JSON header of names and shapes, a newline, then each array's little-endian
    bytes in turn (read back bit for bit, and as data only: nothing in a store is ever unpickled or run)."""
    shapes = [[name, list(a.shape)] for name, a in arrays.items()]
    body = b"".join(np.ascontiguousarray(a, dtype="<f8").tobytes() for a in arrays.values())
    return json.dumps(shapes).encode() + b"\n" + body


def _unpack(blob: bytes) -> dict[str, np.ndarray]:
    """The arrays `_pack` wrote."""
    head, _, body = blob.partition(b"\n")
    out, start = {}, 0
    for name, shape in json.loads(head):
        size = int(np.prod(shape, dtype=int))
        out[name] = np.frombuffer(body, dtype="<f8", count=size, offset=8 * start).reshape(shape).astype(float)
        start += size
    return out


def _put_stats(stats: Stats | InstrumentStats, prefix: str, arrays: dict, meta: dict) -> None:
    """`stats` into `arrays` (float64, by name under `prefix`) and `meta` (counts)."""
    if isinstance(stats, InstrumentStats):
        arrays.update({f"{prefix}A": stats.A, f"{prefix}c": stats.c, f"{prefix}K": stats.K})
        _put_stats(stats.stats, f"{prefix}stats.", arrays, meta)
        meta[f"{prefix}probes"] = sorted(stats.probes)
        for name, probe in stats.probes.items():
            _put_stats(probe, f"{prefix}probe.{name}.", arrays, meta)
        return
    arrays.update({f"{prefix}G": stats.G, f"{prefix}b": stats.b, f"{prefix}s": stats.s})
    meta[f"{prefix}n"], meta[f"{prefix}effective"] = int(stats.n), stats.effective


def _get_stats(prefix: str, arrays: dict, meta: dict, instruments: bool) -> Stats | InstrumentStats:
    """What `_put_stats` wrote under `prefix`."""
    if instruments:
        plain = _get_stats(f"{prefix}stats.", arrays, meta, False)
        probes = {name: _get_stats(f"{prefix}probe.{name}.", arrays, meta, True) for name in meta[f"{prefix}probes"]}
        return InstrumentStats(arrays[f"{prefix}A"], arrays[f"{prefix}c"], arrays[f"{prefix}K"], plain, probes)
    G, b, s = (arrays[f"{prefix}{k}"] for k in "Gbs")
    return Stats(G, b, s, meta[f"{prefix}n"], meta[f"{prefix}effective"])


def encode_file(result: tasks.FileStats) -> tuple[str, bytes | None]:
    """A file's result as (JSON, arrays): samples, reason, CPU seconds, notes, and its statistics."""
    meta = {"samples": result.samples, "reason": result.reason, "cpu": result.cpu, "notes": result.notes}
    if result.stats is None:
        return json.dumps(meta), None
    arrays: dict[str, np.ndarray] = {}
    meta["instruments"] = result.instruments is not None
    _put_stats(result.instruments if result.instruments is not None else result.stats, "", arrays, meta)
    return json.dumps(meta), _pack(arrays)


def decode_file(file: FleetFile, meta_text: str, blob: bytes | None) -> tasks.FileStats:
    """The `tasks.FileStats` `encode_file` wrote, for `file` as this run's layout names it."""
    meta = json.loads(meta_text)
    out = tasks.FileStats(file, None, meta["samples"], meta["reason"], meta["cpu"], notes=meta["notes"])
    if blob is None:
        return out
    found = _get_stats("", _unpack(blob), meta, meta["instruments"])
    if isinstance(found, InstrumentStats):
        out.stats, out.instruments = found.stats, found
    else:
        out.stats = found
    return out


def _encode_choice(choice: tasks.RobotChoice) -> str:
    c = choice.choice
    warnings = [w.as_dict() for w in choice.warnings]
    return json.dumps({"estimator": c.estimator, "why": c.why, "factor": c.factor, "warnings": warnings,
                       "day": choice.day, "cpu": choice.cpu})  # fmt: skip


def _decode_choice(robot: str, text: str) -> tasks.RobotChoice:
    m = json.loads(text)
    warnings = [ResultWarning(**w) for w in m["warnings"]]
    choice = recommend.Choice(m["estimator"], m["why"], m["factor"])
    return tasks.RobotChoice(robot, choice, warnings, m["day"], m["cpu"])


#: A day's fit's array fields (None when the day has no fit).
FIT_ARRAYS = ("pi", "se", "tested", "tested_se")


def _encode_fit(fit: tasks.DayFit) -> tuple[str, bytes]:
    meta = {"files": fit.files, "skipped": fit.skipped, "samples": fit.samples, "estimator": fit.estimator,
            "notes": fit.notes, "cpu": fit.cpu}  # fmt: skip
    arrays = {name: getattr(fit, name) for name in FIT_ARRAYS if getattr(fit, name) is not None}
    return json.dumps(meta), _pack(arrays)


def _decode_fit(robot: str, day: str, text: str, blob: bytes) -> tasks.DayFit:
    m = json.loads(text)
    arrays = _unpack(blob)
    fit = tasks.DayFit(robot, day, m["files"], m["skipped"], m["samples"], m["estimator"])
    fit.notes, fit.cpu = m["notes"], m["cpu"]
    for name in FIT_ARRAYS:
        setattr(fit, name, arrays.get(name))
    return fit


def _encode_baseline(base: tasks.Baseline) -> tuple[str, bytes]:
    return json.dumps({"null": base.null, "days": base.days}), _pack({"pi": base.pi, "weights": base.weights})


def _decode_baseline(robot: str, text: str, blob: bytes) -> tasks.Baseline:
    m, arrays = json.loads(text), _unpack(blob)
    return tasks.Baseline(robot, arrays["pi"], arrays["weights"], m["null"], m["days"])


def _encode_scales(found: tasks.Scales | None) -> bytes | None:
    return None if found is None else _pack({"scale": found.scale, "se": found.se})


def _decode_scales(robot: str, day: str, blob: bytes | None) -> tasks.Scales | None:
    if blob is None:
        return None
    arrays = _unpack(blob)
    return tasks.Scales(robot, day, arrays["scale"], arrays["se"])


# ---------------------------------------------------------------------------------------------- the store
@dataclass
class StoredFile:
    """A file's row without its statistics (`read_files` reads those): its hash, its stamp (size, modification and
    change times, inode: `incremental.stamp`) and the fit it was reduced for."""

    robot: str
    day: str
    sha256: str
    stamp: str | None
    estimator: str
    factor: float


@dataclass
class Stored:
    """What a store held when the run began: where it is, files by name (their rows: `read_files` reads their
    statistics), choices by robot ((judged digest, choice)), fits by (robot, day) ((digest, fit)), baselines by
    robot ((digest, baseline)), scales by (robot, day) ((digest, scales or None))."""

    where: StoreLocation
    files: dict[str, StoredFile]
    choices: dict[str, tuple[str, tasks.RobotChoice]]
    fits: dict[tuple[str, str], tuple[str, tasks.DayFit]]
    baselines: dict[str, tuple[str, tasks.Baseline]] = field(default_factory=dict)
    scales: dict[tuple[str, str], tuple[str, tasks.Scales | None]] = field(default_factory=dict)


@dataclass
class Update:
    """What a run writes back: new or recomputed files (`tasks.FileStats` by name, with their hash, stamp and the
    choice they were reduced for), the names of files gone from the layout and the robot-days gone, the choices,
    fits, baselines and scales (each with its digest) made anew, and the new stamps of files kept (touched, not
    changed)."""

    files: dict[str, tuple[str, str | None, recommend.Choice, tasks.FileStats]]
    gone: list[str]
    gone_days: list[tuple[str, str]]
    choices: dict[str, tuple[str, tasks.RobotChoice]]
    fits: dict[tuple[str, str], tuple[str, tasks.DayFit]]
    baselines: dict[str, tuple[str, tasks.Baseline]] = field(default_factory=dict)
    scales: dict[tuple[str, str], tuple[str, tasks.Scales | None]] = field(default_factory=dict)
    stamps: dict[str, str | None] = field(default_factory=dict)


def _error(where: StoreLocation, exc: BaseException) -> InputError:
    return InputError(f"--store {where.given}: cannot be used as a fleet store ({type(exc).__name__}: {exc})")


def _connect(where: StoreLocation, create: bool) -> sqlite3.Connection | None:
    """A connection to the store (autocommit: transactions are explicit), None when it does not exist and `create`
    is False."""
    if where.path is None:
        return sqlite3.connect(":memory:", isolation_level=None)
    if where.path.is_dir():
        raise InputError(f"--store {where.given}: is a folder; a store is one file")
    refuse_special(where.path, "--store")  # a named pipe would block the open
    if not where.path.exists():
        if not create:
            return None
        where.path.parent.mkdir(parents=True, exist_ok=True)
    try:
        return sqlite3.connect(where.path, isolation_level=None)
    except sqlite3.Error as exc:
        raise _error(where, exc) from None


def read(where: StoreLocation, key: dict) -> Stored:
    """What the store at `where` holds (nothing for a missing or in-memory store), checked against this run's model
    `key` (a store of another model: an InputError naming what differs)."""
    empty = Stored(where, {}, {}, {})
    con = _connect(where, create=False)
    if con is None or where.path is None:
        return empty
    try:
        tables = {row[0] for row in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        if not tables:
            return empty  # an empty file: a store not yet written
        if "meta" not in tables:
            raise InputError(f"--store {where.given}: an SQLite file, but not a fleet store (no meta table)")
        meta = dict(con.execute("SELECT key, value FROM meta"))
        _check_key(where, json.loads(meta.get("model_key", "{}")), key)
        return _load(con, where, tables)
    except (sqlite3.Error, ValueError, KeyError, TypeError) as exc:  # ValueError: a damaged record (JSON, arrays)
        raise _error(where, exc) from None
    finally:
        con.close()


def _check_key(where: StoreLocation, stored: dict, key: dict) -> None:
    """Refuse a store written under another model key, naming each difference."""
    differ = [name for name in sorted(set(stored) | set(key)) if stored.get(name) != key.get(name)]
    if differ:
        shown = "; ".join(f"{name}: stored {stored.get(name)!r}, now {key.get(name)!r}" for name in differ[:4])
        raise InputError(
            f"--store {where.given}: written for another model ({shown}); its statistics do not add up with this "
            "run's. Give another --store, or delete this one to start afresh"
        )


def _load(con: sqlite3.Connection, where: StoreLocation, tables: set[str]) -> Stored:
    """Every row but the files' statistics (module doc)."""
    files = {
        row[0]: StoredFile(*row[1:])
        for row in con.execute("SELECT name, robot, day, sha256, stamp, estimator, factor FROM files")
    }
    choices = {r: (judged, _decode_choice(r, m)) for r, judged, m in con.execute("SELECT * FROM choices")}
    fits = {(r, d): (dg, _decode_fit(r, d, m, a)) for r, d, dg, m, a in con.execute("SELECT * FROM fits")}
    rows = con.execute("SELECT * FROM baselines")
    baselines = {r: (dg, _decode_baseline(r, m, a)) for r, dg, m, a in rows}
    scales = {}
    if "scales" in tables:  # a store written before scales were kept: they are computed and stored this time
        rows = con.execute("SELECT robot, day, digest, arrays FROM scales")
        scales = {(r, d): (dg, _decode_scales(r, d, a)) for r, d, dg, a in rows}
    return Stored(where, files, choices, fits, baselines, scales)


#: `read_files` asks for at most this many files per query (SQLite's limit on a statement's parameters is 32766).
QUERY_FILES = 500


def read_files(stored: Stored, files: list[FleetFile]) -> list[tasks.FileStats]:
    """The stored statistics of `files` (each a file the store holds, with the hash `stored` read at the run's
    start), in their order. A row whose hash moved since (another run wrote the store meanwhile) is an InputError:
    what this run planned on is gone."""
    con = _connect(stored.where, create=False) if files else None
    if con is None:
        if files:
            raise InputError(f"--store {stored.where.given}: removed while this run read it")
        return []
    rows: dict[str, tuple[str, str, bytes | None]] = {}
    try:
        names = [f.name for f in files]
        for start in range(0, len(names), QUERY_FILES):
            part = names[start : start + QUERY_FILES]
            marks = ", ".join("?" * len(part))
            query = f"SELECT name, sha256, meta, arrays FROM files WHERE name IN ({marks})"
            rows.update((name, rest) for name, *rest in con.execute(query, part))
        moved = [f.name for f in files if f.name not in rows or rows[f.name][0] != stored.files[f.name].sha256]
        if moved:
            raise InputError(
                f"--store {stored.where.given}: written by another run while this one read it ({moved[0]}); run again"
            )
        return [decode_file(f, rows[f.name][1], rows[f.name][2]) for f in files]
    except (sqlite3.Error, ValueError, KeyError, TypeError) as exc:
        raise _error(stored.where, exc) from None
    finally:
        con.close()


def write(where: StoreLocation, key: dict, update: Update) -> None:
    """`update` into the store at `where` in one transaction (nothing for an in-memory store): all of it, or, when
    anything fails or the run is interrupted, none of it."""
    if where.path is None:
        return
    run = outputs.current()
    if run is not None and not where.path.exists():  # a new store goes with a failed run's other outputs
        run.before_write(where.path)
    con = _connect(where, create=True)
    try:
        con.execute("BEGIN IMMEDIATE")  # one writer at a time; the whole update or nothing
        try:
            _write(con, key, update)
        except BaseException:
            con.execute("ROLLBACK")
            raise
        con.execute("COMMIT")
    except sqlite3.Error as exc:
        raise _error(where, exc) from None
    finally:
        con.close()


def _write(con: sqlite3.Connection, key: dict, update: Update) -> None:
    for statement in SCHEMA.split(";"):  # not `executescript`: it would commit the open transaction first
        if statement.strip():
            con.execute(statement)
    con.execute("INSERT OR REPLACE INTO meta VALUES ('model_key', ?)", (json.dumps(key, sort_keys=True),))
    con.executemany("DELETE FROM files WHERE name = ?", [(name,) for name in update.gone])
    con.executemany("DELETE FROM fits WHERE robot = ? AND day = ?", update.gone_days)
    con.executemany("DELETE FROM scales WHERE robot = ? AND day = ?", update.gone_days)
    for name, (sha, stamp, choice, result) in update.files.items():
        text, blob = encode_file(result)
        row = (name, result.file.robot, result.file.day, sha, stamp, choice.estimator, choice.factor, text, blob)
        con.execute("INSERT OR REPLACE INTO files VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)", row)
    con.executemany("UPDATE files SET stamp = ? WHERE name = ?", [(v, k) for k, v in update.stamps.items()])
    for robot, (judged, choice) in update.choices.items():
        con.execute("INSERT OR REPLACE INTO choices VALUES (?, ?, ?)", (robot, judged, _encode_choice(choice)))
    for (robot, day), (dg, fit) in update.fits.items():
        text, blob = _encode_fit(fit)
        con.execute("INSERT OR REPLACE INTO fits VALUES (?, ?, ?, ?, ?)", (robot, day, dg, text, blob))
    for robot, (dg, base) in update.baselines.items():
        text, blob = _encode_baseline(base)
        con.execute("INSERT OR REPLACE INTO baselines VALUES (?, ?, ?, ?)", (robot, dg, text, blob))
    for (robot, day), (dg, found) in update.scales.items():
        row = (robot, day, dg, _encode_scales(found))
        con.execute("INSERT OR REPLACE INTO scales VALUES (?, ?, ?, ?)", row)
