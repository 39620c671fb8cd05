"""The fleet layout (`docs/data-format.md`, "Many robots"): ROOT/robot=<id>/day=<YYYY-MM-DD>/<name>.parquet|csv|csv.gz,
found and checked before any work.

ROOT is a local folder or any URL the installed filesystem libraries read (fsspec: `file://`, `s3://` with s3fs,
…). Names that start with "." or "_" are skipped at every level (hidden files, Hive's `_SUCCESS`, a simulated
fleet's `_truth.json`). The two folder levels are the layout: anything else there (a file beside the robot
folders, a folder that is not `robot=<id>` or `day=<date>`) is an `InputError` naming it. Inside a day folder a
file of another type, or a folder, is listed as skipped with its reason and the run goes on; a robot or a day
folder with nothing to read is a warning.

Symbolic links are never followed, at any level, wherever they point (inside ROOT or out of it): a robot folder, a
day folder or a trial file that is a link is listed as skipped (`LINK`, a reason that names the entry only: neither
its target nor anything in it is read or shown), and a worker checks again when it opens a file (`linked`: a link
put in after the layout was found is not followed either). The fleet reads only what lies inside ROOT (ROOT itself
may be reached through a link), so that `--logs` cannot be made to read and echo a file from elsewhere (a
credentials file linked into a day folder), and no trial is counted twice. Logs spread over several disks are
given as one ROOT of real folders (a bind mount, or a copy).
"""

from __future__ import annotations

import contextlib
import datetime
import hashlib
import os
import re
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path, PurePosixPath

import fsspec
from fsspec.implementations.local import LocalFileSystem

from ident_opt.errors import InputError
from ident_opt.warnings import ResultWarning

#: The trial files a day folder may hold (the loader's types that a logger writes).
SUFFIXES = (".parquet", ".csv", ".csv.gz")
#: A robot's id: letters, digits and . _ - (it names files of the report).
ROBOT_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
#: A robot's id names its figure as is up to this many characters; a longer one (up to 249 in a folder name
#: `robot=<id>` of 255 bytes) by its first `STEM_KEEP` characters and a hash (`file_stem`): the figure's name, and the
#: temporary name it is written under (about 30 characters more), must stay within a file name's 255 bytes.
MAX_STEM, STEM_KEEP = 120, 100
#: A day: an ISO date.
DAY = re.compile(r"\d{4}-\d{2}-\d{2}")
#: Why an entry that is a symbolic link is skipped (module doc): its target is neither read nor named.
LINK = "a symbolic link: not followed (the fleet reads only files inside --logs; the link's target is not read)"
#: Why a file whose name is not printable UTF-8 text is skipped (shown with escapes, `shown`).
UNNAMED = "a name that is not printable UTF-8 text (shown with escapes): not read; rename it"


@dataclass(frozen=True)
class FleetFile:
    """One trial of the fleet: its robot, its day (ISO date), what a worker opens (`url`: a local path or a URL)
    and its name relative to ROOT (`robot=R03/day=2026-03-09/a.parquet`, in every output)."""

    robot: str
    day: str
    url: str
    name: str


@dataclass
class Layout:
    """A fleet found under `root`: its trial files (robot, day, name order), the robots that have some, the entries
    skipped (`{"file", "reason"}`) and the warnings (a robot or day folder with nothing to read)."""

    root: str
    files: list[FleetFile]
    skipped: list[dict] = field(default_factory=list)
    warnings: list[ResultWarning] = field(default_factory=list)

    @cached_property
    def index(self) -> dict[str, dict[str, list[FleetFile]]]:
        """robot → day → its trial files, robots and days sorted (built once, when the layout is complete)."""
        out: dict[str, dict[str, list[FleetFile]]] = {}
        for f in sorted(self.files, key=lambda f: (f.robot, f.day, f.name)):
            out.setdefault(f.robot, {}).setdefault(f.day, []).append(f)
        return out

    @property
    def robots(self) -> list[str]:
        """The robots with at least one trial file, sorted."""
        return list(self.index)

    def days(self, robot: str) -> list[str]:
        """The days of `robot` with at least one trial file, in date order."""
        return list(self.index.get(robot, {}))

    def files_of(self, robot: str, day: str) -> list[FleetFile]:
        """The trial files of `robot` on `day`, by name."""
        return self.index.get(robot, {}).get(day, [])


def file_stem(robot: str) -> str:
    """What names a robot's files in the report (its figure): its id when at most `MAX_STEM` characters, else its
    first `STEM_KEEP` and 12 hexadecimal digits of the id's SHA-256 (two long ids that share their start still get
    two files); the id itself is kept whole in the data (JSON, series, fleet.md)."""
    if len(robot) <= MAX_STEM:
        return robot
    return f"{robot[:STEM_KEEP]}-{hashlib.sha256(robot.encode()).hexdigest()[:12]}"


def shown(name: str) -> str:
    """A name as every report shows it: bytes that are not UTF-8 (a name the filesystem gave as surrogate escapes)
    and control characters as backslash escapes (`\\xff`, `\\n`), so that it can be written to any file or
    terminal and cannot break a line or a table."""
    text = name.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text)


def _entries(fs, path: str, where: str) -> list[tuple[str, str, bool, bool, str]]:
    """(name, full path, is a folder, is a symbolic link, fsspec's type: "file", "directory" or "other" for a
    FIFO, socket or device) of what `path` holds, hidden names left out, by name (a
    link is never a folder here: it is not followed)."""
    try:
        listing = fs.ls(path, detail=True)
    except (OSError, ValueError) as exc:
        raise InputError(f"{where}: cannot list the folder ({exc})") from None
    out = []
    for entry in listing:
        full = entry["name"].rstrip("/")
        name = PurePosixPath(full).name
        if name and not name.startswith((".", "_")):
            link = bool(entry.get("islink", False))
            out.append((name, full, entry["type"] == "directory" and not link, link, entry["type"]))
    return sorted(out)


def _key(name: str, key: str, pattern: re.Pattern, where: str, hint: str) -> str:
    """The value of a `key=value` folder name, or an InputError naming the folder and the layout."""
    prefix = f"{key}="
    value = name[len(prefix) :] if name.startswith(prefix) else None
    if value is None or not pattern.fullmatch(value):
        raise InputError(f"{where}: not in the fleet layout ROOT/robot=<id>/day=<YYYY-MM-DD>/<file>: {hint}")
    return value


class _Urls:
    """What a worker opens for each entry found under the root (`FleetFile.url`): its local path, or the root's URL
    with the entry's path below the root put where the URL carries its path. In a plain URL that is its end
    (`memory://fleet/robot=R01/…`, `simplecache::file:///logs/robot=R01/…`); in a chained one it may be another
    part (`zip://robot=R01/…::/data/fleet.zip`: the path inside the archive, not after the archive's own). Each
    part is tried on the first file, the end first, and kept if the URL it makes names that file on the same kind
    of filesystem; none does: an InputError naming the root."""

    def __init__(self, fs, root_url: str, root_path: str):
        self.fs, self.root_url, self.root_path = fs, root_url, root_path
        self.part: int | None = None  # which "::" part of the root URL takes the path (found on the first file)

    def __call__(self, full: str) -> str:
        if isinstance(self.fs, LocalFileSystem):
            return full
        root, path = self.root_path.strip("/"), full.strip("/")
        tail = path[len(root) + 1 :] if root else path  # the entry's path below the root
        if self.part is None:
            self.part = self._find(path, tail)
        return _with_tail(self.root_url, self.part, tail)

    def _find(self, path: str, tail: str) -> int:
        """The part of the root URL that takes a path below it: the first that names `path` again (class doc)."""
        count = len(self.root_url.split("::"))
        for part in (count - 1, *range(count - 1)):
            try:
                fs, found = fsspec.core.url_to_fs(_with_tail(self.root_url, part, tail))
            except (ValueError, ImportError, OSError):
                continue
            if type(fs) is type(self.fs) and found.strip("/") == path:
                return part
        raise InputError(
            f"--logs {self.root_url}: cannot name the files under this URL for the workers (no part of it takes a "
            f"path below the root: {tail} tried in each); give the root in a plain form, e.g. "
            "zip://::/path/to/fleet.zip or the unpacked folder"
        )


def _with_tail(url: str, part: int, tail: str) -> str:
    """`url` with `tail` appended to the path of its "::" part number `part`."""
    parts = url.split("::")
    text = parts[part]
    if "://" in text:
        protocol, path = text.split("://", 1)
        path = path.rstrip("/") + "/" if path.strip("/") else path  # "zip://" → "zip://tail", "file:///" kept
        parts[part] = f"{protocol}://{path}{tail}"
    elif "/" not in text and text in fsspec.available_protocols():  # a bare protocol: "zip::/data/fleet.zip"
        parts[part] = f"{text}://{tail}"
    else:  # a plain path
        parts[part] = text.rstrip("/") + "/" + tail
    return "::".join(parts)


def _local(url: str) -> str | None:
    """The path on this machine's filesystem that `url` names (also behind a cache such as `simplecache::`), or None
    for a URL elsewhere or that cannot be opened."""
    try:
        fs, path = fsspec.core.url_to_fs(str(url))
    except (ValueError, ImportError, OSError):
        return None
    while not isinstance(fs, LocalFileSystem) and isinstance(getattr(fs, "fs", None), fsspec.AbstractFileSystem):
        fs = fs.fs  # a cache over another filesystem: the paths are the wrapped one's
    return path if isinstance(fs, LocalFileSystem) else None


def local_root(root: str) -> Path | None:
    """The local folder the fleet's root `root` names, as `discover` reads it (a path, relative or with `~`, or a
    `file://`/`local://` URL, also behind a cache such as `simplecache::`), absolute; None for a root that is not on
    this machine's filesystem (`memory://`, `s3://`, …) or that cannot be opened (`discover` says why)."""
    path = _local(root)
    return None if path is None else Path(path)


def linked(file: FleetFile) -> bool:
    """Whether the local trial file `file`, or its day or robot folder, is a symbolic link now (a worker checks
    again when it opens the file, module doc); False for a file that is not on this machine's filesystem."""
    path = _local(file.url)
    if path is None or not path.endswith("/" + file.name):
        return False
    here = path[: -len(file.name) - 1]  # ROOT, as the layout found it
    for part in file.name.split("/"):
        here = f"{here}/{part}"
        if os.path.islink(here):
            return True
    return False


@contextlib.contextmanager
def local_copy(url: str) -> Iterator[Path]:
    """A local path to the file at `url`: itself when local, else a temporary copy with the same name (the loader
    reads by path and by file ending), removed afterwards."""
    fs, path = fsspec.core.url_to_fs(url)
    if isinstance(fs, LocalFileSystem):
        yield Path(path)
        return
    with tempfile.TemporaryDirectory(prefix="ident-opt-fleet-") as folder:
        local = Path(folder) / PurePosixPath(path).name
        try:
            fs.get_file(path, str(local))
        except (OSError, ValueError) as exc:
            raise InputError(f"{local}: cannot fetch {url} ({exc})") from None
        yield local


def discover(root: str) -> Layout:
    """The fleet under `root` (a local folder or a URL), checked (module doc); an InputError when `root` is not a
    folder, does not follow the layout, or holds no trial file at all."""
    try:
        fs, root_path = fsspec.core.url_to_fs(str(root))
        folder = fs.isdir(root_path)
    except (ValueError, ImportError, OSError) as exc:  # OSError: a missing archive behind zip://, say
        raise InputError(f"--logs {root}: cannot open ({type(exc).__name__}: {exc})") from None
    if not folder:
        raise InputError(f"--logs {root}: not a folder (the fleet's root holds one robot=<id> folder per robot)")
    layout = Layout(str(root), [])
    urls = _Urls(fs, str(root), root_path)
    for robot_name, robot_path, is_dir, is_link, _ in _entries(fs, root_path, str(root)):
        if is_link:
            layout.skipped.append({"file": shown(robot_name), "reason": LINK})
            continue
        hint = (
            "a robot's folder is named robot=<id> (letters, digits, . _ -); was --logs given a robot's or a day's "
            "folder instead of the fleet's root?"
        )
        if not is_dir:
            raise InputError(f"{root}/{shown(robot_name)}: a file beside the robot folders; {hint}")
        robot = _key(robot_name, "robot", ROBOT_ID, f"{root}/{shown(robot_name)}", hint)
        days = _entries(fs, robot_path, f"{root}/{robot_name}")
        if not days:
            layout.warnings.append(ResultWarning("no_logs", f"{robot_name}: no day folders; the robot is left out"))
        for day_name, day_path, day_is_dir, day_is_link, _ in days:
            where = f"{robot_name}/{shown(day_name)}"  # the robot's name is checked: letters, digits, . _ -
            if day_is_link:
                layout.skipped.append({"file": where, "reason": LINK})
                continue
            hint = "a day's folder is named day=<YYYY-MM-DD>, inside its robot's folder"
            if not day_is_dir:
                raise InputError(f"{root}/{where}: a file beside the day folders; {hint}")
            day = _key(day_name, "day", DAY, f"{root}/{where}", hint)
            try:
                datetime.date.fromisoformat(day)
            except ValueError:
                raise InputError(f"{root}/{where}: {day} is not a date (YYYY-MM-DD)") from None
            _day(fs, layout, robot, day, where, day_path, urls)
    if not layout.files:
        raise InputError(f"--logs {root}: no trial files (.parquet, .csv, .csv.gz) in the fleet layout")
    return layout


def _day(fs, layout: Layout, robot: str, day: str, where: str, day_path: str, urls: _Urls) -> None:
    """A day folder's trial files into `layout`; other entries skipped with their reason, nothing: a warning."""
    entries = _entries(fs, day_path, f"{layout.root}/{where}")
    found = 0
    for name, full, is_dir, is_link, kind in entries:
        rel = f"{where}/{shown(name)}"
        if shown(name) != name:  # the reports could not name it as it is (nor tell two such names apart)
            layout.skipped.append({"file": rel, "reason": UNNAMED})
        elif is_link:
            layout.skipped.append({"file": rel, "reason": LINK})
        elif kind not in ("file", "directory"):  # a FIFO or a device would block or never end the worker's read
            layout.skipped.append({"file": rel, "reason": "not a regular file (a named pipe, socket or device)"})
        elif is_dir:
            layout.skipped.append({"file": rel, "reason": "a folder inside a day folder (trials are files)"})
        elif not name.lower().endswith(SUFFIXES):
            layout.skipped.append({"file": rel, "reason": f"not a trial file ({', '.join(SUFFIXES)})"})
        else:
            layout.files.append(FleetFile(robot, day, urls(full), rel))
            found += 1
    if not found:
        layout.warnings.append(ResultWarning("no_logs", f"{where}: no trial file; the day is left out"))
