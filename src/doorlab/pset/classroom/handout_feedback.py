"""Each student's feedback as a file to hand out, for a course without Gradescope.

``doorlab pset feedback DIR OUT [--pdf] [--force]``: from a class graded by ``grade-all``
(``DIR``: its sheet and its feedback pages, nothing graded here), one file per student in the
new folder ``OUT``, named so that a person or a script uploading them finds the student
(:func:`file_name`: the student id, then the name as Canvas sorts it, "Last_First", then the
submission: ``00007_Doe_Jane_submission_7.pdf``); each member of a group gets the group's
page. ``OUT/index.csv`` lists every file with the student's name, student id, e-mail,
submission and total, for a mail merge or an LMS's bulk upload of feedback files; a student
without a page (absent) is listed without one. With ``--pdf`` the files are PDFs printed by
headless Chromium (Debian package ``chromium``), else the self-contained HTML pages.
"""

from __future__ import annotations

import csv
import io
import re
import shutil
from pathlib import Path

from doorlab.errors import OutputError

INDEX_CSV = "index.csv"
INDEX_COLUMNS = ("name", "sid", "email", "submission", "total", "max_total", "file")


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9.-]+", "_", text).strip("_.")[:60]


def file_name(person: dict, submission: str, suffix: str) -> str:
    """A student's file: ``SID_Last_First_submission.suffix`` (parts they lack left out)."""
    from doorlab.pset.classroom.canvas import sortable_name

    name = sortable_name(person.get("name", "")).replace(",", "")
    ident = person.get("sid") or person.get("email", "").split("@", 1)[0]
    parts = [_safe(p) for p in (ident, name, submission) if p and _safe(p)]
    return "_".join(parts) + suffix


def _people(row: dict) -> list[dict]:
    """A sheet row's students (its ``names``, ``sids`` and ``emails`` columns)."""

    def cells(key: str) -> list[str]:
        text = str(row.get(key) or "").removeprefix("'")
        return [c.strip() for c in text.split(";")] if text else []

    names, sids, emails = cells("names"), cells("sids"), cells("emails")
    count = max(len(names), len(sids), len(emails))
    return [
        {
            "name": names[i] if i < len(names) else "",
            "sid": sids[i] if i < len(sids) else "",
            "email": emails[i] if i < len(emails) else "",
        }
        for i in range(count)
    ]


def hand_out(class_dir: Path, out: Path, *, pdf: bool = False, force: bool = False) -> list[str]:
    """Writes ``out`` (see the module docstring); returns the summary's lines.

    Raises:
        OutputError: ``class_dir`` holds no graded class (no sheet); ``out`` exists (without
            ``force``, or is not doorlab's); Chromium is missing (``pdf``).
    """
    from doorlab.pset.classroom.feedback import FEEDBACK
    from doorlab.pset.classroom.grade_all import GRADES_CSV
    from doorlab.pset.classroom.roster import _cell
    from doorlab.runtime.folders import staged_output

    class_dir, out = Path(class_dir), Path(out)
    try:
        rows = list(csv.DictReader((class_dir / GRADES_CSV).read_text().splitlines()))
    except OSError:
        raise OutputError(
            f"{str(class_dir)!r} holds no graded class ({GRADES_CSV} missing): grade it with "
            "doorlab pset grade-all first"
        ) from None
    chromium = None
    if pdf:
        from doorlab.runtime.pdf import find_chromium, print_pdf

        chromium = find_chromium()
    index, written, missing = [], 0, []
    with staged_output(out, force=force) as staging:
        for row in rows:
            page = class_dir / FEEDBACK / f"{row.get('submission', '')}.html"
            for person in _people(row):
                name = ""
                if page.is_file() and not page.is_symlink():
                    name = file_name(person, row["submission"], ".pdf" if pdf else ".html")
                    if (staging / name).exists():  # two students of one name and no SID
                        name = f"{Path(name).stem}_{len(index)}{Path(name).suffix}"
                    if pdf:
                        print_pdf(page, staging / name, chromium=chromium)
                    else:
                        shutil.copyfile(page, staging / name)
                    written += 1
                else:
                    missing.append(person.get("name") or row["submission"])
                index.append(
                    [person["name"], person["sid"], person["email"], row["submission"]]
                    + [row.get("total", ""), row.get("max_total", ""), name]
                )
        text = io.StringIO()
        writer = csv.writer(text, lineterminator="\n")
        writer.writerow(INDEX_COLUMNS)
        writer.writerows([[_cell(c) for c in line] for line in index])
        (staging / INDEX_CSV).write_text(text.getvalue())
    lines = [f"{written} feedback file(s) in {out} ({'PDF' if pdf else 'HTML'}), {out / INDEX_CSV}"]
    if missing:
        lines.append(f"no page for {len(missing)} student(s): {', '.join(missing[:10])}")
    return lines
