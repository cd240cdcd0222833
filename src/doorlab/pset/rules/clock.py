"""A test's time, as the trusted side counts it: what the test had, not what a loaded machine took.

A test's time limit (60 s a unit test, 150 s an episode) bounds the student's code: an endless
loop, a long sleep. Counted in wall time it also counted what the test never had: the time
its processes waited for a CPU while other gradings (or anything else on the machine) ran,
so a neighbour's load could fail an honest submission, in the student's words. The
:class:`Clock` of a test counts instead:

- its *time*: the wall time since the test started, less the time the trusted process
  waited for a CPU (the kernel's run-queue delay, ``/proc/PID/schedstat``: runnable, not
  running); the limit is on that. Where the kernel keeps no such count, wall time;
- at most :data:`HARD_FACTOR` times the limit in wall time, whatever it waited.

When the limit is reached, :meth:`Clock.starved` tells whether it is the student's: not
when the test reached the wall-time bound first, nor when the student's processes used little
CPU (under :data:`LITTLE_CPU` of the wall time) while the test's two processes (the trusted
one and the student's) spent :data:`STARVED` of it or more waiting for a CPU: that is the
grader's error (a loaded machine), never a verdict; the student's code that sleeps, blocks
or computes past its limit is (it uses the CPU, or does not wait for one).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

UNIT_TIME_LIMIT_S = 60.0
"""Time limit of a unit test [s] (a correct one takes 2-5 s)."""
EPISODE_TIME_LIMIT_S = 150.0
"""Time limit of an episode [s] (a correct one takes 5-15 s on a busy 2-core machine)."""
HARD_FACTOR = 3.0
"""A test ends after at most this many times its limit in wall time."""
LITTLE_CPU = 0.1
"""The student's processes used "little CPU" under this fraction of the wall time."""
STARVED = 0.5
"""A test was starved when its processes waited for a CPU this fraction of the wall time."""
_TICK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def schedstat(pid: int | None = None) -> tuple[float, float] | None:
    """(CPU time, run-queue wait) of process ``pid``'s main thread [s] (None: unknown)."""
    where = "self" if pid is None else str(pid)
    try:
        fields = Path(f"/proc/{where}/schedstat").read_text().split()
        return int(fields[0]) * 1e-9, int(fields[1]) * 1e-9
    except (OSError, ValueError, IndexError):
        return None


def process_cpu(pid: int) -> float | None:
    """CPU time of process ``pid`` and of its children it reaped [s] (None: gone)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_bytes()
    except OSError:
        return None
    fields = stat[stat.rfind(b")") + 2 :].split()
    try:
        return sum(int(fields[i]) for i in (11, 12, 13, 14)) / _TICK
    except (ValueError, IndexError):
        return None


class Clock:
    """One test's time (see the module); usable as a channel deadline
    (:meth:`remaining`).

    Args:
        limit: The test's time limit [s].
    """

    def __init__(self, limit: float):
        self.limit = float(limit)
        self.start = time.monotonic()
        own = schedstat()
        self._wait0 = None if own is None else own[1]
        self._student: tuple[int, Callable[[], float | None], float, float] | None = None

    def watch_student(self, pid: int, cpu: Callable[[], float | None] | None = None) -> None:
        """The student's main process ``pid`` (outside any PID namespace) and how to read
        the CPU time of all its processes (default: ``pid``'s own and its reaped children's)."""
        cpu = cpu or (lambda: process_cpu(pid))
        stats = schedstat(pid)
        self._student = (pid, cpu, cpu() or 0.0, stats[1] if stats else 0.0)

    def wall(self) -> float:
        return time.monotonic() - self.start

    def waited(self) -> float:
        """How long the trusted process waited for a CPU since the test started [s]."""
        own = schedstat()
        if own is None or self._wait0 is None:
            return 0.0
        return max(0.0, own[1] - self._wait0)

    def elapsed(self) -> float:
        """The test's time so far [s]."""
        return self.wall() - self.waited()

    def remaining(self) -> float:
        """Wall time the test may still wait before its time is spent [s] (0: spent)."""
        wall = self.wall()
        hard = HARD_FACTOR * self.limit - wall
        return max(0.0, min(self.limit - (wall - self.waited()), hard))

    def student_use(self) -> tuple[float, float]:
        """(CPU time of the student's processes, run-queue wait of its main process) since
        :meth:`watch_student` [s] (zeros when nothing is watched)."""
        if self._student is None:
            return 0.0, 0.0
        pid, cpu, cpu0, wait0 = self._student
        now = cpu()
        stats = schedstat(pid)
        used = max(0.0, (now if now is not None else cpu0) - cpu0)
        return used, max(0.0, (stats[1] - wait0) if stats else 0.0)

    def starved(self) -> str | None:
        """Why a test whose time ran out is the grader's error (None: it is a verdict)."""
        wall, waited = self.wall(), self.waited()
        cpu, student_wait = self.student_use()
        said = (
            f"in {wall:.0f} s of wall time the test had {wall - waited:.0f} s (the grader "
            f"waited {waited:.0f} s for a CPU, the student's process {student_wait:.0f} s; "
            f"the student's processes used {cpu:.1f} s of CPU)"
        )
        if wall - waited < self.limit - 1e-3:
            return f"the machine is too loaded to time this test: {said}"
        if cpu < LITTLE_CPU * wall and waited + student_wait >= STARVED * wall:
            return f"the machine is too loaded to time this test: {said}"
        return None


def remaining(deadline) -> float | None:
    """Seconds left before ``deadline``: a :func:`time.monotonic` time, a :class:`Clock`
    (anything with ``remaining()``) or None (no deadline)."""
    if deadline is None:
        return None
    if hasattr(deadline, "remaining"):
        return deadline.remaining()
    return deadline - time.monotonic()
