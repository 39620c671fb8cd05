"""The output rules of every command: outputs are checked before any work, never resolve to an input, are written
atomically (a temporary file in the same folder, renamed into place, removed on every failure) with the user's
umask, and a run that fails leaves nothing behind. An output is only ever a regular file (or a folder): an existing
device, named pipe or socket there (or a link to one) is refused, never replaced by the rename (`refuse_special`).

`cli.main` opens a `Run` around each command. Inside it, `declare_inputs` / `declare_output` refuse an output
that is an input; `write_text`, `write_bytes` and `atomic_path` write through the run, which remembers what each
write replaced; `watch_folder` notes what an output folder held before (for writers that cannot go through
`atomic_path`, e.g. a C compiler). `Run.rollback` restores replaced files and removes new ones and new folders.
Outside a run (library use) the writes are still atomic; nothing is rolled back.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from ident_opt.errors import InputError
from ident_opt.paths import (  # noqa: F401  (re-exported: every output is checked with a path's rules)
    FOLDER,
    NAME_MAX,
    PATH_MAX,
    abbreviated,
    cannot_write,
    check_length,
    file_kind,
    mode_kind,
    refuse_special,
    shown,
)

#: How deep `watch_folder` looks for files a failed run created (results/, results/figures, results/.manifest).
WATCH_DEPTH = 2
#: Bytes left free below PATH_MAX in an output folder's path for the names a command writes inside it (e.g.
#: figures/identify_torque_joint1.png) and the temporary name each is written under first.
FOLDER_ROOM = 128
#: At most this many bytes of a file's own name go into the temporary and backup names beside it (`_temp_name`):
#: ".<name>.<8 random>.tmp<suffix>" must itself stay within NAME_MAX.
TEMP_STEM = 96


def _temp_name(path: Path, kind: str) -> tuple[str, str]:
    """(prefix, suffix) of a temporary (`kind` "tmp") or backup ("bak") file beside `path`: its name cut to
    `TEMP_STEM` bytes, so that the temporary name fits NAME_MAX whenever the name itself does. A temporary file
    keeps the suffix when short (a writer may choose its format by it); a backup ends in .bak alone (a reader of
    the folder's *.json, e.g. the reports' index, must not take it for one)."""
    stem = os.fsdecode(os.fsencode(path.name)[:TEMP_STEM])
    suffix = path.suffix if kind == "tmp" and len(os.fsencode(path.suffix)) <= 16 else ""
    return f".{stem}.", f".{kind}{suffix}"


def umask() -> int:
    """The process's umask (read by setting it and putting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _key(path: str | Path) -> str:
    return os.path.realpath(os.fspath(path))


def _same(a: str | Path, b: str | Path) -> bool:
    """Whether two paths name the same file (also through links); a missing path is only itself."""
    if _key(a) == _key(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


class Run:
    """One command's outputs: the inputs they must not be, the files written (and what each replaced), the
    folders created and the folders watched."""

    def __init__(self) -> None:
        self.inputs: list[Path] = []
        self.outputs: list[Path] = []
        self.folders: list[Path] = []  # output folders (--out)
        self.backups: dict[str, Path | None] = {}  # written path -> backup of its old content (None: was new)
        self.created: list[Path] = []
        self.watched: dict[str, set[str]] = {}

    def declare_inputs(self, paths: Iterable[str | Path]) -> None:
        """Note input files (or folders: a ROS 2 bag, every file inside it an input); an output already declared
        that is one of them, or an output folder inside an input folder, is refused."""
        for path in paths:
            path = Path(path)
            for out in [*self.outputs, *self.folders]:
                _refuse(out, path)
            self.inputs.append(path)

    def declare_output(self, path: str | Path) -> None:
        """Note an output file; refused when it resolves to an input."""
        path = Path(path)
        for inp in self.inputs:
            _refuse(path, inp)
        self.outputs.append(path)

    def declare_folder(self, path: str | Path) -> None:
        """Note an output folder; refused when it is an input folder or inside one (a ROS 2 bag)."""
        path = Path(path)
        for inp in self.inputs:
            _refuse(path, inp)
        self.folders.append(path)

    def before_write(self, path: Path) -> None:
        """Refuse a write over an input or a device, pipe or socket (`refuse_special`); keep what `path` holds
        now (once) so a rollback can restore it."""
        for inp in self.inputs:
            _refuse(path, inp)
        refuse_special(path)
        key = _key(path)
        if key in self.backups:
            return
        self._mkdirs(path.parent)
        backup = None
        if path.is_file():
            prefix, suffix = _temp_name(path, "bak")
            try:
                fd, name = tempfile.mkstemp(dir=path.parent, prefix=prefix, suffix=suffix)
                os.close(fd)
                backup = Path(name)
                shutil.copy2(path, backup)
            except OSError as exc:  # a full disk: the old content cannot be kept, so it is not replaced
                if backup is not None:
                    backup.unlink(missing_ok=True)
                raise cannot_write(path, exc) from None
        self.backups[key] = backup

    def _mkdirs(self, folder: Path) -> None:
        missing = []
        for parent in [folder, *folder.parents]:
            if parent.exists():
                break
            missing.append(parent)
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(f"{folder}: cannot create the output folder ({exc.strerror})") from None
        self.created.extend(reversed(missing))

    def watch_folder(self, folder: Path) -> None:
        """Note the files `folder` holds now (to `WATCH_DEPTH`) and create it if needed."""
        self._mkdirs(folder)
        self.watched.setdefault(_key(folder), set(_files(folder)))

    def commit(self) -> None:
        """The run succeeded: drop the backups."""
        for backup in self.backups.values():
            if backup is not None:
                backup.unlink(missing_ok=True)
        self.backups.clear()

    def rollback(self) -> None:
        """The run failed: put back what was replaced, remove what is new (files, then empty new folders)."""
        for key, backup in self.backups.items():
            with contextlib.suppress(OSError):
                if backup is None:
                    Path(key).unlink(missing_ok=True)
                else:
                    os.replace(backup, key)
        for folder, before in self.watched.items():
            for name in set(_files(Path(folder))) - before:
                with contextlib.suppress(OSError):
                    Path(name).unlink()
        for folder in sorted(self.created, key=lambda p: len(p.parts), reverse=True):
            with contextlib.suppress(OSError):
                for sub in sorted(folder.rglob("*"), key=lambda p: len(p.parts), reverse=True):
                    if sub.is_dir():
                        sub.rmdir()  # empty folders only (e.g. figures/, .manifest/)
                folder.rmdir()
        self.backups.clear()


def _files(folder: Path, depth: int = WATCH_DEPTH) -> Iterator[str]:
    """Every file in `folder` down to `depth` levels, by real path."""
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return
    for entry in entries:
        if entry.is_dir(follow_symlinks=False):
            if depth > 1:
                yield from _files(Path(entry.path), depth - 1)
        else:
            yield _key(entry.path)


def _inside(path: Path, folder: Path) -> bool:
    """Whether `path` is in the (existing) folder `folder` or one of its subfolders, also through links."""
    try:
        return folder.is_dir() and same_or_inside(path, folder)
    except OSError:  # a name too long to exist (a URDF's mesh, say): no folder, nothing inside it
        return False


def same_or_inside(path: str | Path, target: str | Path) -> bool:
    """Whether `path` names `target` or a path inside it (resolved, whether or not either exists yet)."""
    return Path(_key(path)).is_relative_to(_key(target))


def _refuse(output: Path, inp: Path) -> None:
    """InputError when `output` is the input `inp` or lies inside the input folder `inp`."""
    if _same(output, inp):
        raise InputError(f"{output}: this output is also an input ({inp}); inputs are never overwritten")
    if _inside(output, inp):
        raise InputError(
            f"{output}: this output is inside the input folder {inp} (a ROS 2 bag's files are its inputs); "
            "inputs are never overwritten: write it elsewhere"
        )


#: The run of the command in progress (None outside `cli.main`).
_current: Run | None = None


@contextlib.contextmanager
def run() -> Iterator[Run]:
    """A run around one command: committed when the body returns, rolled back when it raises."""
    global _current  # one command at a time per process
    previous, _current = _current, Run()
    try:
        yield _current
    except BaseException:
        _current.rollback()
        raise
    else:
        _current.commit()
    finally:
        _current = previous


def current() -> Run | None:
    """The run in progress, if any."""
    return _current


def declare_inputs(paths: Iterable[str | Path]) -> None:
    """Note input files of the current run (no-op outside one)."""
    if _current is not None:
        _current.declare_inputs(paths)


def watch_folder(folder: str | Path) -> None:
    """Note an output folder of the current run (no-op outside one)."""
    if _current is not None:
        _current.watch_folder(Path(folder))


def check_file_output(path: str | Path, flag: str) -> Path:
    """An output file path usable before any work: not a folder, nor a device, pipe or socket (or a link to one:
    `refuse_special`), its folder a folder (or creatable), writable."""
    path = Path(path)
    check_length(path, flag)  # before any look-up: os.stat of such a name raises ENAMETOOLONG
    if path.is_dir():
        raise InputError(f"{flag} {path}: is a folder; give a file name")
    refuse_special(path, flag)
    parent = _existing_parent(path.parent)
    if not parent.is_dir():
        raise InputError(f"{flag} {path}: cannot create its output folder ({parent} is not a folder)")
    if not os.access(parent, os.W_OK | os.X_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise InputError(f"{flag} {path}: not writable (the file or its output folder)")
    if _current is not None:
        _current.declare_output(path)
    return path


def check_folder_output(path: str | Path, flag: str) -> Path:
    """An output folder usable before any work: a folder or creatable, writable. Anything else already there (a
    file, a device, a pipe, a socket, or a link to one) is refused."""
    path = Path(path)
    check_length(path, flag, room=FOLDER_ROOM)
    if path.exists() and not path.is_dir():
        kind = file_kind(path) or "a regular file"
        raise InputError(f"{flag} {path}: exists and is not a folder but {kind}; cannot use it as the output folder")
    parent = _existing_parent(path)
    if not parent.is_dir():
        raise InputError(f"{flag} {path}: cannot create the output folder ({parent} is not a folder)")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{flag} {path}: the output folder is not writable")
    if _current is not None:
        _current.declare_folder(path)
    return path


def _existing_parent(path: Path) -> Path:
    path = path if str(path) else Path(".")
    for parent in [path, *path.parents]:
        if parent.exists():
            return parent
    return Path(".")


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside `path` (same suffix) to write to; renamed onto `path` when the body returns,
    removed whatever happens. The file gets the permissions the umask gives a new file. Every writer of ident-opt
    writes through here (`write_text`, `write_bytes`, the tables, the figures, the simulated trials): a device, pipe
    or socket at `path` (or a link to one) is refused (`refuse_special`), before the body and again just before the
    rename; an OS failure while writing (a full disk, a quota, a name too long) is an InputError naming `path`
    (`cannot_write`), the temporary file removed, so nothing is left half-written."""
    path = Path(path)
    check_length(path)
    if path.is_dir():
        raise InputError(f"{path}: is a folder; cannot write a file there")
    refuse_special(path)
    prefix, suffix = _temp_name(path, "tmp")
    try:
        if _current is not None:
            _current.before_write(path)
        elif not path.parent.is_dir():
            path.parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(dir=path.parent, prefix=prefix, suffix=suffix)
        os.close(fd)
    except OSError as exc:
        raise cannot_write(path, exc) from None
    tmp = Path(name)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~umask())
        refuse_special(path)  # again: the body may have run for a while
        os.replace(tmp, path)
    except OSError as exc:  # the body's writer (savefig, to_csv, …) or the rename: ENOSPC, EDQUOT, EFBIG, EIO
        raise cannot_write(path, exc) from None
    finally:
        tmp.unlink(missing_ok=True)


def write_bytes(path: str | Path, data: bytes) -> Path:
    """`data` into `path`, atomically (`atomic_path`); an OS failure is an `InputError` naming the file."""
    path = Path(path)
    with atomic_path(path) as tmp:  # an OS failure: `cannot_write`
        tmp.write_bytes(data)
    return path


def write_text(path: str | Path, text: str) -> Path:
    """`text` (UTF-8) into `path`, atomically. A file name that is not UTF-8 inside `text` (a sidecar names its
    description) is written with backslash escapes (`\\udcff`), so the file stays valid UTF-8."""
    return write_bytes(path, text.encode("utf-8", "backslashreplace"))


#: The file in a folder that lists what a command wrote there (name -> SHA-256), so that a later run knows which
#: existing files it may replace (`guard_owned`) and which are the user's.
OWNED = ".ident-opt-written.json"


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _owned(folder: Path) -> dict[str, str]:
    refuse_special(folder / OWNED)  # read below: a pipe would block, /dev/zero would fill the memory
    try:
        raw = json.loads((folder / OWNED).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return {str(k): str(v) for k, v in raw.items()} if isinstance(raw, dict) else {}


def guard_owned(folder: str | Path, names: Iterable[str], force: bool = False) -> None:
    """Before writing `names` into `folder`: refuse a name that is a folder, or an existing file that no earlier
    run wrote (or that was edited since) unless `force`; then note each for rollback (`claim`)."""
    folder = Path(folder)
    owned = _owned(folder)
    paths = [folder / name for name in names]
    for path in paths:
        if path.is_dir():
            raise InputError(f"{path}: is a folder; cannot write {path.name} there")
        refuse_special(path)  # before `_digest` reads it
        if path.exists() and not force and owned.get(path.name) != _digest(path):
            raise InputError(
                f"{path}: exists and was not written by ident-opt (or was edited since); "
                "move it away or pass --force to overwrite it"
            )
    claim(paths)


def remember_owned(folder: str | Path, names: Iterable[str]) -> None:
    """Note that `names` in `folder` were written by this run (their SHA-256, in `OWNED`)."""
    folder = Path(folder)
    owned = _owned(folder)
    owned.update({name: _digest(folder / name) for name in names if (folder / name).is_file()})
    write_text(folder / OWNED, json.dumps(owned, indent=1, sort_keys=True) + "\n")


def claim(paths: Iterable[str | Path]) -> None:
    """Files a writer of the current run is about to write in place (not through `atomic_path`): refused when
    an input, restored or removed if the run fails."""
    if _current is not None:
        for path in paths:
            _current.before_write(Path(path))
