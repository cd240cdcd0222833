"""The order in which the suite's files are handed to pytest-xdist's workers.

``--dist loadfile`` gives a worker a whole file at a time, in the collection's order
(``--no-loadscope-reorder``: otherwise xdist sorts the files by their number of tests). Two
things decide how long the run takes on 2 cores:

- the longest files first (longest-processing-time scheduling): the run then ends on short
  files on both workers, not on one worker's long file while the other idles;
- the real-time files (a test with the ``alone`` fixture: conftest.py) after the long files: a
  real-time section waits until the other worker ends the test it is in, and a long test
  there (a class graded in a half-CPU group, 109 s) kept a worker idle that long. So they come
  once the other worker only has short tests left, with enough of them (:data:`TAIL_S`) to
  run between the sections.

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
TAIL_S = 150.0
"""Non-real-time work left after the real-time files start [s]: what the other worker runs
between the real-time sections (about the sections' length outside their alone parts)."""


def read_durations(path: Path = DURATIONS) -> dict[str, float]:
    """The recorded times by file name ({} without the file, or an unreadable one)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return {str(k): float(v) for k, v in data.items()} if isinstance(data, dict) else {}


def file_order(files: Iterable[str], realtime: set[str], durations: dict[str, float]) -> list[str]:
    """The files in the order they should run (see the module): the others longest first,
    the real-time ones (longest first) where the others left after them sum to ``TAIL_S``."""

    def cost(name: str) -> float:
        return durations.get(name, UNKNOWN_S)

    def by_cost(names: Iterable[str]) -> list[str]:
        return sorted(names, key=lambda n: (-cost(n), n))

    files = set(files)
    others, timed = by_cost(files - realtime), by_cost(files & realtime)
    left, cut = 0.0, len(others)
    while cut > 0 and left < TAIL_S:
        cut -= 1
        left += cost(others[cut])
    return others[:cut] + timed + others[cut:]


def write_durations(times: dict[str, float], path: Path = DURATIONS) -> None:
    """Writes the measured times [s] by file, longest first, to ``path``."""
    ordered = dict(sorted(((k, round(v, 1)) for k, v in times.items()), key=lambda kv: -kv[1]))
    path.write_text(json.dumps(ordered, indent=1) + "\n")
