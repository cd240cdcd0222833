"""The 2019 notebook's run, started in the background at the start of a run (the cores' idle time).

The problem set's tests share one run of the notebook's cells (:func:`pset_fixtures.solutions_run`,
a minute of CPU or more: three episodes and a full grading) and the reference figures it
gives (:func:`pset_fixtures.reference`), computed once per test run under a lock
(tests/shared_cache.py) by the first worker that asks. While one worker runs the real-time
files, paced to the wall clock at a fraction of a core, part of the cores stands idle
(docs/development.md); a process that computes those shared values then, at a lower
priority (nice :data:`NICE`: the workers' tests come first), takes that idle time instead of
a worker's later. A worker that asks meanwhile waits on the lock, as it would for another
worker.

It starts only where the paced processes have real-time priority (elsewhere a real-time test
runs beside nothing else: tests/run_lock.py), with the notebook given and the run's shared
folder made, and only when the run collected a test of the problem set. The worker that
starts it waits for it at its session's end (so its CPU is in the run's CPU line,
tests/run_cost.py), or ends it at once when the session was interrupted.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

NICE = 10
"""The process's niceness: about a tenth of a core beside a busy nice-0 process, all of an
idle core."""
SCRIPT = "import pset_fixtures; pset_fixtures.reference()"
"""What it runs (the reference comes from the notebook's run, which it computes first)."""
LOG = "warm_up.log"
"""Its output, in the run's shared folder (a failure is computed again, and reported, by the
first test that asks)."""


def wanted(items: list[pytest.Item]) -> bool:
    """Whether the notebook is given and the run collected a test of the problem set (a
    module that uses pset_fixtures)."""
    import pset_fixtures

    if pset_fixtures.notebook_path() is None:
        return False
    return any(getattr(getattr(item, "module", None), "pset_fixtures", None) for item in items)


def start(run_folder: Path) -> subprocess.Popen:
    """The process that computes the shared notebook run and reference into ``run_folder``."""
    tests = str(Path(__file__).resolve().parent)
    path = os.environ.get("PYTHONPATH")
    env = {**os.environ, "PYTHONPATH": tests if not path else f"{tests}{os.pathsep}{path}"}
    with open(run_folder / LOG, "ab") as log:
        return subprocess.Popen(
            [sys.executable, "-c", SCRIPT],
            cwd=run_folder,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            preexec_fn=lambda: os.nice(NICE),
            start_new_session=True,  # its own process group: the notebook's processes with it
        )


def finish(process: subprocess.Popen, interrupted: bool) -> None:
    """Waits for ``process``; when the session was ``interrupted``, ends its process group
    first (SIGTERM, then SIGKILL after 10 s)."""
    if interrupted and process.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
    process.wait()
