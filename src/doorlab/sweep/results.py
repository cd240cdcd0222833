"""The results table of a sweep: one row per run, written atomically as Parquet and CSV.

Columns, in order: ``run`` (position in the sweep), ``key`` (hash of the run's full scenario),
``controller``, ``doors``, one column per axis (its dotted field name, the field's unit),
``status``, ``error``, ``run_wall_time_s`` (the whole run in its worker: IK, simulation and
metrics [s]), then every key of ``metrics.json`` (:class:`doorlab.episode.metrics.DoorMetrics`) not
already listed. Runs that produced no metrics (ik_failed, diverged, safety_stop: a safety limit,
kuka_driver's external-torque stop included, stopped the episode; error) have empty metrics.
"""

from __future__ import annotations

import dataclasses
import io
import os
import tempfile
import typing
from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from doorlab.episode.metrics import DoorMetrics

RESULTS_PARQUET = "results.parquet"
RESULTS_CSV = "results.csv"
LEAD_COLUMNS = ("run", "key", "controller", "doors")
STATUS_COLUMNS = ("status", "error", "run_wall_time_s")
TIMING_COLUMNS = ("run_wall_time_s", "wall_time_s", "realtime_factor")
"""Columns measured with a clock: they differ between two runs of the same scenario."""
FAILED_STATUSES = ("diverged", "ik_failed", "safety_stop", "error")
"""Statuses of runs that produced no metrics."""


def _metric_dtypes() -> dict[str, str]:
    """pandas dtype of each metrics.json key (nullable where the metric may be absent)."""
    hints = typing.get_type_hints(DoorMetrics)
    dtypes = {}
    for f in dataclasses.fields(DoorMetrics):
        hint = hints[f.name]
        args = set(typing.get_args(hint)) - {type(None)}
        base = next(iter(args)) if args else hint
        dtypes[f.name] = {bool: "boolean", int: "Int64", float: "float64", str: "string"}.get(
            base, "object"
        )
    return dtypes


METRIC_DTYPES = _metric_dtypes()
"""Every metrics.json key and its dtype in the table."""


def metric_columns() -> list[str]:
    """The metrics.json keys that are columns of their own (not lead or status columns)."""
    return [k for k in METRIC_DTYPES if k not in LEAD_COLUMNS + STATUS_COLUMNS]


def make_table(
    rows: Sequence[dict], axes: Sequence[str], extra: dict[str, str] | None = None
) -> pd.DataFrame:
    """The results table of ``rows`` (dicts from :func:`doorlab.sweep.execution.run_one`).

    Args:
        rows: One dict per run (``run``, ``key``, the axis values, status, metrics...).
        axes: The axis fields, in SPEC order.
        extra: More columns after the metrics (a benchmark's), name -> pandas dtype.
    """
    extra = extra or {}
    columns = [*LEAD_COLUMNS, *axes, *STATUS_COLUMNS, *metric_columns(), *extra]
    frame = pd.DataFrame([{c: row.get(c) for c in columns} for row in rows], columns=columns)
    dtypes = {
        "run": "int64",
        "key": "string",
        "controller": "string",
        "doors": "string",
        "status": "string",
        "error": "string",
        "run_wall_time_s": "float64",
    }
    dtypes.update({k: v for k, v in METRIC_DTYPES.items() if k in metric_columns()})
    dtypes.update(extra)
    for column, dtype in dtypes.items():
        frame[column] = frame[column].astype(dtype)
    frame["error"] = frame["error"].fillna("")
    return frame.sort_values("run", kind="stable").reset_index(drop=True)


def _atomic(path: Path, write) -> None:
    from doorlab.runtime.folders import follow_umask

    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        follow_umask(Path(tmp), folder=False)  # mkstemp makes it 0600; a table is shared
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_table(frame: pd.DataFrame, out_dir: Path) -> None:
    """Writes ``results.parquet`` and ``results.csv`` into ``out_dir``, each atomically, and
    records them in the folder's manifest (so ``--force`` knows them for doorlab's)."""
    from doorlab.runtime.folders import record_written

    out_dir = Path(out_dir)
    _atomic(out_dir / RESULTS_PARQUET, lambda p: frame.to_parquet(p, index=False))
    _atomic(out_dir / RESULTS_CSV, lambda p: frame.to_csv(p, index=False))
    record_written(out_dir, [out_dir / RESULTS_PARQUET, out_dir / RESULTS_CSV])


def read_table(out_dir: Path) -> pd.DataFrame | None:
    """The results table in ``out_dir``, or None if there is none.

    The file is read in one go: pyarrow opens a path once for the footer and again for the
    data, so a table replaced in between (a running sweep writes it after every run) would
    mix two files ("Couldn't deserialize thrift").
    """
    path = Path(out_dir) / RESULTS_PARQUET
    if not path.is_file():
        return None
    return pd.read_parquet(io.BytesIO(path.read_bytes()))
