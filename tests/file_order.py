"""The order in which the suite's files are handed to pytest-xdist's workers.

``--dist loadfile`` gives a worker a whole file at a time, in the collection's order
(``--no-loadscope-reorder``: otherwise xdist sorts the files by their number of tests), the
first file to each worker at the start. Two things decide how long the run takes on 2 cores:

- the real-time files (a test with the ``realtime`` fixture: conftest.py, tests/run_lock.py)
  first, longest first (those that wait on the clock, under a CPU-second a second in the
  recording, before those that keep their core busy all the same). Where real-time priority
  cannot be had, a real-time test runs beside other real-time tests, never beside an
  ordinary one, so the workers run them together at the start, rather than one waiting while
  the other runs one; where it can, they share one worker. They are dealt into one bin per
  such worker (:func:`realtime_bins`: the longest to the emptiest bin), and each bin is one
  unit of work for the scheduler (conftest's ``pytest_xdist_make_scheduler``), so every
  worker starts with a bin of about the same length (xdist alone hands out files as workers
  run low, which left one worker idle for 40 s while the other ran two real-time files);
- then the others, longest first (longest-processing-time scheduling): the run ends on short
  files on both workers, not on one worker's long file while the other idles. Except at the
  start: where the real-time files share one worker (real-time priority: conftest.py), the
  other runs the files that keep more than a core busy (:data:`PARALLEL_CPU_PER_S`: a
  sweep's, a benchmark's or a report's worker processes) first, as many as the real-time
  files that wait last, longest first: those tests, paced to the wall clock, leave most of
  their core idle, and those files' extra processes use it.

Each file's time is read from ``tests/durations.json`` (``pytest --record-durations``
rewrites it from a whole run: the sum of each file's setup, call and teardown times [s], and
the CPU its tests used meanwhile [s], the worker's and its waited-for processes'); a file not
in it counts :data:`UNKNOWN_S`. Only the order changes: every test runs, once.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

DURATIONS = Path(__file__).with_name("durations.json")
"""Each test file's measured time [s] (``pytest --record-durations``)."""
UNKNOWN_S = 10.0
"""The time counted for a file durations.json does not have [s]."""
PARALLEL_CPU_PER_S = 1.05
"""CPU-seconds per second of wall time from which a file counts as keeping more than a core
busy: above a file of one process at a time (1.0 at most; less where it waits on real time
or a time limit), below one whose commands run a process per core (in the recording, beside
another worker, their second processes got only part of the second core: 1.09-1.32 for the
benchmark's, the report's and the teaching guide's files)."""


def _read(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def read_durations(path: Path = DURATIONS) -> dict[str, float]:
    """The recorded times by file name [s] ({} without the file, or an unreadable one)."""
    return {
        str(k): float(v["wall"] if isinstance(v, dict) else v)
        for k, v in _read(path).items()
        if isinstance(v, (int, float)) or (isinstance(v, dict) and "wall" in v)
    }


def read_cpu(path: Path = DURATIONS) -> dict[str, float]:
    """The CPU each file's tests used in the recorded run [s] (the files that have it)."""
    return {
        str(k): float(v["cpu"])
        for k, v in _read(path).items()
        if isinstance(v, dict) and "cpu" in v
    }


def file_order(
    files: Iterable[str],
    realtime: set[str],
    durations: dict[str, float],
    cpu: dict[str, float] | None = None,
) -> list[str]:
    """The files in the order they should run (see the module): the real-time ones (those
    that wait on the clock first), then the others, each longest first, those that keep
    more than a core busy (by ``cpu``) first for as long as the real-time ones wait."""

    def cost(name: str) -> float:
        return durations.get(name, UNKNOWN_S)

    def by_cost(names: Iterable[str]) -> list[str]:
        return sorted(names, key=lambda n: (-cost(n), n))

    files = set(files)
    cpu = cpu or {}
    # The real-time files that wait on the clock first (below a CPU-second a second), those
    # that keep their core busy all the same after them (the controllers guide's, whose
    # sweep, report and benchmark come before its real-time block).
    busy = {n for n in files & realtime if cpu.get(n, 0.0) >= cost(n) > 0}
    first = by_cost(files & realtime - busy) + by_cost(busy)
    others = by_cost(files - realtime)
    parallel: list[str] = []
    left = sum(cost(n) for n in first if n not in busy)  # the time of those that wait
    for name in others:
        if left <= 0:
            break
        if name in durations and cpu.get(name, 0.0) >= PARALLEL_CPU_PER_S * cost(name) > 0:
            parallel.append(name)
            left -= cost(name)
    return first + parallel + [n for n in others if n not in parallel]


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


def write_durations(
    times: dict[str, float], cpu: dict[str, float] | None = None, path: Path = DURATIONS
) -> None:
    """Writes the measured times [s] by file, longest first, each with its CPU [s] where
    ``cpu`` has it, to ``path``."""
    cpu = cpu or {}
    rows = {
        name: {"wall": round(wall, 1), **({"cpu": round(cpu[name], 1)} if name in cpu else {})}
        for name, wall in sorted(times.items(), key=lambda kv: -kv[1])
    }
    path.write_text(json.dumps(rows, indent=1) + "\n")
