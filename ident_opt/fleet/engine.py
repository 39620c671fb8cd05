"""The Dask side of a fleet run: a client on a local cluster (one single-threaded worker process per core by
default) or on an existing scheduler, and a runner that submits the task graph robot by robot and gathers only the
small results, with a progress bar over the tasks.

A scheduler that does not answer within `CONNECT_TIMEOUT_S`, an address that answers but does not speak Dask's
protocol (a web server: Dask's own handshake would wait for it forever, so the address is probed first with a
bounded one, `_probe`), one without workers, or workers that cannot run ident-opt on the problem (not installed, the
problem file not at the same path) are `InputError`s naming the address: exit 2, in bounded time.

Ctrl-C or SIGTERM to the process group ends a run in one line, its workers closed (`fleet.interrupts`): the local
cluster's worker processes ignore both signals, and the client takes them between Dask's calls.

The runner keeps at most a window of robots in flight: each robot's futures are released as they complete (the
scheduler keeps a task's input until its dependents ran), so what the cluster holds at once is bounded by the window,
whatever the fleet's size, and the client holds only the results it gathers (fits and evidence, never samples).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import logging
import multiprocessing
import os
import sys
import time
from collections.abc import Callable, Iterable
from typing import Any

from distributed import Client, LocalCluster, as_completed
from distributed.comm import connect
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from ident_opt.errors import InputError
from ident_opt.fleet import interrupts

#: How long to wait for a scheduler to answer, and for it to have a worker [s].
CONNECT_TIMEOUT_S = 10.0
#: The local cluster's worker processes: at most this long [s] with signals ignored while they are spawned, and
#: this long for them all to start.
SPAWN_S, START_S = 30.0, 300.0
#: An interrupted run's cluster is given this long to close [s], then its worker processes are killed.
CLOSE_S = 15.0
#: How often the runner looks for a signal while it waits for a task [s].
POLL_S = 0.02
#: Robots in flight per worker (at least `MIN_WINDOW`).
WINDOW_PER_WORKER, MIN_WINDOW = 2, 4

#: A robot's submission: (futures whose results are gathered, futures only waited for).
Submit = Callable[[Any, Any], tuple[list, list]]


class Engine:
    """A Dask client for one run: `with Engine(scheduler, workers) as engine: engine.run(...)`. Without
    `scheduler`, a `distributed.LocalCluster` of `workers` processes (default: the machine's cores; `processes`
    False: threads in this process, for tests); with it, the scheduler at that address (`tcp://host:8786`)."""

    def __init__(
        self,
        scheduler: str | None = None,
        workers: int | None = None,
        processes: bool = True,
        timeout: float = CONNECT_TIMEOUT_S,
    ):
        self.scheduler = scheduler
        self.requested = workers
        self.processes = processes
        self.timeout = timeout
        self.client = None
        self.cluster = None
        self.blas = None
        self.spawned: list[multiprocessing.Process] = []  # the worker processes started with signals ignored
        self.signals = interrupts.Deferred()

    def __enter__(self) -> Engine:
        self.signals.__enter__()
        try:
            self._start()
            self.signals.deliver()  # one that came while the cluster started
        except BaseException as exc:  # `__exit__` does not run when `__enter__` fails
            self.__exit__(type(exc), exc, exc.__traceback__)
            raise
        return self

    def _start(self) -> None:
        """The client, on the local cluster or the scheduler (class doc)."""
        if self.scheduler is None:
            workers = self.requested or os.cpu_count() or 1
            if not self.processes:  # as Dask's worker processes run: one BLAS thread each (many threads thrash)
                self.blas = threadpool_limits(limits=1)
            self._start_local(workers)
            return
        _probe(self.scheduler, self.timeout)
        try:
            self.client = Client(self.scheduler, timeout=f"{self.timeout}s")
        except (OSError, TimeoutError, ValueError, TypeError) as exc:
            raise InputError(_no_scheduler(self.scheduler, self.timeout, _first_line(exc))) from None
        try:
            self.client.wait_for_workers(1, timeout=self.timeout)
        except (TimeoutError, OSError):
            self.close()
            raise InputError(
                f"--scheduler {self.scheduler}: the scheduler has no workers after {self.timeout:g} s; start some "
                f"(`dask worker {self.scheduler}`)"
            ) from None

    def _start_local(self, workers: int) -> None:
        """The local cluster of `workers` processes (or threads) and its client. The worker processes ignore SIGINT
        and SIGTERM (`fleet.interrupts`): this process ignores them while it spawns them (a fraction of a second),
        not while they start (seconds, the scheduler started first), so that a signal then still reaches it. The
        scheduler's web server takes a free port (8787 taken by another cluster is a warning otherwise)."""
        if not self.processes:
            self.cluster = LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=False,
                # threads in this process: a worker's memory monitor would measure the whole process (the client and
                # what it holds) against its share and pause the worker, waiting on memory it cannot free
                memory_limit=0,
                dashboard_address=None,
                silence_logs=logging.ERROR,
                scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
            )
            self.client = Client(self.cluster)
            return
        self.cluster = LocalCluster(
            n_workers=0,
            threads_per_worker=1,
            processes=True,
            memory_limit=1.0 / workers,  # each worker's share of the memory, as LocalCluster(n_workers=...) gives
            dashboard_address=None,
            # the worker processes print nothing short of a crash: a task's error reaches the client as the file's
            # skip reason, and a worker that outlives an interrupted scheduler logged its failed heartbeat's traceback
            silence_logs=logging.CRITICAL,
            scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
        )
        before = set(multiprocessing.active_children())
        with interrupts.ignored():
            self.cluster.scale(workers)
            deadline = time.monotonic() + SPAWN_S
            while len(self.spawned) < workers and time.monotonic() < deadline:  # else: waiting for them says so
                time.sleep(0.01)
                self.spawned = [p for p in multiprocessing.active_children() if p not in before]
        self.client = Client(self.cluster)
        try:
            self.client.wait_for_workers(workers, timeout=START_S)
        except TimeoutError:
            raise RuntimeError(
                f"the local cluster's {workers} worker processes did not start within {START_S:g} s"
            ) from None

    def __exit__(self, kind, value, traceback) -> None:
        try:
            if kind is not None and issubclass(kind, KeyboardInterrupt):
                # interrupted (Ctrl-C, SIGTERM): the cluster is closed mid-work; Dask's logs and errors about what
                # it drops are not news (the command says it was interrupted, in one line)
                with interrupts.quiet():
                    self.close(interrupted=True)
            else:
                self.close()
        finally:
            self.signals.__exit__(kind, value, traceback)

    def close(self, interrupted: bool = False) -> None:
        """Close the client and the local cluster (an existing scheduler and its workers are left running); the
        worker processes that ignore signals are then ended whatever happened (`interrupts.end`). `interrupted`: the
        run is abandoned, the cluster is given `CLOSE_S` to close and its errors are dropped."""
        try:
            if self.client is not None:
                client, self.client = self.client, None
                _closing(client.close, interrupted)
            if self.cluster is not None:
                cluster, self.cluster = self.cluster, None
                _closing(lambda: cluster.close(timeout=CLOSE_S if interrupted else None), interrupted)
        finally:
            interrupts.end(self.spawned)
            self.spawned = []
            if self.blas is not None:
                self.blas.restore_original_limits()
                self.blas = None

    @property
    def workers(self) -> int:
        """The number of workers the scheduler has now."""
        return len(self.client.scheduler_info()["workers"])

    @property
    def address(self) -> str:
        """ "local" for the local cluster, else the scheduler's address."""
        return "local" if self.scheduler is None else self.scheduler

    def check(self, task: Callable, *args) -> dict:
        """Run `task(*args)` on every worker first (`Client.run`, outside the task graph: it also warms each worker
        up before the timed work): an `InputError` there (the problem not found on a worker) or a worker that cannot
        run ident-opt at all is an InputError naming the scheduler, before any work. {worker: result}."""
        try:
            answers = self.client.run(task, *args)
        except InputError as exc:
            raise InputError(f"a worker of {self.address} cannot load the problem: {exc}") from None
        except Exception as exc:  # whatever stops a worker, said with the address
            raise InputError(
                f"a worker of {self.address} cannot run ident-opt ({type(exc).__name__}: {exc}); the workers need "
                "ident-opt installed and the problem file and logs at the same paths"
            ) from None
        self.signals.deliver()
        return answers

    def run(self, units: Iterable, submit: Submit, total: int, progress: bool, desc: str) -> list:
        """Submit each unit's tasks (`submit(client, unit)`), a window of units at a time, and return the results of
        the futures each marks as gathered, in completion order; a bar over the `total` tasks."""
        queue = iter(units)
        live = as_completed()
        owner: dict[str, int] = {}
        outstanding: dict[int, int] = {}
        gathered: set[str] = set()
        window = max(MIN_WINDOW, WINDOW_PER_WORKER * self.workers)

        def start(index: int) -> bool:
            """Submit the next unit with tasks (as unit `index`); False when none is left."""
            for unit in queue:
                collect, others = submit(self.client, unit)
                gathered.update(f.key for f in collect)
                outstanding[index] = 0
                for future in (*collect, *others):
                    if future.key not in owner:
                        owner[future.key] = index
                        outstanding[index] += 1
                        live.add(future)
                if outstanding[index]:
                    return True
            return False

        count = 0
        while count < window and start(count):
            count += 1
        results = []
        with tqdm(total=total, desc=desc, unit="task", file=sys.stderr, disable=not progress, leave=False) as bar:
            while not live.is_empty():
                if not live.has_ready():  # waiting: the moment to take a signal (`fleet.interrupts`)
                    self.signals.deliver()
                    time.sleep(POLL_S)
                    continue
                future = next(live)
                if future.key in gathered:
                    results.append(future.result())
                bar.update(1)
                index = owner.pop(future.key)
                outstanding[index] -= 1
                if outstanding[index] == 0 and start(count):
                    count += 1
        return results


# ---------------------------------------------------------------------------------------------- helpers
def _first_line(exc: BaseException) -> str:
    """An exception's first line, or its type's name when it has no message."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _no_scheduler(address: str, timeout: float, why: str) -> str:
    """The one-line message of an address where no Dask scheduler answered."""
    return (
        f"--scheduler {address}: no Dask scheduler answered within {timeout:g} s ({why}); start one (`dask "
        "scheduler`) and its workers (`dask worker ADDRESS`), or leave --scheduler out for a local cluster"
    )


async def _identity(address: str, timeout: float) -> dict:
    """Dask's handshake with `address` and its answer to "identity", each bounded by `timeout` [s] (Dask's own
    `connect` waits for the peer's handshake without a limit)."""
    comm = await asyncio.wait_for(connect(address, timeout=timeout), timeout)
    try:
        await comm.write({"op": "identity"})
        return await asyncio.wait_for(comm.read(), timeout)
    finally:
        comm.abort()


def _probe(address: str, timeout: float) -> None:
    """Check that a Dask scheduler answers at `address` within about `timeout` [s] (module doc), in a thread of
    its own (the caller may be running an event loop); an InputError naming the address otherwise."""
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        try:
            answer = pool.submit(asyncio.run, _identity(address, timeout)).result()
        except TimeoutError:
            raise InputError(
                _no_scheduler(address, timeout, "something listens there but does not speak Dask's protocol")
            ) from None
        except OSError as exc:  # nothing listens, or the connection was refused or closed
            raise InputError(_no_scheduler(address, timeout, _first_line(exc))) from None
        except Exception as exc:  # a malformed address, or a peer whose bytes are not Dask's messages
            raise InputError(
                _no_scheduler(address, timeout, f"not Dask's protocol: {type(exc).__name__}: {_first_line(exc)}")
            ) from None
    kind = answer.get("type") if isinstance(answer, dict) else None
    if kind != "Scheduler":
        raise InputError(
            f"--scheduler {address}: a Dask {kind or 'peer'} answered, not a scheduler; give the scheduler's "
            "address (`dask scheduler` prints it)"
        )


def _closing(close: Callable[[], Any], interrupted: bool) -> None:
    """Call `close`; when the run was `interrupted`, whatever it raises is dropped (the worker processes are ended
    after, whatever Dask did: `interrupts.end`)."""
    if not interrupted:
        close()
        return
    with contextlib.suppress(Exception):
        close()
