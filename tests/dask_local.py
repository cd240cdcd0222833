"""A plain Dask cluster on this machine for the tests of ``--scheduler`` (no TLS: doorlab's
own TLS cluster is :func:`doorlab.pset.classroom.cluster.local_cluster`)."""

from __future__ import annotations

from typing import Any


def plain_cluster(workers: int) -> Any:
    """A ``distributed.LocalCluster`` of ``workers`` one-thread processes on loopback, quiet,
    its scheduler's HTTP routes on a free port (not 8787: another cluster's, maybe).
    ``distributed`` is imported here: call it after ``pytest.importorskip("distributed")``."""
    import distributed

    return distributed.LocalCluster(
        n_workers=workers,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
        silence_logs=40,
    )
