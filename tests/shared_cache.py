"""Values computed once per test run and shared by pytest-xdist's workers.

conftest.py makes a folder for the run (``$DOORLAB_TEST_RUN_DIR``, removed at its end) before
the workers start; :func:`shared_text` computes a value in the first worker that asks for it,
under a lock, and the others read it from there (a reference grading takes a minute here).
Without the folder (this module imported outside the suite) it just computes.
"""

from __future__ import annotations

import fcntl
import os
from collections.abc import Callable
from pathlib import Path

RUN_DIR_ENV = "DOORLAB_TEST_RUN_DIR"


def run_dir() -> Path | None:
    """The run's shared folder, or None outside the suite."""
    folder = os.environ.get(RUN_DIR_ENV)
    return Path(folder) if folder else None


def shared_text(name: str, compute: Callable[[], str]) -> str:
    """The text ``compute()`` returns, computed once per run (``name``: a file name)."""
    folder = run_dir()
    if folder is None:
        return compute()
    path = folder / name
    with open(folder / f"{name}.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # the others wait while one computes
        if path.is_file():
            return path.read_text()
        text = compute()
        partial = folder / f".{name}.partial"
        partial.write_text(text)
        os.replace(partial, path)
        return text
