"""The instructor's tables in a class's folder, and how a row names a student.

A class's folder (``grade-all --out DIR``) is doorlab's, but for two files the instructor
writes and doorlab only reads (never replaces, never records as its own, keeps across
``--force``): ``DIR/extensions.csv`` (:mod:`doorlab.pset.classroom.extensions`) and
``DIR/adjustments.csv`` (:mod:`doorlab.pset.classroom.adjustments`). Both are CSV with a
header row, read within bounds (:data:`MAX_TABLE_BYTES`, :data:`MAX_ROWS`), and a row names
a student by a submission's id, a student id (SID) or an e-mail address
(:func:`matching`). A bad row is one line naming the file, its row and the valid choices.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

from doorlab.errors import ConfigError
from doorlab.runtime.inputs import quote_text, read_text_file

MAX_TABLE_BYTES = 4 << 20
"""Largest instructor's table read [bytes] (a row is ~100 bytes: 40,000 rows)."""
MAX_ROWS = 20_000
"""Most rows in an instructor's table."""
INSTRUCTOR_FILES = ("extensions.csv", "adjustments.csv")
"""The instructor's files in a class's folder: read by every run, never written."""


def read_table(path: Path, columns: tuple[str, ...], required: tuple[str, ...]) -> list[dict]:
    """The rows of the instructor's CSV ``path`` (a missing file: none), each a dict of
    ``columns`` (stripped text, "" when left out) with ``"row"``, its number in the file
    (the header is row 1).

    Raises:
        ConfigError: The file cannot be read, is not CSV, lacks a ``required`` column, has
            a column not in ``columns``, or has too many rows.
    """
    if not path.exists() and not path.is_symlink():
        return []
    name = path.name
    text = read_text_file(path, what=name, max_bytes=MAX_TABLE_BYTES).lstrip("\ufeff")
    try:
        reader = csv.reader(io.StringIO(text))
        header = [h.strip().lower() for h in next(reader, [])]
        body = list(reader)
    except csv.Error as e:
        raise ConfigError(f"{path} is not CSV ({e})") from None
    if not header:
        raise ConfigError(f"{path} has no header row (the columns: {', '.join(columns)})")
    unknown = [h for h in header if h and h not in columns]
    if unknown:
        raise ConfigError(
            f"{path}: the column {quote_text(unknown[0])} is none of {', '.join(columns)}"
        )
    missing = [c for c in required if c not in header]
    if missing:
        raise ConfigError(f"{path}: the column {missing[0]!r} is missing ({', '.join(columns)})")
    if len(body) > MAX_ROWS:
        raise ConfigError(f"{path} has more than {MAX_ROWS} rows")
    rows = []
    for number, cells in enumerate(body, start=2):
        if not any(c.strip() for c in cells):
            continue
        if len(cells) > len(header):
            raise ConfigError(
                f"{name} row {number}: {len(cells)} cells under {len(header)} columns"
            )
        row = {c: "" for c in columns}
        row.update({h: c.strip() for h, c in zip(header, cells, strict=False) if h})
        row["row"] = number
        rows.append(row)
    return rows


def matching(student: str, submissions) -> list[tuple[object, dict | None]]:
    """The submissions (and their member, None for the submission as a whole) that a
    table's ``student`` cell names: a submission's id, a member's student id (SID) or
    e-mail address (case aside)."""
    key = student.strip()
    found = []
    for submission in submissions:
        if submission.id == key:
            found.append((submission, None))
            continue
        for person in submission.submitters:
            sid, email = person.get("sid", ""), person.get("email", "")
            if (sid and sid == key) or (email and email.lower() == key.lower()):
                found.append((submission, person))
                break
    return found


def one_submission(student: str, submissions, where: str):
    """The one submission a table's ``student`` cell names.

    Raises:
        ConfigError: It names none, or more than one (naming them: use the id).
    """
    found = matching(student, submissions)
    if not found:
        raise ConfigError(
            f"{where}: {quote_text(student)} is no submission id, student id (SID) or e-mail "
            "of this class (sheet columns submission, sids, emails)"
        )
    ids = sorted({s.id for s, _ in found})
    if len(ids) > 1:
        raise ConfigError(
            f"{where}: {quote_text(student)} names {len(ids)} submissions ({', '.join(ids[:4])}); "
            "name one by its submission id"
        )
    return found[0][0]
