"""What a path may be, before anything is read from or written to it: its kind (`file_kind`: a regular file, or a
folder, a pipe, a device, a socket — never opened to find out), its length (`check_length`: NAME_MAX and PATH_MAX),
how a message shows it (`abbreviated`, `shown`) and the one-line error of a write that failed (`cannot_write`).
`ident_opt.outputs` applies them to every output and re-exports them."""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from ident_opt.errors import InputError

#: The longest file name [bytes] (NAME_MAX) and path [bytes, with its terminating NUL] (PATH_MAX) of Linux and
#: macOS's usual file systems, when `os.pathconf` cannot say (an output folder not created yet).
NAME_MAX, PATH_MAX = 255, 4096
#: Kinds of file by `stat` mode test: what a path is when it is not a regular file (`file_kind`).
_KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)
FOLDER = _KINDS[0][1]


def file_kind(path: str | Path) -> str | None:
    """What `path` names when that is not a regular file, following links ("a folder", "a named pipe (FIFO)",
    "a character device", "a block device", "a socket"); None for a regular file or nothing (a dangling link, a
    path that cannot be looked up). By `os.stat` alone: it never opens the path (opening a FIFO blocks, opening
    some devices acts on them)."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):  # missing, dangling, unreadable parent, a NUL byte in the name
        return None
    return mode_kind(mode)


def mode_kind(mode: int) -> str | None:
    """`file_kind` of a file of `st_mode` `mode` (from `os.stat` or `os.fstat`): None for a regular file."""
    if stat.S_ISREG(mode):
        return None
    return next((kind for test, kind in _KINDS if test(mode)), "not a regular file")


def refuse_special(path: str | Path, flag: str | None = None) -> None:
    """InputError (naming `flag` and the path) when `path` exists and is neither a regular file nor a folder: a
    device, a named pipe or a socket, or a link to one. An output is written beside and renamed into place, which
    would replace the device node itself (as root: /dev/null, /dev/full) with a regular file."""
    kind = file_kind(path)
    if kind is None or kind == FOLDER:
        return
    label = f"{flag} {path}" if flag else str(path)
    link = f" (through a link to {os.path.realpath(path)})" if Path(path).is_symlink() else ""
    raise InputError(
        f"{label}: exists and is {kind}{link}, not a regular file; ident-opt writes outputs only as regular files "
        "and never replaces a device, pipe or socket: give another path"
    )


def _limit(path: Path, name: str, default: int) -> int:
    """`os.pathconf` value `name` of the nearest existing folder of `path`, else `default`."""
    for folder in [path, *path.parents]:
        try:
            return int(os.pathconf(folder if str(folder) else ".", name))
        except (OSError, ValueError):  # missing (yet), a name too long, not a folder
            continue
    return default


def abbreviated(path: str | Path, keep: int = 120) -> str:
    """A path as a message shows it on one line: a name beyond `keep` characters as its start, an ellipsis and its
    end; a name that is not valid UTF-8 with a replacement character where the byte was (never a surrogate escape,
    which a terminal cannot show)."""
    text = os.fsencode(os.fspath(path)).decode("utf-8", "replace")
    return text if len(text) <= 2 * keep else f"{text[:keep]}…{text[-keep:]}"


def check_length(path: str | Path, flag: str | None = None, room: int = 0, reading: bool = False) -> None:
    """InputError naming `path` (and `flag`) when no file system here can hold it: a component longer than NAME_MAX
    bytes, or an absolute path (plus `room` bytes for names to come inside it) of PATH_MAX bytes or more. The system
    calls would fail with ENAMETOOLONG only once the work is done (or half-written). `reading`: an input, which
    therefore cannot exist."""
    path = Path(path)
    label = f"{flag} {abbreviated(path)}" if flag else abbreviated(path)
    fix = "no file can have it, so it cannot be read" if reading else "give a shorter one"
    name_max = _limit(path.parent, "PC_NAME_MAX", NAME_MAX)
    for part in path.parts:
        size = len(os.fsencode(part))
        if size > name_max and part != path.anchor:
            which = "its name" if part == path.name else f"its folder {abbreviated(part, 24)!r}"
            raise InputError(
                f"{label}: {which} is {size} bytes long, and a name may have at most {name_max} bytes (NAME_MAX) "
                f"here: {fix}"
            )
    path_max = _limit(path.parent, "PC_PATH_MAX", PATH_MAX)
    size = len(os.fsencode(os.path.abspath(path)))
    if size + room >= path_max:
        extra = f", and {room} more are kept for the files written inside it" if room else ""
        raise InputError(
            f"{label}: the path is {size} bytes long{extra}; a path must have fewer than {path_max} bytes "
            f"(PATH_MAX) here: {fix}"
        )


def cannot_write(path: str | Path, exc: OSError) -> InputError:
    """The InputError of a write of `path` that failed with `exc` (a full disk, a quota, a name too long, …): one
    line naming the file and the reason. Whatever was written of it was removed (`atomic_path`)."""
    reason = {
        errno.ENOSPC: "no space left on the device",
        errno.EDQUOT: "the disk quota is exhausted",
        errno.EFBIG: "the file is larger than this process may write (its file size limit)",
    }.get(exc.errno, exc.strerror or type(exc).__name__)
    return InputError(f"{abbreviated(path)}: cannot write ({reason}); nothing of it was left behind")


def shown(path: str | Path) -> str:
    """A data path as people read it: relative to the working folder when inside it, else absolute."""
    resolved = Path(path).resolve()
    try:
        return os.path.relpath(resolved) if resolved.is_relative_to(Path.cwd()) else str(resolved)
    except ValueError:
        return str(resolved)
