"""Who may run now, shared by the suite's pytest-xdist workers (conftest.py).

Ordinary tests run beside each other; tests with real-time sections (the ``realtime``
fixture: LCM processes paced to the wall clock, tolerances derived from their latency) run
beside each other; never one of each. A real-time section needs the CPU the moment its
processes wake; each uses a fraction of a core (a driver and a client at 200 Hz), so two of
them on two workers share the cores well, and so does a real-time test's light work outside
its sections (reading logs, a comparison), while an ordinary test (a class graded by several
processes, a simulation per core) would delay their wake-ups. A real-time test's heavy work
(a one-process episode running flat out) runs at idle priority (conftest's ``heavy``): it
gets a core only when no section's process wants it (a simulation at normal priority beside
two sections made statuses 10 ms late on two cores).

Each worker has a slot in a small state file (its pid and what it does: ``test``,
``realtime``, or ``waiting`` to run real-time), read and written under an ``flock``; a worker
waits by polling it every :data:`RunLock.POLL_S`. A worker waiting to run real-time keeps new
ordinary tests from starting, so it starts as soon as the ordinary tests in progress end; a
slot whose process is gone (a crashed worker) counts for nothing.
"""

from __future__ import annotations

import fcntl
import json
import os
import time
from collections.abc import Callable
from pathlib import Path

STATE_FILE = "tests.state.json"
"""In the run's folder: {worker: [pid, state]}."""
WAITS_FILE = "lock_waits.jsonl"
"""In the run's folder: each wait for the lock longer than :data:`RECORDED_WAIT_S`."""
RECORDED_WAIT_S = 0.1


class RunLock:
    """One worker's side of the lock (see the module)."""

    POLL_S = 0.02

    def __init__(self, folder: Path, worker: str):
        self._folder = folder
        self._mutex = open(folder / "tests.lock", "a")  # held for the session
        self._state = folder / STATE_FILE
        self._worker = worker

    def _slots(self) -> dict[str, list]:
        try:
            return json.loads(self._state.read_text())
        except (OSError, ValueError):
            return {}

    def _others(self) -> dict[str, str]:
        """The other live workers' states (under the mutex)."""
        out = {}
        for worker, (pid, state) in self._slots().items():
            if worker == self._worker or state is None:
                continue
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                continue
            out[worker] = state
        return out

    def _set(self, state: str | None) -> None:
        """Sets this worker's slot (under the mutex)."""
        slots = self._slots()
        slots[self._worker] = [os.getpid(), state]
        partial = self._state.with_suffix(f".{self._worker}.partial")
        partial.write_text(json.dumps(slots))
        os.replace(partial, self._state)

    def _enter(self, state: str, free: Callable[[dict[str, str]], bool]) -> None:
        """Waits until ``free(others)`` holds, then takes ``state``, atomically."""
        asked = time.monotonic()
        while True:
            fcntl.flock(self._mutex, fcntl.LOCK_EX)
            try:
                if free(self._others()):
                    self._set(state)
                    break
            finally:
                fcntl.flock(self._mutex, fcntl.LOCK_UN)
            time.sleep(self.POLL_S)
        waited = time.monotonic() - asked
        if waited > RECORDED_WAIT_S:
            with open(self._folder / WAITS_FILE, "a") as f:
                f.write(json.dumps({"worker": self._worker, "for": state, "waited": waited}))
                f.write("\n")

    def _update(self, state: str | None) -> None:
        fcntl.flock(self._mutex, fcntl.LOCK_EX)
        try:
            self._set(state)
        finally:
            fcntl.flock(self._mutex, fcntl.LOCK_UN)

    def test(self) -> None:
        """An ordinary test: once no other worker runs (or waits to run) real-time."""
        self._enter("test", lambda others: not ({"realtime", "waiting"} & set(others.values())))

    def realtime(self) -> None:
        """A real-time test: once no other worker runs an ordinary test."""
        self._update("waiting")
        self._enter("realtime", lambda others: "test" not in others.values())

    def release(self) -> None:
        self._update(None)


def read_waits(folder: Path) -> list[dict]:
    """The recorded waits (:data:`WAITS_FILE`)."""
    path = folder / WAITS_FILE
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text().splitlines()]
