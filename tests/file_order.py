"""The order in which the suite's files are handed to pytest-xdist's workers.

``--dist loadfile`` gives a worker a whole file at a time, in the collection's order
(``--no-loadscope-reorder``: otherwise xdist sorts the files by their number of tests), the
first file to each worker at the start. Two things decide how long the run takes on 2 cores:

- the real-time files (a test with the ``realtime`` fixture: conftest.py, tests/run_lock.py)
  first, longest first: a real-time test runs beside other real-time tests, never beside an
  ordinary one, so the workers run them together at the start, rather than one waiting while
  the other runs one. They are dealt into one bin per worker (:func:`realtime_bins`: the
  longest to the emptiest bin), and each bin is one unit of work for the scheduler (conftest's
  ``pytest_xdist_make_scheduler``), so every worker starts with a bin of about the same
  length (xdist alone hands out files as workers run low, which left one worker idle for
  40 s while the other ran two real-time files);
- then the others, longest first (longest-processing-time scheduling): the run ends on short
  files on both workers, not on one worker's long file while the other idles.

Each file's time is read from ``tests/durations.json`` (``pytest --record-durations``
rewrites it from a whole run: the sum of each file's setup, call and teardown times [s]); a
file not in it counts :data:`UNKNOWN_S`. Only the order changes: every test runs, once.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

DURATIONS = Path(__file__).with_name("durations.json")
"""Each test file's measured time [s] (``pytest --record-durations``)."""
UNKNOWN_S = 10.0
"""The time counted for a file durations.json does not have [s]."""


def read_durations(path: Path = DURATIONS) -> dict[str, float]:
    """The recorded times by file name ({} without the file, or an unreadable one)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return {str(k): float(v) for k, v in data.items()} if isinstance(data, dict) else {}


def file_order(files: Iterable[str], realtime: set[str], durations: dict[str, float]) -> list[str]:
    """The files in the order they should run (see the module): the real-time ones, then
    the others, each longest first."""

    def by_cost(names: Iterable[str]) -> list[str]:
        return sorted(names, key=lambda n: (-durations.get(n, UNKNOWN_S), n))

    files = set(files)
    return by_cost(files & realtime) + by_cost(files - realtime)


def realtime_bins(
    realtime: Iterable[str], durations: dict[str, float], workers: int
) -> dict[str, str]:
    """{file: bin name} for the real-time files: ``workers`` bins, each file (longest first)
    into the bin with the least time so far; the bins named ``realtime-1`` (the longest) on."""
    bins: list[list[str]] = [[] for _ in range(max(1, workers))]
    load = [0.0] * len(bins)
    for name in sorted(realtime, key=lambda n: (-durations.get(n, UNKNOWN_S), n)):
        k = min(range(len(bins)), key=lambda i: (load[i], i))
        bins[k].append(name)
        load[k] += durations.get(name, UNKNOWN_S)
    order = sorted((k for k in range(len(bins)) if bins[k]), key=lambda k: (-load[k], k))
    return {name: f"realtime-{rank + 1}" for rank, k in enumerate(order) for name in bins[k]}


def write_durations(times: dict[str, float], path: Path = DURATIONS) -> None:
    """Writes the measured times [s] by file, longest first, to ``path``."""
    ordered = dict(sorted(((k, round(v, 1)) for k, v in times.items()), key=lambda kv: -kv[1]))
    path.write_text(json.dumps(ordered, indent=1) + "\n")
