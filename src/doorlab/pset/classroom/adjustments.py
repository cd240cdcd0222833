"""The instructor's adjustments: ``DIR/adjustments.csv`` in a class's folder.

A grade the instructor changes by hand (a regrade request granted, a penalty waived, a typed
student id corrected) is a row of ``adjustments.csv`` (columns :data:`COLUMNS`), never an
edit of the sheet or of the LMS: every run of ``grade-all`` reads the file and applies it to
the results it writes (:mod:`doorlab.pset.classroom.final_grade`), so an adjustment survives
every regrade (a re-score, a new export, ``--only``, ``--force``) and shows in the sheet, the
feedback page, ``changes.csv`` and the gradebook exports. A row is one of:

- **points**: ``student``, ``points`` (added, may be negative), ``reason``; with ``test`` (a
  test's key, e.g. ``impedance_episode``) they are added to that test's score (kept within 0
  and its points), without, to the total after the late penalty;
- **a test's score**: ``student``, ``test``, ``score`` (the test's score, within 0 and its
  points), ``reason``;
- **an identity**: ``student``, ``sid`` and/or ``email``, ``reason``: that student's student
  id or e-mail in the sheet and the gradebook exports (a student who typed another's SID in
  a self-enrolled course); ``student`` names the member (a submission id names the
  submission's only member).

``student`` is a submission's id, a student id (SID) or an e-mail (case aside) that names one
submission. Every row needs a ``reason`` (it is shown wherever the adjustment is). A bad row
stops the run before anything is graded, in one line naming the row.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

from doorlab.errors import ConfigError
from doorlab.pset.classroom.tables import matching, one_submission, read_table
from doorlab.pset.isolation.safe_text import clean_text
from doorlab.pset.rules import verdicts
from doorlab.runtime.inputs import quote_text

ADJUSTMENTS_CSV = "adjustments.csv"
"""The instructor's adjustments in a class's folder."""
COLUMNS = ("student", "test", "points", "score", "sid", "email", "reason")
MAX_POINTS = 1000.0
"""Largest adjustment [points] (a typo guard)."""


@dataclass(frozen=True)
class Adjustment:
    """A change of a submission's grade.

    Attributes:
        row: Its row in the file.
        test: The test's key ("" for the total).
        points: Points added (None with ``score``).
        score: The test's score (None with ``points``).
        reason: Why.
    """

    row: int
    test: str
    points: float | None
    score: float | None
    reason: str

    def describe(self) -> str:
        """How the feedback, the sheet and changes.csv say it (never starting with a sign: a
        spreadsheet would take it for a formula)."""
        if self.score is not None:
            return f"{self.test} set to {self.score:g} ({self.reason})"
        points = abs(self.points or 0.0)
        what = f"{points:g} point{'s' if points != 1 else ''} "
        what += "added" if (self.points or 0.0) >= 0 else "taken off"
        return f"{what} {'on ' + self.test if self.test else 'on the total'} ({self.reason})"


@dataclass(frozen=True)
class Identity:
    """A student's identity corrected: their SID and/or e-mail in the sheet and exports."""

    row: int
    submission: str
    member: int
    sid: str | None
    email: str | None
    reason: str


@dataclass
class Adjustments:
    """What ``adjustments.csv`` holds: the grade changes by submission id, the identities."""

    grades: dict[str, list[Adjustment]] = field(default_factory=dict)
    identities: list[Identity] = field(default_factory=list)


def _number(text: str, name: str, where: str) -> float | None:
    if text == "":
        return None
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or abs(value) > MAX_POINTS:
        raise ConfigError(
            f"{where}: {name} must be a number within +-{MAX_POINTS:g}, got {quote_text(text)}"
        )
    return value


def _test(key: str, where: str) -> str:
    keys = [t.key for t in verdicts.TESTS]
    if key and key not in keys:
        raise ConfigError(f"{where}: test must be one of {', '.join(keys)} (or empty: the total)")
    return key


def _identity(row: dict, submissions, where: str) -> Identity:
    found = matching(row["student"], submissions)
    ids = sorted({s.id for s, _ in found})
    if len(ids) != 1:
        one_submission(row["student"], submissions, where)  # raises, naming the choices
    submission, person = found[0]
    if person is None:
        if len(submission.submitters) != 1:
            raise ConfigError(
                f"{where}: {submission.id} has {len(submission.submitters)} students; name the "
                "one to correct by their SID or e-mail"
            )
        person = submission.submitters[0]
    member = list(submission.submitters).index(person)
    sid, email = row["sid"] or None, row["email"] or None
    return Identity(row["row"], submission.id, member, sid, email, row["reason"])


def read_adjustments(out: Path, submissions, assignment) -> Adjustments:
    """``out/adjustments.csv`` (none without the file), checked against the class's
    ``submissions`` and ``assignment`` (a test's score within its points).

    Raises:
        ConfigError: A bad row (one line naming the file, the row and what is valid).
    """
    from doorlab.pset.rules.verdicts import test_settings

    found = Adjustments()
    specs = {t.key: t for t in verdicts.TESTS}
    for row in read_table(Path(out) / ADJUSTMENTS_CSV, COLUMNS, ("student", "reason")):
        where = f"{ADJUSTMENTS_CSV} row {row['row']}"
        row["reason"] = clean_text(row["reason"], 200)
        if not row["reason"]:
            raise ConfigError(f"{where}: every adjustment needs a reason (it is shown with it)")
        test = _test(row["test"], where)
        points = _number(row["points"], "points", where)
        score = _number(row["score"], "score", where)
        identity = bool(row["sid"] or row["email"])
        kinds = sum((points is not None, score is not None, identity))
        if kinds != 1:
            raise ConfigError(
                f"{where}: give one of points (added), score (a test's score, with test) or "
                "sid/email (a student's identity)"
            )
        if identity:
            found.identities.append(_identity(row, submissions, where))
            continue
        if score is not None:
            if not test:
                raise ConfigError(f"{where}: score sets a test's score: name the test")
            settings = test_settings(assignment, specs[test])
            most = float(getattr(settings, "points", specs[test].max_score))
            if not 0.0 <= score <= most:
                raise ConfigError(f"{where}: {test}'s score must be within 0 and {most:g}")
        submission = one_submission(row["student"], submissions, where)
        adjustment = Adjustment(row["row"], test, points, score, row["reason"])
        found.grades.setdefault(submission.id, []).append(adjustment)
    return found


def apply_identities(submissions: list, identities: list[Identity]) -> list:
    """The submissions with their students' identities corrected (new objects)."""
    by_id: dict[str, list[Identity]] = {}
    for identity in identities:
        by_id.setdefault(identity.submission, []).append(identity)
    out = []
    for submission in submissions:
        changes = by_id.get(submission.id)
        if not changes:
            out.append(submission)
            continue
        people = [dict(p) for p in submission.submitters]
        for change in changes:
            if change.sid is not None:
                people[change.member]["sid"] = change.sid
            if change.email is not None:
                people[change.member]["email"] = change.email
        out.append(dataclasses.replace(submission, submitters=tuple(people)))
    return out
