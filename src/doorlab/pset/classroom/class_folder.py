"""A class's folder (``grade-all --out DIR``): the names of its files, what a run may find in
it and keep (``--resume``, ``--force``), and its files written atomically and recorded in its
manifest.

:func:`_check_out` checks, writing nothing, that ``DIR`` may be written and reads what a
resumed class keeps (:class:`_Previous`: its reference, its assignment's digest, its results,
its sheet and history); :func:`_commit` writes one submission's ``results.json`` (a staging
folder renamed into place) and :func:`_write_text` any other file of the class, each recorded
as doorlab's (:mod:`doorlab.runtime.folders`), so a full disk leaves no file the manifest
disagrees with. :mod:`doorlab.pset.classroom.grade_all` grades the class into it.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

from doorlab.errors import OutputError
from doorlab.pset.classroom.regrade import old_sheet
from doorlab.pset.classroom.resources import write_failure
from doorlab.pset.classroom.roster import Submission
from doorlab.pset.classroom.tables import INSTRUCTOR_FILES

GRADES_CSV = "grades.csv"
"""The sheet: one row per submission."""
CLASS_JSON = "class.json"
"""The class's grading: the reference figures, the assignment's digest, doorlab's version."""
SUMMARY_TXT = "summary.txt"
"""The summary printed at the end."""
RESULTS_JSON = "results.json"
"""Each submission's Gradescope results, in ``DIR/<submission>/``."""
CLASS_FILES = (
    GRADES_CSV,
    CLASS_JSON,
    SUMMARY_TXT,
    "changes.csv",
    "history",
    "feedback",
    "class.html",
    "summary.json",
    "canvas.csv",
    "gradescope.csv",
    "canvas_roster.csv",
)
"""What a run rewrites in ``DIR`` besides the submissions' folders
(:mod:`doorlab.pset.classroom.regrade`, :mod:`doorlab.pset.classroom.class_outputs`)."""
REWRITTEN = ("feedback", "class.html", "summary.json", "canvas.csv", "gradescope.csv")
"""What a run rewrites from the results at its end (removed where a full disk left it
unrecorded: the next run writes it again)."""


def _reserved_names() -> tuple[str, ...]:
    """What no submission's id may be: the class folder's own files."""
    from doorlab.runtime.folders import MANIFEST_NAME

    return (*CLASS_FILES, MANIFEST_NAME)


def assignment_digest(assignment) -> str:
    """SHA-256 of the assignment's settings (the defaults when None)."""
    from doorlab.pset.rules.assignment import Assignment

    data = (assignment or Assignment()).to_dict()
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()


def _read_results(folder: Path) -> dict | None:
    try:
        data = json.loads((folder / RESULTS_JSON).read_text())
    except (OSError, ValueError):
        return None
    ok = isinstance(data, dict) and isinstance(data.get("tests"), list)
    return data if ok and isinstance(data.get("extra_data"), dict) else None


@dataclass
class _Previous:
    """What a resumed class keeps: its reference, its assignment's digest and settings, the
    results of the submissions it graded, the sheet and the history (kept on)."""

    reference: dict
    digest: str
    results: dict[str, dict] = field(default_factory=dict)
    settings: dict | None = None
    sheet: str | None = None
    history: dict[str, bytes] = field(default_factory=dict)
    failed: set[str] = field(default_factory=set)

    @property
    def rows(self) -> dict[str, dict]:
        """The previous sheet's rows (as read), by submission."""
        import csv

        return {r.get("submission", ""): r for r in csv.DictReader((self.sheet or "").splitlines())}


def _check_out(out: Path, submissions: list[Submission], *, resume: bool, force: bool):
    """Checks that ``out`` may be written (writing nothing); returns what ``--resume`` keeps
    (None for a new class)."""
    from doorlab.runtime.folders import check_replaceable, foreign_file

    if out.exists() and not out.is_dir():
        raise OutputError(f"--out {str(out)!r} is a file, not a folder")
    existing = out.is_dir() and any(p.name not in INSTRUCTOR_FILES for p in out.iterdir())
    if not (existing and resume):
        if existing and not force:
            raise OutputError(
                f"--out {str(out)!r} already exists; pass --resume to grade the rest of its "
                "class or --force to start over"
            )
        check_replaceable(out, force=force, keep=INSTRUCTOR_FILES)
        if not existing:
            return None
        sheet, history, _ = old_sheet(out)  # --force: the old sheet goes to the history
        if sheet is None:
            return None
        previous = _Previous({}, "", sheet=sheet, history=history)
        previous.results = {s.id: r for s in submissions if (r := _read_results(out / s.id))}
        return previous
    try:
        info = json.loads((out / CLASS_JSON).read_text())
        previous = _Previous(dict(info["reference"]), str(info["assignment_sha256"]))
        previous.settings = info.get("assignment")
        previous.sheet, previous.history, previous.failed = old_sheet(out)
    except (OSError, ValueError, KeyError, TypeError):
        raise OutputError(
            f"--out {str(out)!r} holds no class graded by doorlab ({CLASS_JSON} missing or "
            "unreadable): nothing to resume"
        ) from None
    names = [*CLASS_FILES, *(s.id for s in submissions)]
    found = foreign_file(out, only=names)
    if found is not None:
        raise OutputError(
            f"--out {str(out)!r} holds {found[0]!r}, {found[1]}, and --resume would "
            "overwrite or trust it; move it away or choose another --out"
        )
    for submission in submissions:
        results = _read_results(out / submission.id)
        if results is not None:
            previous.results[submission.id] = results
    return previous


def _commit(out: Path, submission_id: str, results: dict) -> None:
    """``out/<id>/results.json``, atomically (a staging folder renamed into place), recorded in
    ``out``'s manifest. Where a full disk stops it, the submission keeps its earlier results or
    none (never a folder the manifest disagrees with: the next run would refuse it).

    Raises:
        OutputError: One line (the submission is then an ``error`` row).
    """
    import shutil

    from doorlab.pset.grading.grader import write_results
    from doorlab.runtime.folders import (
        MANIFEST_NAME,
        commit_output,
        discard_output,
        prepare_output,
        record_written,
    )

    target = out / submission_id
    label = f"{str(target)!r}"
    staging = prepare_output(target, force=True, label=label)
    try:
        write_results(results, staging / RESULTS_JSON)
        commit_output(staging, target)
    except (OSError, OutputError) as e:  # nothing moved (its staging folder goes)
        why = e.strerror if isinstance(e, OSError) else str(e).rsplit(": ", 1)[-1]
        raise write_failure(target / RESULTS_JSON, OSError(0, why)) from None
    finally:
        discard_output(staging)
    try:
        record_written(out, [target / RESULTS_JSON, target / MANIFEST_NAME])
    except OSError as e:  # in place, but not recorded: removed (--resume grades it again)
        shutil.rmtree(target, ignore_errors=True)
        raise write_failure(target / RESULTS_JSON, e) from None


def _write_text(out: Path, name: str, text: str | bytes, *, record: bool = True) -> None:
    """``out/name`` (``name`` may be in a subfolder) atomically, recorded as doorlab's (with
    ``record``: its entry first, then the file, so a full disk leaves both as they were;
    else the caller records it with others, :func:`record_written`).

    Raises:
        OutputError: One line (ENOSPC, a folder that cannot be written).
    """
    import os
    import tempfile

    from doorlab.runtime.folders import follow_umask, replace_recorded

    path = out / name
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        with os.fdopen(fd, "wb" if isinstance(text, bytes) else "w") as f:
            f.write(text)
        follow_umask(Path(tmp), folder=False)
        if record:
            replace_recorded(out, Path(tmp), path)
        else:
            os.replace(tmp, path)
    except OSError as e:
        raise write_failure(path, e) from None
    finally:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
