"""A submission's own due date: an extension, from the class's file or from Gradescope.

The course's late policy (:mod:`doorlab.pset.classroom.late`) has one due date; a student
given more time has their own:

- ``grade-all``: ``DIR/extensions.csv``, the instructor's file in the class's folder
  (columns ``student``, ``due``, ``reason``; ``student`` a submission's id, a student id or
  an e-mail; ``due`` ISO 8601 with its UTC offset), read by every run (a new or changed row
  re-applies the late policy to that submission, nothing simulated);
- ``run_autograder`` on Gradescope: Gradescope's own due date of the submission in
  ``/autograder/submission_metadata.json``
  (https://gradescope-autograders.readthedocs.io/en/latest/submission_metadata/): each
  user's ``assignment.due_date`` where Gradescope gives one (a student's extension), else the
  assignment's ``due_date``.

Either only ever extends: the submission's due date is the later of the course's and its own.
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass
from pathlib import Path

from doorlab.errors import ConfigError
from doorlab.pset.classroom.tables import one_submission, read_table
from doorlab.pset.isolation.safe_text import clean_text
from doorlab.runtime.inputs import quote_text

EXTENSIONS_CSV = "extensions.csv"
"""The instructor's extensions in a class's folder."""
COLUMNS = ("student", "due", "reason")


@dataclass(frozen=True)
class OwnDue:
    """A submission's own due date.

    Attributes:
        due: The due date (aware).
        why: Where it comes from, as the late policy's line says it.
    """

    due: datetime.datetime
    why: str


def _parse(text: str, where: str) -> datetime.datetime:
    try:
        due = datetime.datetime.fromisoformat(text.strip())
    except ValueError:
        due = None
    if due is None or due.utcoffset() is None:
        raise ConfigError(
            f"{where}: due must be a date and time in ISO 8601 with its UTC offset, e.g. "
            f"2024-03-04T23:59:00-05:00, got {quote_text(text)}"
        )
    return due


def read_extensions(out: Path, submissions) -> dict[str, OwnDue]:
    """The extensions of ``out/extensions.csv`` by submission id (none without the file).

    Raises:
        ConfigError: A row names no submission or several, has no valid ``due``, or a
            submission has two rows (one line naming the file and row).
    """
    found: dict[str, OwnDue] = {}
    rows: dict[str, int] = {}
    for row in read_table(Path(out) / EXTENSIONS_CSV, COLUMNS, ("student", "due")):
        where = f"{EXTENSIONS_CSV} row {row['row']}"
        submission = one_submission(row["student"], submissions, where)
        due = _parse(row["due"], where)
        if submission.id in found:
            raise ConfigError(
                f"{where}: {submission.id} has an extension already (row "
                f"{rows[submission.id]}); keep one row per submission"
            )
        reason = clean_text(row["reason"], 200) or "no reason given"
        found[submission.id] = OwnDue(due, f"an extension ({EXTENSIONS_CSV}: {reason})")
        rows[submission.id] = row["row"]
    return found


def gradescope_due(metadata: object) -> OwnDue | None:
    """The submission's own due date in Gradescope's ``submission_metadata.json`` data: the
    latest of its users' ``assignment.due_date`` (Gradescope's per-student due date, an
    extension), else the assignment's ``due_date``; None without one."""
    from doorlab.pset.classroom.late import submission_time

    if not isinstance(metadata, dict):
        return None
    own = []
    for user in metadata.get("users") or []:
        entry = user.get("assignment") if isinstance(user, dict) else None
        when = submission_time(entry.get("due_date")) if isinstance(entry, dict) else None
        if when is not None:
            own.append(when)
    if own:
        return OwnDue(max(own), "Gradescope's due date for this submission (its extension)")
    assignment = metadata.get("assignment")
    when = submission_time(assignment.get("due_date")) if isinstance(assignment, dict) else None
    return None if when is None else OwnDue(when, "Gradescope's due date for this assignment")
