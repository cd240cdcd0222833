"""What a test run cost in CPU time, beside its wall time (the line conftest.py prints at the end).

The run's processes are pytest's own and everything below it that was waited for: the
pytest-xdist workers (reaped before the terminal summary) and, through them, every command
and episode a test ran and waited for. A process nobody waited for (one a test left behind,
reparented to init) is not counted, so the figure is a lower bound. Two cores give
``2 x wall`` core-seconds; CPU seconds above the cores' share of a time budget mean no order
of the tests fits the run in that budget (docs/development.md).
"""

from __future__ import annotations

import os
import resource
import time
from dataclasses import dataclass


@dataclass(frozen=True)
class Mark:
    """A point of the run: the wall clock [s] and the CPU used so far [s]."""

    wall: float  # time.monotonic() [s]
    user: float  # this process's and its waited-for descendants' user time [s]
    system: float  # the same, in the kernel [s]


def mark() -> Mark:
    """The CPU this process and its waited-for descendants used so far, and the clock."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return Mark(
        time.monotonic(), own.ru_utime + children.ru_utime, own.ru_stime + children.ru_stime
    )


def cores() -> int:
    """The cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def used(start: Mark, end: Mark) -> float:
    """The CPU used between two marks [s], user and system."""
    return (end.user - start.user) + (end.system - start.system)


def summary(start: Mark, end: Mark, core_count: int) -> str:
    """One line (under 90 characters: a page shows it whole): the CPU seconds between two marks
    against the core-seconds of their wall time."""
    user, system = end.user - start.user, end.system - start.system
    wall = end.wall - start.wall
    available = core_count * wall
    share = 100.0 * used(start, end) / available if available > 0 else 0.0
    return (
        f"CPU: {used(start, end):.0f} CPU-s (user {user:.0f}, system {system:.0f}) in {wall:.0f} s "
        f"on {core_count} cores: {share:.0f} % of {available:.0f} core-s"
    )
