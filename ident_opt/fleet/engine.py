"""The Dask side of a fleet run: a client on a local cluster (one single-threaded worker process per core by
default) or on an existing scheduler, and a runner that submits the task graph robot by robot and gathers only the
small results, with a progress bar over the tasks.

A scheduler that does not answer within `CONNECT_TIMEOUT_S`, one without workers, or workers that cannot run
ident-opt on the problem (not installed, the problem file not at the same path) are `InputError`s naming the
address: exit 2, in bounded time.

The runner keeps at most a window of robots in flight: each robot's futures are released as they complete (the
scheduler keeps a task's input until its dependents ran), so what the cluster holds at once is bounded by the window,
whatever the fleet's size, and the client holds only the results it gathers (fits and evidence, never samples).
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Callable, Iterable
from typing import Any

from distributed import Client, LocalCluster, as_completed
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from ident_opt.errors import InputError

#: How long to wait for a scheduler to answer, and for it to have a worker [s].
CONNECT_TIMEOUT_S = 10.0
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

    def __enter__(self) -> Engine:
        if self.scheduler is None:
            workers = self.requested or os.cpu_count() or 1
            if not self.processes:  # as Dask's worker processes run: one BLAS thread each (many threads thrash)
                self.blas = threadpool_limits(limits=1)
            self.cluster = LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=self.processes,
                dashboard_address=None,
                silence_logs=logging.ERROR,
            )
            self.client = Client(self.cluster)
            return self
        try:
            self.client = Client(self.scheduler, timeout=f"{self.timeout}s")
        except (OSError, TimeoutError, ValueError, TypeError) as exc:
            first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise InputError(
                f"--scheduler {self.scheduler}: no Dask scheduler answered within {self.timeout:g} s ({first}); "
                "start one (`dask scheduler`) and its workers (`dask worker ADDRESS`), or leave --scheduler out for "
                "a local cluster"
            ) from None
        try:
            self.client.wait_for_workers(1, timeout=self.timeout)
        except (TimeoutError, OSError):
            self.close()
            raise InputError(
                f"--scheduler {self.scheduler}: the scheduler has no workers after {self.timeout:g} s; start some "
                f"(`dask worker {self.scheduler}`)"
            ) from None
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close the client and the local cluster (an existing scheduler and its workers are left running)."""
        if self.client is not None:
            self.client.close()
            self.client = None
        if self.cluster is not None:
            self.cluster.close()
            self.cluster = None
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
            return self.client.run(task, *args)
        except InputError as exc:
            raise InputError(f"a worker of {self.address} cannot load the problem: {exc}") from None
        except Exception as exc:  # whatever stops a worker, said with the address
            raise InputError(
                f"a worker of {self.address} cannot run ident-opt ({type(exc).__name__}: {exc}); the workers need "
                "ident-opt installed and the problem file and logs at the same paths"
            ) from None

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
            for future in live:
                if future.key in gathered:
                    results.append(future.result())
                bar.update(1)
                index = owner.pop(future.key)
                outstanding[index] -= 1
                if outstanding[index] == 0 and start(count):
                    count += 1
        return results
