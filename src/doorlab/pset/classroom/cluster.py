"""A class graded on a Dask cluster that no student's code can reach.

A Dask scheduler runs whatever a connected client asks, on every worker (``Client.run``), as
the workers' user: a student's code that reaches the scheduler could patch the grader of the
whole class. Two lines hold it:

- **the student's code has no network**: ``grade-all --scheduler`` grades only where the
  student's process gets a network namespace of its own (loopback only): the student's view
  (bubblewrap), or, without it, as root, the separate user's own namespace
  (:data:`doorlab.pset.isolation.choice.OWN_NAMESPACES`). Before anything is graded a worker is
  asked how it would isolate (:func:`check_workers`): a cluster whose workers cannot is refused in
  one line, and every grading checks it again on its own worker (a grading there is an
  ``error`` row, never a grade);
- **the cluster speaks TLS**: :func:`local_cluster` starts one on this machine whose comms
  are TLS with a certificate and key made in memory for it (``distributed``'s
  ``Security.temporary()``, the ``cryptography`` package): nothing without the key connects,
  let alone runs code. For a cluster the course starts, give the scheduler, the workers and
  the client certificates (``dask scheduler --tls-ca-file ... --tls-cert ... --tls-key ...``,
  the same for ``dask worker``, and for doorlab Dask's configuration, e.g.
  ``DASK_DISTRIBUTED__COMM__TLS__CA_FILE``, ``..._CLIENT__CERT``, ``..._CLIENT__KEY`` and
  ``DASK_DISTRIBUTED__COMM__REQUIRE_ENCRYPTION=True``) and a ``tls://`` address to
  ``--scheduler``; the workers need not run as root where bubblewrap can make its namespaces
  and a delegated cgroup serves (:mod:`doorlab.pset.isolation.cgroups`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass

from doorlab.errors import ConfigError

CHECK_TIMEOUT_S = 120.0
"""How long a worker may take to say how it would isolate [s] (it builds the view once)."""


def worker_isolation(policy: str) -> dict:
    """On a worker: how its gradings would isolate the student's code (``mode``,
    ``network_isolated``, ``reason``), or why none can (``error``)."""
    import tempfile
    from pathlib import Path

    from doorlab.pset.isolation.choice import IsolationError, prepare

    with tempfile.TemporaryDirectory(prefix="doorlab_probe_") as tmp:
        try:
            isolation = prepare(Path(tmp), policy)
        except (IsolationError, OSError) as e:
            return {"error": str(e)}
    return {
        "mode": isolation.mode,
        "network_isolated": isolation.network_isolated,
        "reason": isolation.reason,
    }


def check_workers(executor, policy: str) -> dict:
    """Asks a worker of ``executor`` how it would isolate; returns its answer.

    Raises:
        ConfigError: The worker's gradings would let the student's code reach the network
            (so the cluster), or it cannot isolate it at all (one line).
    """
    from doorlab.runtime.inputs import quote_text

    future = executor.submit(worker_isolation, policy)
    try:
        facts = future.result(timeout=CHECK_TIMEOUT_S)
    except Exception as e:  # noqa: BLE001 - the worker's failure, in one line
        raise ConfigError(
            f"--scheduler: a worker could not say how it isolates the student's code "
            f"({type(e).__name__}: {quote_text(str(e))})"
        ) from None
    if "error" in facts:
        raise ConfigError(f"--scheduler: a worker cannot grade: {quote_text(facts['error'])}")
    if not facts.get("network_isolated"):
        raise ConfigError(
            "--scheduler: the cluster's workers would run the student's code without a "
            f"network namespace ({quote_text(facts.get('reason') or facts.get('mode'))}), "
            "so it could reach the scheduler and run code on every worker; install "
            "bubblewrap on the workers (or run them as root: the separate user then gets a "
            "namespace of its own)"
        )
    return facts


@dataclass
class LocalCluster:
    """A Dask cluster on this machine's loopback, TLS only (see :func:`local_cluster`).

    Attributes:
        address: The scheduler's ``tls://`` address.
        security: The ``distributed.Security`` a client needs to connect (its key is in
            this process's memory only).
    """

    address: str
    security: object


@contextlib.contextmanager
def local_cluster(workers: int = 2) -> Iterator[LocalCluster]:
    """A ``distributed.LocalCluster`` of ``workers`` processes (one thread each) on
    loopback whose comms are TLS with a certificate made for it, for the ``with`` block.

    Raises:
        ConfigError: ``distributed`` or ``cryptography`` is missing (the extra ``sweep``).
    """
    try:
        from distributed import LocalCluster as DaskCluster
        from distributed import Security

        security = Security.temporary()
    except ImportError as e:
        raise ConfigError(
            f'a TLS cluster needs distributed and cryptography (pip install "doorlab[sweep]"): {e}'
        ) from None
    with DaskCluster(
        n_workers=workers,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        protocol="tls://",
        security=security,
        dashboard_address=None,
        silence_logs=40,
    ) as cluster:
        yield LocalCluster(cluster.scheduler_address, security)
