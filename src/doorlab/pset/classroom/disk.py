"""Room on the disks a class is graded on: the class folder's and ``TMPDIR``'s.

No student's code writes to either: what it writes goes to its view's tmpfs (its own memory,
:mod:`doorlab.pset.isolation.bwrap_root`). What does go there is the grader's: each grading's
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
