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

import datetime
import os
import re
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
#: A day: an ISO date.
DAY = re.compile(r"\d{4}-\d{2}-\d{2}")
#: Why an entry that is a symbolic link is skipped (module doc): its target is neither read nor named.
LINK = "a symbolic link: not followed (the fleet reads only files inside --logs; the link's target is not read)"


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


def _entries(fs, path: str, shown: str) -> list[tuple[str, str, bool, bool, str]]:
    """(name, full path, is a folder, is a symbolic link, fsspec's type: "file", "directory" or "other" for a
    FIFO, socket or device) of what `path` holds, hidden names left out, by name (a
    link is never a folder here: it is not followed)."""
    try:
        listing = fs.ls(path, detail=True)
    except (OSError, ValueError) as exc:
        raise InputError(f"{shown}: cannot list the folder ({exc})") from None
    out = []
    for entry in listing:
        full = entry["name"].rstrip("/")
        name = PurePosixPath(full).name
        if name and not name.startswith((".", "_")):
            link = bool(entry.get("islink", False))
            out.append((name, full, entry["type"] == "directory" and not link, link, entry["type"]))
    return sorted(out)


def _key(name: str, key: str, pattern: re.Pattern, shown: str, hint: str) -> str:
    """The value of a `key=value` folder name, or an InputError naming the folder and the layout."""
    prefix = f"{key}="
    value = name[len(prefix) :] if name.startswith(prefix) else None
    if value is None or not pattern.fullmatch(value):
        raise InputError(f"{shown}: not in the fleet layout ROOT/robot=<id>/day=<YYYY-MM-DD>/<file>: {hint}")
    return value


def _url(fs, full: str, root_url: str, root_path: str) -> str:
    """What a worker opens for the entry at `full`: its local path, or the root's URL extended by its tail."""
    if isinstance(fs, LocalFileSystem):
        return full
    return root_url.rstrip("/") + "/" + full[len(root_path.rstrip("/")) + 1 :]


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


def discover(root: str) -> Layout:
    """The fleet under `root` (a local folder or a URL), checked (module doc); an InputError when `root` is not a
    folder, does not follow the layout, or holds no trial file at all."""
    try:
        fs, root_path = fsspec.core.url_to_fs(str(root))
    except (ValueError, ImportError) as exc:
        raise InputError(f"--logs {root}: cannot open ({exc})") from None
    if not fs.isdir(root_path):
        raise InputError(f"--logs {root}: not a folder (the fleet's root holds one robot=<id> folder per robot)")
    layout = Layout(str(root), [])
    for robot_name, robot_path, is_dir, is_link, _ in _entries(fs, root_path, str(root)):
        if is_link:
            layout.skipped.append({"file": robot_name, "reason": LINK})
            continue
        hint = (
            "a robot's folder is named robot=<id> (letters, digits, . _ -); was --logs given a robot's or a day's "
            "folder instead of the fleet's root?"
        )
        if not is_dir:
            raise InputError(f"{root}/{robot_name}: a file beside the robot folders; {hint}")
        robot = _key(robot_name, "robot", ROBOT_ID, f"{root}/{robot_name}", hint)
        days = _entries(fs, robot_path, f"{root}/{robot_name}")
        if not days:
            layout.warnings.append(ResultWarning("no_logs", f"{robot_name}: no day folders; the robot is left out"))
        for day_name, day_path, day_is_dir, day_is_link, _ in days:
            where = f"{robot_name}/{day_name}"
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
            _day(fs, layout, robot, day, where, day_path, root_path)
    if not layout.files:
        raise InputError(f"--logs {root}: no trial files (.parquet, .csv, .csv.gz) in the fleet layout")
    return layout


def _day(fs, layout: Layout, robot: str, day: str, where: str, day_path: str, root_path: str) -> None:
    """A day folder's trial files into `layout`; other entries skipped with their reason, nothing: a warning."""
    entries = _entries(fs, day_path, f"{layout.root}/{where}")
    found = 0
    for name, full, is_dir, is_link, kind in entries:
        rel = f"{where}/{name}"
        if is_link:
            layout.skipped.append({"file": rel, "reason": LINK})
        elif kind not in ("file", "directory"):  # a FIFO or a device would block or never end the worker's read
            layout.skipped.append({"file": rel, "reason": "not a regular file (a named pipe, socket or device)"})
        elif is_dir:
            layout.skipped.append({"file": rel, "reason": "a folder inside a day folder (trials are files)"})
        elif not name.lower().endswith(SUFFIXES):
            layout.skipped.append({"file": rel, "reason": f"not a trial file ({', '.join(SUFFIXES)})"})
        else:
            layout.files.append(FleetFile(robot, day, _url(fs, full, layout.root, root_path), rel))
            found += 1
    if not found:
        layout.warnings.append(ResultWarning("no_logs", f"{where}: no trial file; the day is left out"))
