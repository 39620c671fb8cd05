"""Where ident-opt keeps what it can rebuild: simulated trials (data) and compiled libraries (code).

**Data.** `cache_root` is `$IDENT_OPT_CACHE` when set, else `.cache` of the project holding a file (the nearest
folder above it with a `pyproject.toml`), else `.cache` next to the file. Each user of the cache keys its entries by
a hash of everything they depend on, so a stale entry is never reused. Only data goes there (simulated trials, CSV
read as numbers): a project folder may be shared or downloaded, so nothing in it is ever run.

**Code.** A compiled library is loaded into the process and runs as the user, so it is kept only in a cache this user
alone can write, never next to the inputs: `CodeCache(kind)` is the folder `kind` of `code_root()`
(`$IDENT_OPT_CACHE` when set, else `$XDG_CACHE_HOME/ident-opt`, else `~/.cache/ident-opt`):

    <root>/key                    32 random bytes (mode 0600), made on first use: the key of the records
    <root>/<kind>/lib<f>_<h>.so   a library this tool compiled (h: a hash of its C source and flags)
    <root>/records/<kind>/lib<f>_<h>.so.hmac   "hmac-sha256 <hex>": HMAC-SHA256 under the key of the name and bytes

Folders are made with mode 0700; the root and every folder below it must belong to the user and be writable by
nobody else, and files must be regular (no links followed), the user's and not writable by others. Every file is
opened relative to an open descriptor of its folder, so a folder swapped after its check is never read. A library is
read only when its record matches its bytes under the key: one the tool did not write (planted, copied from another
machine or user, half-written, tampered) has no valid record and is compiled anew, never loaded; what
is loaded is the checked bytes themselves (`cbuild.load_bytes` writes them to `scratch()`). Writes go to a
temporary name and are renamed into place, so parallel processes never see a partial file; two processes that race
to build one library at most leave a record that does not match, which the next reader rebuilds. When the root is
not trusted (another owner, writable by others) or cannot be made, this process caches in a fresh private temporary
folder instead (with a warning), removed when it exits. Outside POSIX (no owner, no descriptor-relative opens) the
code cache keeps nothing across runs.
"""

from __future__ import annotations

import atexit
import hashlib
import hmac
import os
import secrets
import shutil
import stat
import sys
import tempfile
import threading
from pathlib import Path

#: Bytes of the key that signs the records.
KEY_BYTES = 32
#: Whether this platform can check owners and open files relative to a folder without following links.
PERSISTENT = (
    os.name == "posix" and hasattr(os, "geteuid") and hasattr(os, "O_NOFOLLOW") and os.open in os.supports_dir_fd
)
_DIR = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0)
_FILE = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
_NEW = os.O_RDWR | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)


def cache_root(path: Path) -> Path:
    """The data cache folder for a file (a problem, a URDF): $IDENT_OPT_CACHE if set, else `.cache` of the project
    holding it (the nearest folder above with a pyproject.toml), else `.cache` next to it. Never for code: a
    compiled library goes to `CodeCache`."""
    env = os.environ.get("IDENT_OPT_CACHE")
    if env:
        return Path(env)
    here = Path(path).resolve().parent
    for folder in (here, *here.parents):
        if (folder / "pyproject.toml").is_file():
            return folder / ".cache"
    return here / ".cache"


def code_root() -> Path:
    """The root of the code cache: $IDENT_OPT_CACHE if set, else $XDG_CACHE_HOME/ident-opt (when absolute), else
    ~/.cache/ident-opt. Not checked here: `CodeCache` checks it."""
    env = os.environ.get("IDENT_OPT_CACHE")
    if env:
        return Path(env).expanduser().absolute()
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    return (Path(xdg) if os.path.isabs(xdg) else Path.home() / ".cache") / "ident-opt"


class Untrusted(OSError):
    """A code cache folder this process must not trust (its message says why)."""


def distrust(st: os.stat_result, secret: bool = False) -> str | None:
    """Why a file or folder with this status is not the user's alone, or None when it is: another owner, or
    writable by group or others (readable too when `secret`)."""
    if st.st_uid != os.geteuid():
        return f"it belongs to user id {st.st_uid}, not to you ({os.geteuid()})"
    if st.st_mode & (0o077 if secret else 0o022):
        return f"other users can {'read or write' if secret else 'write'} it (mode {stat.S_IMODE(st.st_mode):04o})"
    return None


def _subfolder(parent: int, name: str) -> int:
    """An open descriptor of the folder `name` in the open folder `parent`, made with mode 0700 when missing; never
    through a link; `Untrusted` when it is not the user's alone."""
    try:
        os.mkdir(name, 0o700, dir_fd=parent)
    except FileExistsError:
        pass
    try:
        fd = os.open(name, _DIR | os.O_NOFOLLOW, dir_fd=parent)
    except OSError as exc:
        raise Untrusted(f"its folder {name!r} cannot be opened ({exc.strerror}; a link?)") from None
    why = distrust(os.fstat(fd))
    if why:
        os.close(fd)
        raise Untrusted(f"its folder {name!r}: {why}")
    return fd


def read_private(folder: int, name: str, secret: bool = False, limit: int | None = None) -> bytes | None:
    """The bytes of the file `name` in the open folder `folder`, or None when it is missing, a link or not a regular
    file, another user's, or writable by others (readable too when `secret`), or longer than `limit`. Read from
    the descriptor it was checked on."""
    try:
        fd = os.open(name, _FILE, dir_fd=folder)
    except OSError:
        return None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or distrust(st, secret) or (limit is not None and st.st_size > limit):
            return None
        os.set_blocking(fd, True)
        with open(fd, "rb", closefd=False) as fh:
            return fh.read()
    finally:
        os.close(fd)


def write_private(folder: int, name: str, data: bytes, replace: bool = True) -> None:
    """Write `data` to `name` in the open folder `folder` (mode 0600): under a temporary name, then renamed into
    place (`replace`) or linked there only if `name` is missing (else nothing changes)."""
    partial = f".{name}.{os.getpid()}.{secrets.token_hex(4)}.part"
    fd = os.open(partial, _NEW, 0o600, dir_fd=folder)
    try:
        with open(fd, "wb", closefd=False) as fh:
            fh.write(data)
        if replace:
            os.replace(partial, name, src_dir_fd=folder, dst_dir_fd=folder)
            return
        try:
            os.link(partial, name, src_dir_fd=folder, dst_dir_fd=folder)
        except FileExistsError:
            pass
        except OSError:  # a file system without hard links: renamed instead (a racing writer may then win)
            os.replace(partial, name, src_dir_fd=folder, dst_dir_fd=folder)
    finally:
        os.close(fd)
        try:
            os.unlink(partial, dir_fd=folder)
        except FileNotFoundError:
            pass


_scratch: list[Path] = []  # the folder, once made
_scratch_lock = threading.Lock()
_warned: set[str] = set()


def scratch() -> Path:
    """A private temporary folder (mode 0700, made by `tempfile.mkdtemp` under an unguessable name) shared by this
    process and its forked children, removed when the process that made it exits. Name files in it with the
    process id."""
    with _scratch_lock:
        if not _scratch:
            _scratch.append(Path(tempfile.mkdtemp(prefix="ident-opt-")))
            atexit.register(_remove_scratch, os.getpid(), _scratch[0])
        return _scratch[0]


def _remove_scratch(pid: int, folder: Path) -> None:
    if os.getpid() == pid:  # a forked child running its parent's handler leaves the parent's folder alone
        shutil.rmtree(folder, ignore_errors=True)


def _key(root: int) -> bytes:
    """The key of the records in the open root folder: read, or made on first use (a bad one is replaced, which
    invalidates every record signed with it)."""
    key = read_private(root, "key", secret=True, limit=KEY_BYTES)
    if key is not None and len(key) == KEY_BYTES:
        return key
    try:
        os.stat("key", dir_fd=root, follow_symlinks=False)
        bad = True  # there, but a link, another user's, readable by others or of the wrong size
    except FileNotFoundError:
        bad = False
    write_private(root, "key", secrets.token_bytes(KEY_BYTES), replace=bad)
    key = read_private(root, "key", secret=True, limit=KEY_BYTES)
    if key is None or len(key) != KEY_BYTES:
        raise Untrusted("its key file cannot be made or read back")
    return key


class CodeCache:
    """The folder `kind` of the code cache (see the module's docstring), open and checked: `read` a library's bytes
    if this tool wrote them, `write` a library it built. Use it in a `with` block (it holds folder descriptors)."""

    def __init__(self, kind: str):
        if not kind.isidentifier():
            raise ValueError(f"a code cache kind is a plain name, not {kind!r}")
        self.kind = kind
        self._fds: list[int] = []
        self.root: Path | None = None
        if not PERSISTENT:
            return
        root = None
        try:
            root = code_root()
            self._open(root)
        except (OSError, RuntimeError) as exc:  # Untrusted is an OSError; RuntimeError: no home folder
            self.close()
            why = str(exc) if isinstance(exc, Untrusted) else f"it cannot be used ({exc})"
            _warn(f"not using the code cache {root or '(no home folder)'}: {why}")
            self._open(scratch() / "cache")

    def _open(self, root: Path) -> None:
        """Open and check `root`, its key, the folder of the kind and that of its records."""
        try:
            root.mkdir(mode=0o700, parents=True, exist_ok=True)
            fd = os.open(root, _DIR)  # the root may be a link the user made: the folder it names is checked
        except OSError as exc:
            raise Untrusted(f"it cannot be made or opened ({exc.strerror})") from None
        self._fds.append(fd)
        why = distrust(os.fstat(fd))
        if why:
            raise Untrusted(why)
        self._key = _key(fd)
        self._folder = _subfolder(fd, self.kind)
        self._fds.append(self._folder)
        records = _subfolder(fd, "records")
        self._fds.append(records)
        self._records = _subfolder(records, self.kind)
        self._fds.append(self._records)
        self.root = root

    def _record(self, name: str, data: bytes) -> bytes:
        tag = hmac.new(self._key, name.encode() + b"\0" + data, hashlib.sha256).hexdigest()
        return f"hmac-sha256 {tag}\n".encode()

    def read(self, name: str) -> bytes | None:
        """The bytes of the library `name` when this tool wrote them (its record matches them), else None."""
        if self.root is None:
            return None
        record = read_private(self._records, f"{name}.hmac", limit=256)
        if record is None:
            return None
        data = read_private(self._folder, name)
        if data is None or not hmac.compare_digest(record, self._record(name, data)):
            return None
        return data

    def write(self, name: str, data: bytes) -> None:
        """Keep the library `name` (its bytes `data`, which this tool just built) with its record."""
        if self.root is None:
            return
        write_private(self._folder, name, data)
        write_private(self._records, f"{name}.hmac", self._record(name, data))

    def close(self) -> None:
        while self._fds:
            os.close(self._fds.pop())

    def __enter__(self) -> CodeCache:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _warn(message: str) -> None:
    """Say once per process why the code cache is not used."""
    if message not in _warned:
        _warned.add(message)
        print(
            f"warning: {message}; compiling into a private temporary folder for this run instead "
            "(remove that folder, or set IDENT_OPT_CACHE to a folder only you can write)",
            file=sys.stderr,
        )
