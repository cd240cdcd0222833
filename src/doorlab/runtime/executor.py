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

import asyncio
import concurrent.futures
import multiprocessing
import os
import threading
import urllib.parse
from collections.abc import Iterator
from contextlib import contextmanager

from doorlab.errors import ConfigError
from doorlab.runtime.inputs import quote, quote_text
from doorlab.runtime.interrupts import end_pool, spawning_workers, worker_signals

SCHEDULER_SCHEMES = ("tcp", "tls", "ws", "wss")
"""Protocols of the addresses ``--scheduler`` accepts, e.g. ``tcp://10.0.0.5:8786``."""

WORKER_ENVIRONMENT = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
"""Set for local worker processes (as Dask's nanny does for its workers): one process per core,
each single-threaded, instead of every process's BLAS/OpenMP threads competing for the cores.
A value the user exported is kept."""

CONNECT_TIMEOUT_S = 10.0
"""How long connecting to a Dask scheduler may take [s], each step: reaching it, its
handshake, its first answer, a first worker (``--scheduler-timeout`` sets it). On a LAN a
scheduler answers in milliseconds; 10 s covers a slow VPN and a cluster still starting."""


def check_scheduler(address: str) -> str:
    """Returns ``address`` if it is a Dask scheduler address ``PROTOCOL://HOST[:PORT]``.

    Raises:
        ConfigError: Not of that form (protocol tcp, tls, ws or wss; a port in 1-65535).
    """
    valid = "a Dask scheduler address like tcp://HOST:PORT (PORT in 1-65535)"
    if not isinstance(address, str):
        raise ConfigError(f"--scheduler must be {valid}, got {quote(address)}")
    shown = quote_text(address)
    try:
        parts = urllib.parse.urlsplit(address)
        port = parts.port  # ValueError if not an integer in 0-65535
    except ValueError:
        raise ConfigError(f"--scheduler must be {valid}, got {shown}") from None
    if (
        parts.scheme not in SCHEDULER_SCHEMES
        or not parts.hostname
        or any(c.isspace() for c in address)
        or parts.path not in ("", "/")
        or parts.query
        or parts.fragment
        or parts.username is not None
        or port == 0
        or (":" in parts.netloc.rsplit("]", 1)[-1] and port is None)  # "tcp://host:"
    ):
        raise ConfigError(f"--scheduler must be {valid}, got {shown}")
    return address


class LocalExecutor(concurrent.futures.ProcessPoolExecutor):
    """Worker processes on this machine (spawned, so each imports doorlab afresh).

    Ctrl-C is this process's to handle: the workers are born with SIGINT (and SIGHUP)
    blocked, then ignore SIGINT; SIGTERM/SIGHUP end them at once
    (:mod:`doorlab.runtime.interrupts`).
    """

    def __init__(self, jobs: int) -> None:
        if not isinstance(jobs, int) or isinstance(jobs, bool) or jobs < 1:
            raise ConfigError(f"jobs must be an integer >= 1, got {quote(jobs)}")
        with spawning_workers():
            super().__init__(
                max_workers=jobs,
                mp_context=multiprocessing.get_context("spawn"),
                initializer=worker_signals,
            )
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
        with spawning_workers():
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
        """Cancels pending tasks and ends the worker processes (SIGTERM, then SIGKILL for any
        still there after a moment); returns once they are gone."""
        end_pool(self, at_once=True)


def _within(timeout_s: float, what: str, call):
    """``call()`` in a helper thread, given ``timeout_s``: its result, or TimeoutError.

    Connecting to a Dask scheduler may wait forever in places (a server that accepts and
    says nothing stalls the handshake); the thread is a daemon and is left behind.
    """
    box: dict = {}

    def target() -> None:
        try:
            box["value"] = call()
        except BaseException as e:  # handed to the caller
            box["error"] = e

    thread = threading.Thread(target=target, name=f"doorlab-{what}", daemon=True)
    thread.start()
    thread.join(timeout_s)
    if thread.is_alive():
        raise TimeoutError(f"{what} took more than {timeout_s:g} s")
    if "error" in box:
        raise box["error"]
    return box["value"]


def _security(security=None):
    """The TLS settings to connect with: ``security`` (a ``distributed.Security``), else
    Dask's configuration's (``distributed.comm.tls.*``: empty unless the course set them)."""
    if security is not None:
        return security
    from distributed import Security

    return Security()


def probe_scheduler(address: str, timeout_s: float = CONNECT_TIMEOUT_S, security=None) -> dict:
    """Connects to ``address``, completes Dask's handshake and asks who answers, all within
    ``timeout_s``; returns the scheduler's identity. ``security``: a ``distributed.Security``
    (a ``tls://`` scheduler's certificates; default: Dask's configuration's).

    Raises:
        ConfigError: Unreachable, silent, not speaking Dask's protocol (a garbage answer),
            or not a scheduler (one line, within ``timeout_s`` and a little).
    """
    from distributed.comm import connect

    security = _security(security)
    if address.startswith(("tls://", "wss://")) and not security.tls_ca_file:
        raise ConfigError(
            f"the scheduler at {address} speaks TLS: give its certificates (grade-all: "
            "--cluster-keys DIR; else Dask's configuration: distributed.comm.tls.ca-file, "
            "client.cert and client.key, e.g. DASK_DISTRIBUTED__COMM__TLS__CA_FILE)"
        )
    arguments = security.get_connection_args("client")

    async def identify() -> object:
        comm = await connect(address, timeout=timeout_s, **arguments)  # and the handshake
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    def run() -> object:
        # Dask bounds reaching the address (OSError at timeout_s), not the handshake nor the
        # answer: a server that accepts and says nothing would be waited for forever.
        return asyncio.run(asyncio.wait_for(identify(), timeout_s + 0.25))

    try:
        reply = _within(timeout_s + 1.0, "scheduler-probe", run)
    except (TimeoutError, asyncio.TimeoutError):
        raise ConfigError(
            f"the server at {address} did not answer as a Dask scheduler within "
            f"{timeout_s:g} s (--scheduler-timeout); is a Dask scheduler listening there?"
        ) from None
    except OSError as e:
        raise ConfigError(
            f"cannot reach the Dask scheduler at {address}: {quote_text(str(e))}"
        ) from None
    except Exception as e:  # a garbage answer: MemoryError, ValueError, msgpack errors...
        raise ConfigError(
            f"the server at {address} does not speak Dask's protocol "
            f"({type(e).__name__}: {quote_text(str(e))})"
        ) from None
    if not isinstance(reply, dict) or reply.get("type") != "Scheduler":
        kind = reply.get("type") if isinstance(reply, dict) else type(reply).__name__
        raise ConfigError(f"{address} answers, but is not a Dask scheduler ({quote(kind)})")
    return reply


class DaskExecutor(concurrent.futures.Executor):
    """Tasks on a Dask ``distributed`` cluster, through its Client's executor.

    Connecting is bounded: :func:`probe_scheduler` first (handshake and identity, within the
    timeout), then the Client (within the timeout), then a first worker (within the timeout).
    """

    def __init__(
        self, address: str, *, timeout_s: float = CONNECT_TIMEOUT_S, security=None
    ) -> None:
        check_scheduler(address)
        try:
            from distributed import Client
        except ImportError as e:  # pragma: no cover - distributed is a dependency
            raise ConfigError(f"--scheduler needs the 'distributed' package: {e}") from None
        self.timeout_s = timeout_s
        security = _security(security)
        probe_scheduler(address, timeout_s, security)
        try:
            self.client = _within(
                timeout_s + 1.0,
                "dask-client",
                lambda: Client(address, timeout=timeout_s, set_as_default=False, security=security),
            )
        except Exception as e:
            raise ConfigError(
                f"cannot connect a Dask client to {address} within {timeout_s:g} s: "
                f"{type(e).__name__}: {quote_text(str(e))}"
            ) from None
        try:
            self.client.wait_for_workers(1, timeout=timeout_s)
        except Exception:
            self._close()
            raise ConfigError(
                f"the Dask scheduler at {address} has no workers (waited {timeout_s:g} s); "
                "start some with: dask worker ADDRESS --nthreads 1"
            ) from None
        # pure=False: every submission runs (no result sharing between identical calls).
        self._executor = self.client.get_executor(pure=False)
        workers = self.client.scheduler_info().get("workers", {})
        threads = sum(w.get("nthreads", 1) for w in workers.values())
        self.jobs = max(threads, 1)
        self.description = f"Dask cluster {address} ({len(workers)} workers, {threads} threads)"

    def submit(self, fn, /, *args, **kwargs) -> concurrent.futures.Future:  # noqa: D102
        return self._executor.submit(fn, *args, **kwargs)

    def _close(self) -> None:
        try:
            self.client.close(timeout=self.timeout_s)
        except Exception:  # a scheduler gone meanwhile: nothing left to close cleanly
            pass

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:  # noqa: D102
        try:
            self._executor.shutdown(wait=wait)
        finally:
            self._close()

    def stop(self) -> None:
        """Cancels the submitted tasks and disconnects (the cluster keeps running)."""
        try:
            futures = list(self._executor._futures)  # the Dask futures behind ours
            if futures:
                self.client.cancel(futures)
        except Exception:
            pass
        finally:
            self._close()


@contextmanager
def open_executor(
    *,
    jobs: int = 1,
    scheduler: str | None = None,
    timeout_s: float = CONNECT_TIMEOUT_S,
    security=None,
) -> Iterator[LocalExecutor | DaskExecutor]:
    """An executor for the ``with`` block: local processes, or a Dask cluster's.

    Leaving the block normally waits for the submitted tasks; leaving it by an exception
    (Ctrl-C included) stops the executor at once (:meth:`LocalExecutor.stop`).

    Args:
        jobs: Local worker processes (ignored with ``scheduler``).
        scheduler: A Dask scheduler address ``tcp://HOST:PORT``; None: local processes.
        timeout_s: Each step of connecting to ``scheduler`` [s] (see :class:`DaskExecutor`).
        security: A ``distributed.Security``: the TLS certificates of a ``tls://``
            scheduler (default: Dask's configuration's, ``distributed.comm.tls.*``).

    Raises:
        ConfigError: Bad ``jobs`` or ``scheduler``, or the scheduler cannot be reached.
    """
    if scheduler:
        executor = DaskExecutor(scheduler, timeout_s=timeout_s, security=security)
    else:
        executor = LocalExecutor(jobs)
    try:
        yield executor
    except BaseException:
        executor.stop()
        raise
    executor.shutdown(wait=True)
