"""Real-time priority for what a real-time test paces to the wall clock (tests/run_lock.py).

A real arm's driver and the client that commands it run at a real-time priority (Linux's
``SCHED_FIFO``, as ``chrt -f`` gives it): a woken process of that class takes a core from
any ordinary one at once. The real-time tests start ``doorlab sim-driver``, ``doorlab run
--hardware`` and ``doorlab identify`` so (:func:`preexec`), and a test that answers statuses
itself does so with every thread of its process in that class (:func:`realtime_process`:
the main thread alone waited for the GIL behind pytest-xdist's I/O thread when that one,
holding it, was preempted by a busy neighbour, and answered statuses in bursts). Then the
suite's ordinary tests may run beside them: a simulation running flat out on every core
delays none of their wake-ups, and the workers keep every core busy while the real-time
tests, which use a fraction of a core, wait on the wall clock.

Only a process allowed to (root, ``CAP_SYS_NICE``, or an ``RLIMIT_RTPRIO`` above 0) gets
that class; elsewhere, or with ``DOORLAB_TEST_REALTIME_PRIORITY=0``, :func:`problem` says
why, and the real-time tests run beside nothing but each other (conftest.py).
"""

from __future__ import annotations

import contextlib
import functools
import os
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

PRIORITY = 10
"""The ``SCHED_FIFO`` priority [1-99] (below the kernel's interrupt threads, 50)."""
ENV = "DOORLAB_TEST_REALTIME_PRIORITY"
"""Set to 0 to run the real-time tests without it (as where it cannot be had)."""


def _fifo() -> None:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(PRIORITY))


@functools.cache
def problem() -> str | None:
    """Why the paced processes cannot have real-time priority here (None: they can)."""
    if os.environ.get(ENV, "1").strip() == "0":
        return f"{ENV}=0"
    if not hasattr(os, "SCHED_FIFO"):
        return "no SCHED_FIFO on this platform"
    box: dict = {}

    def probe() -> None:  # a thread of its own: the test thread's class is left alone
        try:
            _fifo()
        except OSError as e:
            box["error"] = f"SCHED_FIFO refused ({e.strerror}): not root, no CAP_SYS_NICE"

    thread = threading.Thread(target=probe)
    thread.start()
    thread.join()
    return box.get("error")


def preexec() -> Callable[[], None] | None:
    """A ``preexec_fn`` for a paced process: real-time priority (None where it cannot be had)."""
    return None if problem() else _fifo


@contextlib.contextmanager
def realtime_process() -> Iterator[None]:
    """Every thread of this process at real-time priority for the block (where it can be had;
    a thread started meanwhile keeps its creator's class), each put back after it."""
    if problem():
        yield
        return
    saved = []
    for entry in Path("/proc/self/task").iterdir():
        tid = int(entry.name)
        try:
            saved.append((tid, os.sched_getscheduler(tid), os.sched_getparam(tid)))
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(PRIORITY))
        except OSError:  # a thread that ended meanwhile
            continue
    try:
        yield
    finally:
        for tid, policy, param in saved:
            try:
                os.sched_setscheduler(tid, policy, param)
            except OSError:
                continue
