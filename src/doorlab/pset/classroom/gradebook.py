"""Gradebook exports of a class's sheet: one row per student (each member of a group gets the
group's grade), the late penalty applied.

- ``canvas.csv``, Canvas's gradebook import (Instructure's guide "How do I import grades in
  the Gradebook?",
  https://community.canvaslms.com/t5/Instructor-Guide/How-do-I-import-grades-in-the-Gradebook/ta-p/807):
  the columns Canvas's own export starts with and its import requires, ``Student``, ``ID``,
  ``SIS User ID``, ``SIS Login ID``, ``Section``, then one column named after the assignment
  (the assignment file's ``title``: a new column creates the assignment, an existing
  assignment's name updates it), and a second row ``Points Possible`` with its points, as
  Canvas's export writes it. Canvas matches a row to a student by these identifiers: here
  ``SIS User ID`` is Gradescope's SID and ``SIS Login ID`` the student's e-mail (``ID``,
  Canvas's own number, is not known to Gradescope; leave it empty). A submission whose
  grading failed, or a student without one, leaves its cell empty (Canvas then changes
  nothing).
- ``gradescope.csv``: Gradescope's roster columns (its roster import names a student by name,
  e-mail and SID: https://guides.gradescope.com/hc/en-us/articles/21926598776333), with the
  grade, the points possible, the submission, its time and the late penalty.

Every cell goes through the sheet's guard (:func:`doorlab.pset.classroom.roster.sheet_text`'s: no
spreadsheet formula, no control character).
"""

from __future__ import annotations

import csv
import io

from doorlab.pset.classroom.roster import _cell

FORMATS = ("canvas", "gradescope")
"""The exports ``grade-all --export`` writes."""
FILES = {"canvas": "canvas.csv", "gradescope": "gradescope.csv"}
CANVAS_COLUMNS = ("Student", "ID", "SIS User ID", "SIS Login ID", "Section")
"""The student columns of Canvas's gradebook import, in its export's order."""
GRADESCOPE_COLUMNS = (
    "Name",
    "Email",
    "SID",
    "Total Score",
    "Max Points",
    "Submission ID",
    "Submission Time",
    "Late Penalty",
    "Status",
)


def students(submissions, rows: dict[str, dict]) -> tuple[list[dict], list[str]]:
    """One entry per student: ``{"name", "sid", "email", "row", "submission"}``; and what
    the export should warn of (a student in two submissions: the later one counts)."""
    chosen: dict[str, dict] = {}
    notes = []
    for submission in submissions:
        row = rows.get(submission.id)
        for person in submission.submitters:
            key = person.get("sid") or person.get("email") or person.get("name")
            if not key:
                continue
            entry = {**person, "row": row, "submission": submission}
            if key in chosen:
                earlier = chosen[key]["submission"]
                later = max((earlier, submission), key=lambda s: s.created_at)
                notes.append(
                    f"{key} is in {earlier.id} and {submission.id}: {later.id} (the later) counts"
                )
                entry = entry if later is submission else chosen[key]
            chosen[key] = entry
    return list(chosen.values()), notes


def _score(row: dict | None) -> str:
    if row is None or row.get("status") not in ("graded", "not_graded"):
        return ""
    return _cell(float(row.get("total") or 0.0))


def canvas_text(submissions, rows: dict[str, dict], assignment) -> tuple[str, list[str]]:
    """``canvas.csv``'s text and its warnings."""
    people, notes = students(submissions, rows)
    best = max((float(r.get("max_total") or 0) for r in rows.values() if r), default=0.0)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow([*CANVAS_COLUMNS, _cell(assignment.title)])
    writer.writerow(["Points Possible", "", "", "", "", _cell(best)])
    for p in people:
        writer.writerow(
            [
                _cell(p.get("name", "")),
                "",
                _cell(p.get("sid", "")),
                _cell(p.get("email", "")),
                "",
                _score(p["row"]),
            ]
        )
    return out.getvalue(), notes


def gradescope_text(submissions, rows: dict[str, dict]) -> tuple[str, list[str]]:
    """``gradescope.csv``'s text and its warnings."""
    people, notes = students(submissions, rows)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(GRADESCOPE_COLUMNS)
    for p in people:
        row = p["row"] or {}
        writer.writerow(
            [
                _cell(p.get("name", "")),
                _cell(p.get("email", "")),
                _cell(p.get("sid", "")),
                _score(p["row"]),
                _cell(row.get("max_total")),
                _cell(p["submission"].id),
                _cell(p["submission"].created_at),
                _cell(row.get("late_penalty")),
                _cell(row.get("status", "")),
            ]
        )
    return out.getvalue(), notes


def export_text(fmt: str, submissions, rows: dict[str, dict], assignment) -> tuple[str, list[str]]:
    """The export ``fmt`` (one of :data:`FORMATS`)."""
    if fmt == "canvas":
        return canvas_text(submissions, rows, assignment)
    return gradescope_text(submissions, rows)
