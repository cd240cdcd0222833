"""Canvas's gradebook: the course's own export filled with the class's grades.

``grade-all --export canvas --roster FILE``: FILE is the course's Canvas gradebook export
(Grades, Export, "Export Entire Gradebook": Instructure's guides "How do I export grades in
the Gradebook?" and "How do I import grades in the Gradebook?",
https://community.canvaslms.com/t5/Instructor-Guide/How-do-I-import-grades-in-the-Gradebook/ta-p/807).
Its first columns name each student as Canvas does: ``Student`` ("Last, First", Canvas's
sortable name), ``ID`` (Canvas's own number), ``SIS User ID``, ``SIS Login ID``, perhaps
``Integration ID``, ``Section``; then one column per assignment (``Title (id)``); its second
row gives each assignment's ``Points Possible``. :func:`fill` writes ``canvas.csv`` for
Canvas's import: every student of the roster, in its order, with those columns as Canvas
wrote them (so Canvas matches each row by its own ``ID``), and one column for this
assignment (the roster's column of the same title when it has one, so the import updates
it; else a new column, which creates the assignment), with the ``Points Possible`` row.

Each student of the class (Gradescope's name, SID and e-mail) is matched to one row of the
roster (:func:`match`): by e-mail against ``SIS Login ID`` (the e-mail is Gradescope's account,
the SID is typed by the student), then by SID against ``SIS User ID``, then by the e-mail's
name before ``@`` against a login that is no address. Students of the class that match no
row, and rows of the roster without a submission, are listed (the summary); two submissions
matching one row are refused before anything is graded (:func:`conflicts`).
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from pathlib import Path

from doorlab.errors import ConfigError
from doorlab.runtime.inputs import read_text_file

ROSTER_COPY = "canvas_roster.csv"
"""The roster a class's canvas.csv is filled from, copied into the class's folder (a later
run without ``--roster`` fills it again from this copy)."""
MAX_ROSTER_BYTES = 32 << 20
"""Largest roster read [bytes] (a student's row with 100 assignments is ~1 kB)."""
STUDENT_COLUMNS = ("Student", "ID", "SIS User ID", "SIS Login ID", "Section")
"""The student columns Canvas's export starts with and its import requires."""
OPTIONAL_COLUMNS = ("Integration ID",)
"""A student column some Canvas exports have (kept when present)."""
POINTS_POSSIBLE = "Points Possible"


@dataclass
class Roster:
    """A Canvas gradebook export, as read.

    Attributes:
        columns: Its student columns, in its order (:data:`STUDENT_COLUMNS` and those of
            :data:`OPTIONAL_COLUMNS` it has).
        students: Each student's cells of those columns, in its order.
        assignments: Its assignment columns' names.
        points: Each assignment's points possible (its second row), by column name.
    """

    columns: list[str]
    students: list[dict[str, str]] = field(default_factory=list)
    assignments: list[str] = field(default_factory=list)
    points: dict[str, str] = field(default_factory=dict)


def parse_roster(text: str, name: str = "the roster") -> Roster:
    """A Canvas gradebook export's text as a :class:`Roster`.

    Raises:
        ConfigError: Not CSV, or a student column missing (one line naming it).
    """
    try:
        table = list(csv.reader(io.StringIO(text.lstrip("\ufeff"))))
    except csv.Error as e:
        raise ConfigError(f"{name} is not CSV ({e})") from None
    header = [h.strip() for h in (table[0] if table else [])]
    missing = [c for c in STUDENT_COLUMNS if c not in header]
    if missing:
        raise ConfigError(
            f"{name} is not a Canvas gradebook export: it has no column {missing[0]!r} (Canvas's "
            f"Grades, Export: {', '.join(STUDENT_COLUMNS)}, then the assignments)"
        )
    columns = [c for c in header if c in STUDENT_COLUMNS + OPTIONAL_COLUMNS]
    known = set(columns)
    roster = Roster(columns, assignments=[h for h in header if h and h not in known])
    index = {h: i for i, h in enumerate(header)}
    for cells in table[1:]:
        row = {h: (cells[i].strip() if i < len(cells) else "") for h, i in index.items()}
        if row["Student"] == POINTS_POSSIBLE:
            roster.points = {a: row.get(a, "") for a in roster.assignments}
            continue
        if not row["Student"] and not row["ID"]:  # a posting-policy row, a blank line
            continue
        roster.students.append({c: row[c] for c in columns})
    return roster


def read_roster(path: Path) -> tuple[Roster, bytes]:
    """The roster file ``path`` (``--roster``), parsed, and its bytes (kept in the class).

    Raises:
        ConfigError: It cannot be read or is not a Canvas gradebook export.
    """
    text = read_text_file(path, what="--roster", max_bytes=MAX_ROSTER_BYTES)
    return parse_roster(text, f"--roster {str(path)!r}"), text.encode()


def _key(person: dict) -> tuple[str, str, str]:
    return (person.get("name", ""), person.get("sid", ""), person.get("email", ""))


def match(roster: Roster, people: list[dict]) -> tuple[dict, list[str]]:
    """Each person of the class (``{"name", "sid", "email"}``) matched to a roster row's
    index; and notes (a SID that names another row than the e-mail: the e-mail wins)."""
    logins = {}
    sids = {}
    for i, row in enumerate(roster.students):
        if row["SIS Login ID"]:
            logins.setdefault(row["SIS Login ID"].lower(), i)
        if row["SIS User ID"]:
            sids.setdefault(row["SIS User ID"], i)
    found, notes = {}, []
    for person in people:
        email, sid = person.get("email", "").lower(), person.get("sid", "")
        by_email = logins.get(email) if email else None
        if by_email is None and email and "@" in email:
            local = logins.get(email.split("@", 1)[0])
            if local is not None and "@" not in roster.students[local]["SIS Login ID"]:
                by_email = local
        by_sid = sids.get(sid) if sid else None
        chosen = by_email if by_email is not None else by_sid
        if chosen is None:
            continue
        if by_email is not None and by_sid is not None and by_sid != by_email:
            notes.append(
                f"SID {sid} of {person.get('name', '')} ({email}) is "
                f"{roster.students[by_sid]['Student']}'s in the roster: matched by e-mail to "
                f"{roster.students[by_email]['Student']}"
            )
        found[_key(person)] = chosen
    return found, notes


def conflicts(roster: Roster, people: list[tuple[str, dict]]) -> str | None:
    """The first roster row two submissions' students match (one line), or None;
    ``people``: (submission id, person)."""
    matched, _ = match(roster, [p for _, p in people])
    seen: dict[int, tuple[str, dict]] = {}
    for submission, person in people:
        row = matched.get(_key(person))
        if row is None:
            continue
        if row in seen and seen[row][0] != submission:
            other, first = seen[row]
            return (
                f"the roster's {roster.students[row]['Student']} (SIS User ID "
                f"{roster.students[row]['SIS User ID'] or '-'}) matches {other} "
                f"({first.get('name', '')}, {first.get('email', '')}) and {submission} "
                f"({person.get('name', '')}, {person.get('email', '')})"
            )
        seen[row] = (submission, person)
    return None


def column_name(roster: Roster, title: str) -> str:
    """This assignment's column: the roster's of the same title (``Title (id)``), else the
    title (a new column: Canvas creates the assignment)."""
    for name in roster.assignments:
        if name == title or (name.startswith(f"{title} (") and name.endswith(")")):
            return name
    return title


def fill(roster: Roster, grades: dict, title: str, points: str) -> tuple[list[list[str]], list]:
    """``canvas.csv``'s table: the roster's students with this assignment's column; and
    the roster's students without a grade (their names). ``grades``: person key -> grade
    text, for the people :func:`match` matched (by row index: see the caller)."""
    column = column_name(roster, title)
    table = [
        [*roster.columns, column],
        [POINTS_POSSIBLE, *[""] * (len(roster.columns) - 1), points],
    ]
    missing = []
    for i, row in enumerate(roster.students):
        grade = grades.get(i, "")
        if i not in grades:
            missing.append(row["Student"])
        table.append([*(row[c] for c in roster.columns), grade])
    return table, missing


def sortable_name(name: str) -> str:
    """Canvas's order of a name, "Last, First" (its sortable name: the last word first), for
    a student known only by Gradescope's "First Last"."""
    words = name.split()
    if len(words) < 2 or "," in name:
        return name
    return f"{words[-1]}, {' '.join(words[:-1])}"
