"""Runs one grading job in its own process: ``python -m doorlab.pset.worker JOB FOLDER OUT``.

JOB is ``unit:<name>``, ``student:<controller>`` or ``reference:<controller>``; the result
(a JSON object) goes to OUT. A student's exception becomes ``{"passed": false, "error": ...}``
with the end of its traceback; the grader enforces the time limit by killing this process.
"""

from __future__ import annotations

import json
import sys
import traceback
from pathlib import Path

TRACEBACK_LINES = 12
"""Lines of a student's traceback kept in a test's output."""


def run_job(job: str, folder: Path) -> dict:
    """Runs one job and returns its JSON-ready result."""
    from doorlab.pset import checks

    kind, _, name = job.partition(":")
    if kind == "unit":
        return getattr(checks, f"check_{name}")(folder)
    if kind == "student":
        return {"figures": checks.student_episode(folder, name)}
    if kind == "reference":
        return {"figures": checks.reference_episode(name)}
    raise ValueError(f"unknown job {job!r}")


def main(argv: list[str]) -> int:
    job, folder, out = argv
    folder_path = Path(folder).resolve()
    try:
        result = run_job(job, folder_path)
    except BaseException as e:  # noqa: BLE001 - a student's code may raise anything
        frames = traceback.extract_tb(e.__traceback__)
        # Show the student's own frames (files in the folder); doorlab's only if there are none.
        mine = [f for f in frames if Path(f.filename).resolve().is_relative_to(folder_path)]
        shown = traceback.format_list(mine or frames[-3:])
        tail = "".join(shown).rstrip().splitlines()[-TRACEBACK_LINES:]
        message = str(e).strip().splitlines()[0] if str(e).strip() else ""
        result = {
            "passed": False,
            "error": f"{type(e).__name__}: {message}".rstrip(": "),
            "output": "\n".join(tail),
        }
    Path(out).write_text(json.dumps(result, default=str))
    return 0


if __name__ == "__main__":
    import os

    os.environ.setdefault("MPLBACKEND", "Agg")
    sys.exit(main(sys.argv[1:]))
