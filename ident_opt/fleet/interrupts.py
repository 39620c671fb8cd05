"""Ctrl-C and SIGTERM during a fleet run: one line and a non-zero exit, no worker's traceback, no worker left.

A terminal's Ctrl-C, and a supervisor's SIGTERM to the process group, reach every process of the group: the client
and the local cluster's worker processes alike. Two rules keep that clean:

- **The workers ignore both signals** (`ignored`: a process spawned while this one ignores a signal ignores it too,
  and Python keeps it so). A worker killed mid-message would print its traceback and make the scheduler log errors;
  instead the client closes them as it unwinds, and kills any still alive after (`end`: multiprocessing would end
  them at exit with SIGTERM, which they ignore, and wait for them forever). A worker whose client died exits by
  itself (Dask watches its parent).
- **The client takes a signal between Dask's calls, not inside one** (`Deferred`): a KeyboardInterrupt raised
  inside one of Dask's blocking calls (the client's start, `Client.run`) leaves its event loop with half-cancelled
  work, and its close then fails, hangs or logs tracebacks. While a run is on the cluster a signal is noted, and
  delivered (`Deferred.deliver`) where the engine waits in its own loop, or when a blocking call returns (Dask's
  calls in a run take seconds at most); a second signal is delivered at once.

Dask's logs while an interrupted run's cluster is closed are silenced (`quiet`): they are about the work dropped.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import signal
import threading
from collections.abc import Iterator
from types import FrameType
from typing import Any

#: The signals a run takes between Dask's calls (SIGTERM where the platform has it).
SIGNALS = tuple(s for s in (signal.SIGINT, getattr(signal, "SIGTERM", None)) if s is not None)


class Interrupted(KeyboardInterrupt):
    """A signal whose handler was the system's default (SIGTERM outside the command line): the run is closed as for
    Ctrl-C, then the signal is raised again with that default (`Deferred.__exit__`)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


class Deferred:
    """`with Deferred() as d:` SIGINT and SIGTERM are noted, not raised, until `d.deliver()` (module doc); the
    handlers before are put back on exit, and a signal still pending is then delivered (unless an exception is
    already on its way). Off the main thread (where Python sets no handler) it does nothing."""

    def __init__(self):
        self.pending: int | None = None
        self.previous: dict[int, Any] = {}

    def __enter__(self) -> Deferred:
        if threading.current_thread() is threading.main_thread():
            self.previous = {s: signal.signal(s, self._note) for s in SIGNALS}
        return self

    def _note(self, signum: int, frame: FrameType | None) -> None:
        if self.pending is None:
            self.pending = signum
            return
        self.pending = None  # a second one: the user means now
        self._raise(signum, frame)

    def deliver(self) -> None:
        """Raise the pending signal's exception here, as its own handler would (KeyboardInterrupt for Ctrl-C, the
        command's for SIGTERM; `Interrupted` for a default handler); nothing when none is pending or it was
        ignored. The handlers before are put back first: a later signal goes to them, while the run closes."""
        signum, self.pending = self.pending, None
        if signum is not None:
            self._raise(signum, None)

    def _raise(self, signum: int, frame: FrameType | None) -> None:
        handler = self.previous.get(signum, signal.SIG_DFL)
        if handler == signal.SIG_IGN:
            return
        self._restore()
        if callable(handler):
            handler(signum, frame)  # KeyboardInterrupt, the command's exception, or what the caller's does
            return
        raise Interrupted(signum)  # the system's default: closed as for Ctrl-C, then raised again (`__exit__`)

    def _restore(self) -> None:
        for signum, handler in self.previous.items():
            signal.signal(signum, _settable(handler))
        self.previous = {}

    def __exit__(self, kind, value, traceback) -> None:
        if kind is None:
            self.deliver()
        self._restore()
        if isinstance(value, Interrupted) and hasattr(signal, "raise_signal"):
            # the default action (end the process, with the signal's status), now that the run is closed
            signal.signal(value.signum, signal.SIG_DFL)
            signal.raise_signal(value.signum)


@contextlib.contextmanager
def ignored() -> Iterator[None]:
    """SIGINT and SIGTERM ignored, the handlers before put back after: a process spawned meanwhile ignores them
    for good (module doc). Nothing to do off the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, signal.SIG_IGN) for s in SIGNALS}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, _settable(handler))


def _settable(handler: Any) -> Any:
    """A handler `signal.signal` returned, as it can be set again: None (one not set from Python) as the default."""
    return signal.SIG_DFL if handler is None else handler


def end(processes: list[multiprocessing.Process]) -> None:
    """Kill those of `processes` still alive and reap them (module doc)."""
    for process in processes:
        if process.is_alive():
            process.kill()
    for process in processes:
        process.join(timeout=10)


@contextlib.contextmanager
def quiet() -> Iterator[None]:
    """Logging off meanwhile (an interrupted run's cluster closed: Dask's logs of the work it drops)."""
    logging.disable(logging.CRITICAL)
    try:
        yield
    finally:
        logging.disable(logging.NOTSET)
