"""Room for a class: each student's view's memory, and the disks it is graded on.

**Memory** (:mod:`doorlab.pset.isolation.memory`): on local workers, ``grade-all`` plans each
view's limit once for the class (:func:`class_memory`: ``--jobs`` gradings at once, one view
each, in the room this machine or its container has), and puts the grader's own processes last
in line for the OOM killer; on a cluster each worker plans its own (:func:`worker_view_memory`).
The summary states the limits and names the submissions whose view the kernel ended
(:func:`memory_lines`).

**Disk**: the class folder's and ``TMPDIR``'s. No student's code writes to either: what it
writes goes to its view's tmpfs (its own memory, :mod:`doorlab.pset.isolation.bwrap_root`).
What does go there is the grader's: each grading's
private folders in ``TMPDIR`` (the student side's copy, the submission's, a few MiB), and each
submission's results and feedback page in the class folder (about 0.5 MiB). A disk that
something else fills must cost no grade, no sheet and no traceback: ``grade-all`` checks both
for :data:`ROOM_BYTES` before it starts (refused in one line, nothing written) and before it
hands each submission to a worker (else that submission is an ``error`` row that ``--resume``
grades again); a write of the class folder that fails anyway (ENOSPC) is one line and, for a
submission's results, an ``error`` row, and leaves every file and the folder's manifest
agreeing (:func:`doorlab.runtime.folders.replace_recorded`), so the next run goes on.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from doorlab.errors import OutputError

ROOM_BYTES = 16 << 20
"""Free space kept in the class folder's file system and in ``TMPDIR`` to grade one more
submission [bytes] (a grading's private folders hold a few MiB; its results and page about
0.5 MiB)."""


def free_bytes(path: str | Path) -> int | None:
    """Bytes an ordinary write may still use on ``path``'s file system (its nearest existing
    folder), or None if it cannot be asked."""
    path = Path(os.path.abspath(path))
    while not path.exists() and path != path.parent:
        path = path.parent
    try:
        stats = os.statvfs(path)
    except OSError:
        return None
    return stats.f_bavail * stats.f_frsize


def room_problem(out: str | Path, *, tmpdir: bool = True) -> str | None:
    """Why one more submission cannot be graded here (too little room in the class folder's
    file system, or in ``TMPDIR`` with ``tmpdir``: local workers), or None."""
    places = [(Path(out), "the class folder")]
    if tmpdir:
        places.append((Path(tempfile.gettempdir()), "TMPDIR"))
    for where, label in places:
        free = free_bytes(where)
        if free is not None and free < ROOM_BYTES:
            return (
                f"{label} ({where}) has {free >> 20} MiB free, and a grading keeps "
                f"{ROOM_BYTES >> 20} MiB"
            )
    return None


def check_room(out: str | Path, *, tmpdir: bool = True) -> None:
    """Refuses to start a class without room (see :func:`room_problem`).

    Raises:
        OutputError: One line naming the folder and what is free.
    """
    why = room_problem(out, tmpdir=tmpdir)
    if why is not None:
        raise OutputError(f"cannot grade: {why}; free some space first")


def write_failure(path: str | Path, error: BaseException) -> OutputError:
    """One line for a write of the class folder that failed."""
    if isinstance(error, OutputError):
        return error
    text = error.strerror if isinstance(error, OSError) and error.strerror else str(error)
    return OutputError(f"cannot write {path}: {text}")


# Memory -----------------------------------------------------------------------------------


def class_memory(jobs: int, todo: int, scheduler: str | None):
    """Each student's view's memory limit on local workers (``jobs`` gradings at once, one
    view each), or None on a cluster (each worker plans its own); and the grader's own
    processes last in line for the OOM killer (:mod:`doorlab.pset.isolation.memory`).

    Raises:
        MemoryRoomError: Too little memory for ``jobs`` views (the message says how many fit).
    """
    from doorlab.pset.isolation.memory import plan, protect_trusted

    protect_trusted()
    if scheduler is not None or not todo:
        return None
    at_once = min(jobs, todo)
    return plan(views=at_once, gradings=at_once)


def worker_view_memory() -> int:
    """On a cluster's worker: its view's memory limit, from its own room (its Dask memory
    limit where it has one: Dask's share of its machine for it)."""
    from doorlab.pset.isolation.memory import dask_worker_room, plan, room

    found = min(filter(None, [room(), dask_worker_room()]), key=lambda r: r.bytes)
    return plan(views=1, gradings=1, own_bytes=0, found=found, strict=False).view_bytes


def memory_lines(plan, results: dict[str, dict], graded: list[str], *, local: bool) -> list[str]:
    """The summary's lines on memory: the views' limits (``plan``: the class's, or on a
    cluster the workers' own, from the results), the submissions the kernel ended at theirs."""
    lines = [plan.line()] if plan is not None else []
    if plan is None and not local:
        lines += _cluster_memory(results, graded)
    return lines + _memory_verdicts(results)


def _cluster_memory(results: dict[str, dict], graded: list[str]) -> list[str]:
    """The summary's line on the views' memory limits the cluster's workers chose."""
    from doorlab.pset.isolation.memory import mib

    found = set()
    for sid in graded:
        sandbox = ((results.get(sid) or {}).get("extra_data") or {}).get("sandbox") or {}
        value = (sandbox.get("cgroup") or {}).get("view_memory_bytes")
        if isinstance(value, int):
            found.add(value)
    if not found:
        return []
    shown = mib(min(found)) if len(found) == 1 else f"{mib(min(found))} to {mib(max(found))}"
    return [f"memory: each student's view at most {shown} (each worker's share of its room)"]


def _memory_verdicts(results: dict[str, dict]) -> list[str]:
    """The summary's line on the submissions whose view the kernel ended for memory."""
    from doorlab.pset.isolation.memory import ended_for_memory

    ended = [sid for sid, r in results.items() if ended_for_memory(r)]
    if not ended:
        return []
    shown = ", ".join(ended[:5]) + (f" and {len(ended) - 5} more" if len(ended) > 5 else "")
    return [
        f"memory: the kernel ended the code of {len(ended)} submission"
        f"{'s' if len(ended) != 1 else ''} at its view's limit ({shown}): its own tests' "
        "verdict, no other grading touched"
    ]
