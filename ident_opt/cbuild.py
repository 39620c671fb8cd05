"""The C toolchain: CasADi functions to C sources, a compiler, shared libraries loaded back into CasADi.

`generate_sources` writes CasADi's generated C, `compile_library` builds a shared library from it with the
machine's compiler (`find_compiler`: $CC, else cc, gcc or clang; an `InputError` when there is none), and
`load_external` loads a function of it back as a `casadi.Function`. `cached_function` compiles a function once per
machine and user into the private code cache (`ident_opt.cache.CodeCache`: only libraries this tool built and
signed are read back from it) and loads it; `CompiledRows` maps one such function over many samples at once (the
n-joint regressor). Code generation proper (what is generated, READMEs, checks) is `ident_opt.shipping.codegen`.
"""

from __future__ import annotations

import hashlib
import itertools
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import casadi as ca
import numpy as np

from ident_opt.cache import CodeCache, scratch
from ident_opt.errors import InputError

#: The default base name of generated files: <NAME>.c, <NAME>.h and lib<NAME>.so (.dylib on macOS).
NAME = "ident_opt_model"
#: Flags used to build the shared library (the README repeats them). No -ffast-math: it would change
#: results (and NaN/inf handling) relative to the Python model.
CFLAGS = ("-O2", "-std=c99", "-fPIC")


def generate_sources(functions: list[ca.Function], out_dir: Path, name: str = NAME) -> tuple[Path, Path]:
    """Write <name>.c and <name>.h (CasADi's code generator) into `out_dir`; returns their paths."""
    out_dir = Path(out_dir)
    cg = ca.CodeGenerator(f"{name}.c", {"with_header": True, "with_export": True, "verbose": False})
    for f in functions:
        cg.add(f)
    try:
        cg.generate(str(out_dir) + os.sep)
    except RuntimeError as exc:
        raise InputError(f"{out_dir}: CasADi could not write the C code ({exc})") from None
    return out_dir / f"{name}.c", out_dir / f"{name}.h"


def library_name(name: str = NAME) -> str:
    """lib<name>.so, or .dylib on macOS, .dll on Windows."""
    suffix = {"darwin": ".dylib", "win32": ".dll"}.get(sys.platform, ".so")
    return f"lib{name}{suffix}"


def find_compiler() -> list[str]:
    """The C compiler command: $CC if set (split like a shell would, e.g. "ccache gcc"; its program must
    exist), else gcc, else cc on PATH. `InputError` when there is none."""
    cc = os.environ.get("CC", "").strip()
    if cc:
        words = shlex.split(cc)
        found = shutil.which(words[0])
        if not found:
            raise InputError(f"the C compiler CC={cc!r} was not found; install one or set CC to a C compiler")
        return [found, *words[1:]]
    for candidate in ("gcc", "cc"):
        found = shutil.which(candidate)
        if found:
            return [found]
    raise InputError("no C compiler found (tried gcc and cc on PATH); install one (e.g. apt install gcc) or set CC")


def compile_library(source: Path, out_dir: Path, compiler: list[str] | None = None, name: str = NAME) -> Path:
    """Compile `source` into the shared library `out_dir`/lib<name>.so with `CFLAGS`; returns its path.
    `compiler` is a command (program and leading arguments), by default `find_compiler()`."""
    compiler = list(compiler or find_compiler())
    lib = Path(out_dir) / library_name(name)
    run_compiler([*compiler, *CFLAGS, "-shared", str(source), "-o", str(lib), "-lm"], compiler[0], str(source))
    if not lib.is_file():
        raise InputError(
            f"the C compiler {compiler[0]!r} reported success but wrote no {lib.name}: is it a C compiler?"
        )
    return lib


def compile_shared(sources: list[str], library: Path, compiler: list[str], flags: tuple[str, ...] = CFLAGS) -> Path:
    """Compile C `sources` into the shared `library` with `flags`; `InputError` when the compiler fails."""
    run_compiler([*compiler, *flags, "-shared", *sources, "-o", str(library), "-lm"], compiler[0])
    return Path(library)


def run_compiler(cmd: list[str], name: str, what: str = "the online update") -> None:
    """Run the compiler command `cmd` (its program `name`) on `what`; `InputError` when it cannot run or fails."""
    try:
        # errors="replace": the compiler's messages quote the paths, which need not be UTF-8
        done = subprocess.run(cmd, capture_output=True, text=True, errors="replace", check=False)
    except OSError as exc:
        raise InputError(f"cannot run the C compiler {name!r} ({exc.strerror})") from None
    if done.returncode != 0:
        raise InputError(f"the C compiler failed on {what} (exit {done.returncode}):\n{done.stderr.strip()}")


def load_external(lib: Path, fname: str) -> ca.Function:
    """A compiled entry point back as a CasADi Function (`casadi.external`), for checks and timing."""
    return ca.external(fname, str(Path(lib).resolve()))


def cached_function(function: ca.Function, kind: str, build: bool = True) -> ca.Function | None:
    """`function` as generated C compiled into a shared library and loaded back: from the code cache's folder
    `kind` (`CodeCache`) when this tool built it there before (its key: a hash of the C source and `CFLAGS`), else
    compiled now and kept there, so a machine compiles each function once. With `build=False`, None when it is not
    cached yet (nothing compiled). A library in the cache without a valid record (planted, tampered) is never
    loaded: it is compiled anew and replaced."""
    name = function.name()
    with tempfile.TemporaryDirectory() as tmp:
        source, _ = generate_sources([function], Path(tmp), name)
        key = hashlib.sha256(source.read_bytes() + " ".join(CFLAGS).encode()).hexdigest()[:16]
        lib = library_name(f"{name}_{key}")
        with CodeCache(kind) as cache:
            data = cache.read(lib)
            if data is None:
                if not build:
                    return None
                data = compile_library(source, Path(tmp), name=name).read_bytes()
                try:
                    cache.write(lib, data)
                except OSError:
                    pass  # a full or read-only cache: this run still uses what it built
    return load_bytes(data, lib, name)


_loads = itertools.count()


def load_bytes(data: bytes, lib: str, fname: str) -> ca.Function:
    """The entry point `fname` of the library whose bytes are `data` (checked or just built), as a CasADi Function.
    The bytes are written to a new file of this process's private folder (`cache.scratch`, mode 0700), loaded from
    there and the file removed: what is loaded is what was checked, whatever happens to the cache meanwhile."""
    path = scratch() / f"{os.getpid()}-{next(_loads)}-{lib}"
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o600)
    try:
        with open(fd, "wb", closefd=True) as fh:
            fh.write(data)
        return ca.external(fname, str(path))
    finally:
        path.unlink(missing_ok=True)


#: Samples per call of the compiled regressor: its input and output buffers (~4 kB a sample) stay cache-sized.
REGRESSOR_CHUNK = 512


class CompiledRows:
    """A CasADi Function of one sample's x (k×1) to one dense output (r×c), as generated C compiled into a shared
    library and mapped over `chunk` samples: `rows(X)` for X (N, k) gives (N, c, r), i.e. each sample's output
    transposed, read through CasADi's buffers (no copies into CasADi matrices, which cost more than the C).

    The library is compiled once per machine and user into the code cache's folder `kind` (`cached_function`)."""

    def __init__(self, function: ca.Function, kind: str, chunk: int = REGRESSOR_CHUNK):
        self.n_in = function.size1_in(0)
        self.shape = (function.size2_out(0), function.size1_out(0))
        self.chunk = chunk
        self.mapped = cached_function(function, kind).map(chunk, "serial")
        self._buffer, self._run = self.mapped.buffer()
        self._x = np.zeros((chunk, self.n_in))  # the last, partial chunk goes through these
        self._y = np.empty((chunk, *self.shape))
        self._lock = threading.Lock()  # one CasADi buffer and one scratch pair: one caller at a time

    def _call(self, x: np.ndarray, y: np.ndarray) -> None:
        """Evaluate one full chunk: x (chunk, k) C-contiguous into y (chunk, c, r) C-contiguous."""
        self._buffer.set_arg(0, memoryview(x))
        self._buffer.set_res(0, memoryview(y))
        self._run()
        if self._buffer.ret() != 0:
            raise RuntimeError(f"the compiled {self.mapped.name()} failed (status {self._buffer.ret()})")

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """(N, c, r): each sample's output, transposed, for X (N, k)."""
        X = np.ascontiguousarray(X, dtype=float)
        out = np.empty((len(X), *self.shape))
        full = len(X) - len(X) % self.chunk
        with self._lock:
            for s in range(0, full, self.chunk):
                self._call(X[s : s + self.chunk], out[s : s + self.chunk])
            if full < len(X):
                self._x[: len(X) - full] = X[full:]
                self._call(self._x, self._y)
                out[full:] = self._y[: len(X) - full]
        return out
