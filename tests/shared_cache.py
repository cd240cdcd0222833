"""Values computed once per test run and shared by pytest-xdist's workers.

conftest.py makes a folder for the run (``$DOORLAB_TEST_RUN_DIR``, removed at its end) before
the workers start; :func:`shared_text` computes a value in the first worker that asks for it,
under a lock, and the others read it from there (a reference grading takes a minute here);
:func:`shared_folder` does the same for a folder (the 2019 notebook's run: half a minute).
Without the folder (this module imported outside the suite) it just computes.
"""

from __future__ import annotations

import fcntl
import os
import shutil
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


def shared_folder(name: str, fill: Callable[[Path], str], fallback: Path) -> tuple[Path, str]:
    """A folder that ``fill(folder)`` writes once per run, and the text it returns
    (``name``: the folder's name in the run's folder; outside the suite, ``fallback``).

    The first worker that asks fills it under a lock (a folder left half-written by a
    worker that died is filled again); the others wait, then share it as it is: a test must
    not change what another reads there."""
    base = run_dir()
    if base is None:
        fallback.mkdir(parents=True, exist_ok=True)
        return fallback, fill(fallback)
    folder, done = base / name, base / f"{name}.done"
    with open(base / f"{name}.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if done.is_file():
            return folder, done.read_text()
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir()
        text = fill(folder)
        partial = base / f".{name}.done.partial"
        partial.write_text(text)
        os.replace(partial, done)
        return folder, text
