"""Gradebook exports of a class's sheet: one row per student (each member of a group gets the
group's grade), the late penalty and the instructor's adjustments applied.

- ``canvas.csv``, Canvas's gradebook import (Instructure's guide "How do I import grades in
  the Gradebook?",
  https://community.canvaslms.com/t5/Instructor-Guide/How-do-I-import-grades-in-the-Gradebook/ta-p/807).
  With ``--roster`` (the course's own Canvas gradebook export,
  :mod:`doorlab.pset.classroom.canvas`): that export's students, in its order, with Canvas's
  own ``ID``, names ("Last, First"), SIS ids and sections, and this assignment's column.
  Without: one row per student of the class under the columns Canvas's export starts with
  (``Student``, ``ID``, ``SIS User ID``, ``SIS Login ID``, ``Section``), the name in Canvas's
  order ("Last, First"), ``SIS User ID`` Gradescope's SID and ``SIS Login ID`` the e-mail
  (``ID`` and ``Section`` Gradescope does not know: empty; Canvas then matches a row by the
  SIS ids, which only holds where Gradescope's SID is Canvas's SIS User ID). Then one column
  named after the assignment (the assignment file's ``title``) and a second row ``Points
  Possible``, as Canvas's export writes it. A submission whose grading failed, or a student
  without one, leaves its cell empty (Canvas then changes nothing).
- ``gradescope.csv``: one row per student keyed by Gradescope's roster identifiers (name,
  e-mail, SID: https://guides.gradescope.com/hc/en-us/articles/21926598776333) with the
  total, the points possible, the submission, its time, the late penalty, the adjustments
  and the status: for a gradebook other than Canvas's that imports a column of grades by
  e-mail or student id (Moodle's and Blackboard's CSV grade imports map such a column), or
  for the course's records. (Gradescope itself takes no grades from a file for a
  programming assignment: its autograder's results are its grades.)

No export ever holds two rows for one student or one row for two: a class where two
students share an SID or an e-mail (a self-enrolled course's typed SID) is refused before
anything is graded, in one line naming both submissions and how to resolve it
(:func:`check_exports`: an identity row in ``adjustments.csv``, or the roster).

Every cell goes through the sheet's guard (:func:`doorlab.pset.classroom.roster.sheet_text`'s: no
spreadsheet formula, no control character).
"""

from __future__ import annotations

import csv
import io

from doorlab.errors import ConfigError
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
    "Adjustment",
    "Status",
)


def students(submissions, rows: dict[str, dict]) -> list[dict]:
    """One entry per student of each submission, in order: ``{"name", "sid", "email",
    "row", "submission"}`` (each member of a group with the group's row). Two entries never
    share an SID or e-mail: :func:`identity_conflict` refuses such a class first."""
    return [
        {**person, "row": rows.get(submission.id), "submission": submission}
        for submission in submissions
        for person in submission.submitters
        if person.get("sid") or person.get("email") or person.get("name")
    ]


def _who(submission, person: dict) -> str:
    name, email = person.get("name", ""), person.get("email", "")
    return f"{submission.id} ({', '.join(x for x in (name, email) if x) or 'no name'})"


def identity_conflict(submissions) -> str | None:
    """The first SID or e-mail that two students of the class share (one line naming both
    submissions), or None: an export keyed by them would hold one row for two students."""
    seen: dict[tuple[str, str], tuple] = {}
    for submission in submissions:
        for person in submission.submitters:
            keys = [("SID", person.get("sid", "")), ("e-mail", person.get("email", "").lower())]
            for kind, value in keys:
                if not value:
                    continue
                if (kind, value) in seen:
                    other, first = seen[(kind, value)]
                    return (
                        f"{kind} {value!r} is both {_who(other, first)}'s and "
                        f"{_who(submission, person)}'s"
                    )
                seen[(kind, value)] = (submission, person)
    return None


RESOLVE = (
    "correct the student's identity in the class's adjustments.csv (a row: student, sid or "
    "email, reason)"
)
"""How an identity conflict is resolved (every refusal says it)."""


def check_exports(formats, submissions, roster=None) -> None:
    """Refuses, before anything is graded, exports that would give two students one row.

    Raises:
        ConfigError: One line naming both submissions and how to resolve it.
    """
    from doorlab.pset.classroom import canvas

    for fmt in formats:
        if fmt == "canvas" and roster is not None:
            people = [(s.id, p) for s in submissions for p in s.submitters]
            found = canvas.conflicts(roster, people)
            how = f"{RESOLVE}, or the roster"
        else:
            found = identity_conflict(submissions)
            how = RESOLVE + (
                " or give --roster (Canvas's export: matched by e-mail first)"
                if fmt == "canvas"
                else ""
            )
        if found is not None:
            raise ConfigError(f"--export {fmt}: {found}: one row would replace the other; {how}")


def _score(row: dict | None) -> str:
    if row is None or row.get("status") not in ("graded", "not_graded"):
        return ""
    return _cell(float(row.get("total") or 0.0))


def canvas_text(submissions, rows: dict[str, dict], assignment, roster=None):
    """``canvas.csv``'s text and its notes: with ``roster`` (the course's Canvas export,
    :mod:`doorlab.pset.classroom.canvas`) its students filled in; without, one row per
    student of the class."""
    from doorlab.pset.classroom import canvas

    people = students(submissions, rows)
    best = max((float(r.get("max_total") or 0) for r in rows.values() if r), default=0.0)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    if roster is None:
        writer.writerow([*CANVAS_COLUMNS, _cell(assignment.title)])
        writer.writerow(["Points Possible", "", "", "", "", _cell(best)])
        for p in people:
            name = canvas.sortable_name(p.get("name", ""))
            row = [name, "", p.get("sid", ""), p.get("email", ""), "", _score(p["row"])]
            writer.writerow([_cell(x) for x in row])
        return out.getvalue(), []
    matched, notes = canvas.match(roster, people)
    grades, unmatched = {}, []
    for p in people:
        index = matched.get(canvas._key(p))
        if index is None:
            unmatched.append(f"{p.get('name', '')} ({p.get('email') or p.get('sid') or '-'})")
        else:
            grades[index] = _score(p["row"])
    table, missing = canvas.fill(roster, grades, assignment.title, _cell(best))
    for line in table:
        writer.writerow([_cell(x) for x in line])
    if unmatched:
        notes.append(
            f"{len(unmatched)} student(s) of the class are not in the roster (no row for them): "
            + "; ".join(unmatched[:20])
            + (" ..." if len(unmatched) > 20 else "")
        )
    if missing:
        notes.append(
            f"{len(missing)} student(s) of the roster have no submission (their cell is empty: "
            "Canvas changes nothing): "
            + "; ".join(missing[:20])
            + (" ..." if len(missing) > 20 else "")
        )
    return out.getvalue(), notes


def gradescope_text(submissions, rows: dict[str, dict]) -> tuple[str, list[str]]:
    """``gradescope.csv``'s text and its warnings."""
    people, notes = students(submissions, rows), []
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
                _cell(row.get("adjustment")),
                _cell(row.get("status", "")),
            ]
        )
    return out.getvalue(), notes


def export_text(
    fmt: str, submissions, rows: dict[str, dict], assignment, roster=None
) -> tuple[str, list[str]]:
    """The export ``fmt`` (one of :data:`FORMATS`; ``roster``: Canvas's, for ``canvas``)."""
    if fmt == "canvas":
        return canvas_text(submissions, rows, assignment, roster)
    return gradescope_text(submissions, rows)
