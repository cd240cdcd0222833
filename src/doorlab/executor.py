"""One executor interface for running episodes in parallel: local processes or a Dask cluster.

:func:`open_executor` returns a :class:`concurrent.futures.Executor`:

- by default, local worker processes (``spawn`` context: pydrake and ``fork`` do not mix);
  nothing to start, nothing to install beyond doorlab;
- with ``scheduler="tcp://HOST:PORT"``, the executor of a Dask ``distributed`` Client connected
  to that scheduler. Every worker needs doorlab installed (the same version) in its Python
  environment; start a cluster with ``dask scheduler`` on one machine and
  ``dask worker tcp://HOST:8786 --nthreads 1`` on each (one thread per worker process: an
  episode is single-threaded Python and Drake work, so run one worker process per core).

Futures of both are :class:`concurrent.futures.Future`, so callers use ``submit`` and
:func:`concurrent.futures.as_completed` the same way. :func:`stop_executor` ends an executor
without waiting for running tasks (Ctrl-C): local worker processes are terminated, Dask tasks
are cancelled.
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import os
import re
from collections.abc import Iterator
from contextlib import contextmanager

from doorlab.errors import ConfigError

SCHEDULER_PATTERN = re.compile(r"^(tcp|tls|inproc|ws|wss)://[^\s/]+(:\d+)?/?$")
"""Addresses ``--scheduler`` accepts, e.g. ``tcp://10.0.0.5:8786``."""

WORKER_ENVIRONMENT = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
"""Set for local worker processes (as Dask's nanny does for its workers): one process per core,
each single-threaded, instead of every process's BLAS/OpenMP threads competing for the cores.
A value the user exported is kept."""

CONNECT_TIMEOUT_S = 20.0
"""How long to wait for a Dask scheduler to answer [s]."""


def check_scheduler(address: str) -> str:
    """Returns ``address`` if it looks like a Dask scheduler address.

    Raises:
        ConfigError: Not of the form ``tcp://HOST:PORT`` (or tls://, ws://, inproc://).
    """
    if not isinstance(address, str) or not SCHEDULER_PATTERN.match(address):
        raise ConfigError(
            f"--scheduler must be a Dask scheduler address like tcp://HOST:PORT, got {address!r}"
        )
    return address


class LocalExecutor(concurrent.futures.ProcessPoolExecutor):
    """Worker processes on this machine (spawned, so each imports doorlab afresh)."""

    def __init__(self, jobs: int) -> None:
        if not isinstance(jobs, int) or isinstance(jobs, bool) or jobs < 1:
            raise ConfigError(f"jobs must be an integer >= 1, got {jobs!r}")
        super().__init__(max_workers=jobs, mp_context=multiprocessing.get_context("spawn"))
        self.jobs = jobs
        self.description = f"{jobs} local worker process{'es' if jobs > 1 else ''}"
        self._environment: dict[str, str | None] | None = None

    def submit(self, fn, /, *args, **kwargs) -> concurrent.futures.Future:  # noqa: D102
        # Workers are spawned on demand by submit() and inherit os.environ then: set the
        # single-threaded environment for them, and restore the caller's at shutdown.
        if self._environment is None:
            self._environment = {k: os.environ.get(k) for k in WORKER_ENVIRONMENT}
            for key, value in WORKER_ENVIRONMENT.items():
                os.environ.setdefault(key, value)
        return super().submit(fn, *args, **kwargs)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:  # noqa: D102
        super().shutdown(wait=wait, cancel_futures=cancel_futures)
        if self._environment is not None:
            for key, value in self._environment.items():
                if value is None:
                    os.environ.pop(key, None)
                else:
                    os.environ[key] = value
            self._environment = None

    def stop(self) -> None:
        """Cancels pending tasks and terminates the worker processes (no waiting)."""
        processes = list((getattr(self, "_processes", None) or {}).values())
        self.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            if process.is_alive():
                process.terminate()
        for process in processes:
            process.join(timeout=5.0)


class DaskExecutor(concurrent.futures.Executor):
    """Tasks on a Dask ``distributed`` cluster, through its Client's executor."""

    def __init__(self, address: str) -> None:
        check_scheduler(address)
        try:
            from distributed import Client
        except ImportError as e:  # pragma: no cover - distributed is a dependency
            raise ConfigError(f"--scheduler needs the 'distributed' package: {e}") from None
        try:
            self.client = Client(address, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
        except (OSError, TimeoutError) as e:
            raise ConfigError(f"cannot reach the Dask scheduler at {address}: {e}") from None
        # pure=False: every submission runs (no result sharing between identical calls).
        self._executor = self.client.get_executor(pure=False)
        workers = self.client.scheduler_info().get("workers", {})
        threads = sum(w.get("nthreads", 1) for w in workers.values())
        self.jobs = max(threads, 1)
        self.description = f"Dask cluster {address} ({len(workers)} workers, {threads} threads)"

    def submit(self, fn, /, *args, **kwargs) -> concurrent.futures.Future:  # noqa: D102
        return self._executor.submit(fn, *args, **kwargs)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:  # noqa: D102
        try:
            self._executor.shutdown(wait=wait)
        finally:
            self.client.close()

    def stop(self) -> None:
        """Cancels the submitted tasks and disconnects (the cluster keeps running)."""
        try:
            futures = list(self._executor._futures)  # the Dask futures behind ours
            if futures:
                self.client.cancel(futures)
        finally:
            self.client.close()


@contextmanager
def open_executor(
    *, jobs: int = 1, scheduler: str | None = None
) -> Iterator[LocalExecutor | DaskExecutor]:
    """An executor for the ``with`` block: local processes, or a Dask cluster's.

    Leaving the block normally waits for the submitted tasks; leaving it by an exception
    (Ctrl-C included) stops the executor at once (:meth:`LocalExecutor.stop`).

    Args:
        jobs: Local worker processes (ignored with ``scheduler``).
        scheduler: A Dask scheduler address ``tcp://HOST:PORT``; None: local processes.

    Raises:
        ConfigError: Bad ``jobs`` or ``scheduler``, or the scheduler cannot be reached.
    """
    executor = DaskExecutor(scheduler) if scheduler else LocalExecutor(jobs)
    try:
        yield executor
    except BaseException:
        executor.stop()
        raise
    executor.shutdown(wait=True)
