"""Regrading a class that was graded before: what each submission needs, and what changed.

``doorlab pset grade-all SUBMISSIONS --out DIR --resume`` over a class folder plans each
submission (:func:`plan_step`), cheapest first:

- **keep**: its files (their SHA-256, :func:`taken_digest`, against the one its results
  record), the settings that change a result, and the reference are the ones it was graded
  with: its results stay as they are;
- **rescore** / **rejudge**: only points or visibility, or margins or the reference, changed
  (or the late policy): new results from its stored figures, without simulating
  (:mod:`doorlab.pset.grading.rescore`);
- **grade**: its files changed (a fixed submission in a new export), it was not graded or its
  grading failed, the random seed or an episode's helpers changed, its results hold no stored
  figures, or ``--only`` names it: graded again, simulated.

A kept result whose final grade changes (a row of ``adjustments.csv`` or ``extensions.csv``
added, changed or removed: :mod:`doorlab.pset.classroom.final_grade`) is **adjusted**:
rewritten from its judged tests, nothing simulated.

Every run over an existing sheet writes ``DIR/changes.csv`` (:data:`CHANGE_COLUMNS`: each
submission the run regraded, its old and new total, the tests whose score changed, and why)
and keeps the sheet it replaces as ``DIR/history/grades-NNN.csv`` (with that run's
``changes-NNN.csv``), numbered from 001: no earlier sheet is ever lost.
"""

from __future__ import annotations

import copy
import csv
import functools
import hashlib
import io
import re
from dataclasses import dataclass
from pathlib import Path

from doorlab.errors import ConfigError
from doorlab.pset.grading.rescore import settings_change
from doorlab.pset.rules import verdicts
from doorlab.pset.rules.assignment import bytes_digest

CHANGES_CSV = "changes.csv"
"""What the last run over an existing sheet changed."""
HISTORY = "history"
"""The folder of the sheets replaced (``grades-NNN.csv``) and their runs' changes."""
CHANGE_COLUMNS = ("submission", "names", "action", "old_total", "new_total", "tests", "why")
"""``changes.csv``'s columns: ``action`` is how the run regraded it (``grade``: simulated,
``rescore``, ``rejudge``, ``adjust``: the instructor's adjustments or extensions re-applied);
``tests`` the tests whose score changed (``key old -> new``)."""
INTERRUPTED = (
    "graded by an earlier run that was interrupted before it wrote the sheet (its results "
    "were newer than the sheet)"
)
"""Why a kept submission whose results differ from the previous sheet's row is a change."""


@functools.cache
def _stubs() -> dict[str, bytes]:
    from doorlab.pset.handout.folder import render_folder

    texts = render_folder(solutions=False)
    return {rel: texts[rel].encode() for rel in verdicts.STUDENT_FILES}


def taken_digest(files: dict[str, bytes], intake) -> str:
    """The SHA-256 its grading records of a submission's graded files: what the intake took,
    each missing file as its stub (the grading's folder); for a submission the intake
    refused, a digest of why."""
    if intake.refused is not None:
        reason = hashlib.sha256(str(intake.refused).encode()).hexdigest()
        return f"refused:{reason}"
    stubs = _stubs()
    return bytes_digest({rel: files.get(rel, stubs[rel]) for rel in verdicts.STUDENT_FILES})


def stored_digest(results: dict) -> str | None:
    """The graded files' SHA-256 a results file records (None: not recorded)."""
    extra = results.get("extra_data") or {}
    batch = extra.get("batch") or {}
    if isinstance(batch, dict) and batch.get("files_sha256"):
        return str(batch["files_sha256"])
    drawn = extra.get("seed") or {}
    return (
        str(drawn["files_sha256"]) if isinstance(drawn, dict) and "files_sha256" in drawn else None
    )


@dataclass(frozen=True)
class Step:
    """What a regrade does to one submission.

    Attributes:
        action: ``keep``, ``rescore``, ``rejudge`` or ``grade``.
        why: Why (empty for ``keep``).
    """

    action: str
    why: str = ""


def plan_step(
    old: dict | None,
    digest: str | None,
    settings: dict,
    *,
    failed: bool = False,
    reference_changed: bool = False,
    requested: bool = False,
) -> Step:
    """The step of a submission whose earlier results are ``old`` (None: none) and whose
    files now digest to ``digest`` (None: not taken, e.g. absent), under the new
    ``settings`` (:meth:`~doorlab.pset.rules.assignment.Assignment.to_dict`)."""
    if requested:
        return Step("grade", "regraded on request (--only)")
    if old is None:
        return Step("grade", "its grading failed before" if failed else "not graded before")
    before = stored_digest(old)
    if digest is not None and digest.startswith("unread:"):
        return Step("grade", f"its files could not be read to compare ({digest[7:]})")
    if digest is not None and before != digest:
        return Step("grade", f"its files changed (SHA-256 {str(before)[:12]} -> {digest[:12]})")
    extra = old.get("extra_data") or {}
    change = settings_change(extra.get("settings"), settings)
    if reference_changed and not extra.get("not_graded"):
        change.add("rejudge", "the reference episodes changed")
    old_late = (extra.get("settings") or {}).get("late")
    if change.action == "keep" and old_late is not None and old_late != settings.get("late"):
        change.add("rescore", "the late policy changed")
    return Step(change.action, "; ".join(change.why))


def changed_tests(old: dict | None, new: dict | None) -> str:
    """The tests whose score differs between two results: ``key old -> new``, ``; ``-joined."""
    keys = {t.name: t.key for t in verdicts.TESTS}
    before = {t["name"]: t["score"] for t in (old or {}).get("tests", [])}
    after = {t["name"]: t["score"] for t in (new or {}).get("tests", [])}
    parts = []
    for spec in verdicts.TESTS:
        a, b = before.get(spec.name), after.get(spec.name)
        if a != b:
            shown = ["-" if x is None else f"{x:g}" for x in (a, b)]
            parts.append(f"{keys[spec.name]} {shown[0]} -> {shown[1]}")
    return "; ".join(parts)


def change_row(
    submission: str, names: str, step: Step, old: dict | None, new: dict | None, error: str = ""
) -> dict:
    """One row of ``changes.csv``."""

    def total(results: dict | None) -> str:
        return "" if results is None else f"{float(results.get('score') or 0):g}"

    return {
        "submission": submission,
        "names": names,
        "action": step.action,
        "old_total": total(old),
        "new_total": total(new) if new is not None else f"error: {error}"[:300],
        "tests": changed_tests(old, new),
        "why": step.why,
    }


def changes_text(rows: list[dict]) -> str:
    """``changes.csv``'s text (cells cleaned and guarded as the sheet's)."""
    from doorlab.pset.classroom.roster import _cell

    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CHANGE_COLUMNS)
    for row in rows:
        writer.writerow([_cell(row.get(c, "")) for c in CHANGE_COLUMNS])
    return out.getvalue()


_NUMBERED = re.compile(r"grades-(\d{3,})\.csv")


def next_history_number(out: Path) -> int:
    """The number of the next sheet kept in ``out/history`` (1 for the first)."""
    folder = Path(out) / HISTORY
    found = [
        int(m.group(1)) for p in folder.glob("grades-*.csv") if (m := _NUMBERED.fullmatch(p.name))
    ]
    return max(found, default=0) + 1


def old_sheet(out: Path) -> tuple[str | None, dict[str, bytes], set[str]]:
    """A class folder's sheet, its history's files and the submissions whose grading failed."""
    import csv

    try:
        sheet = (out / "grades.csv").read_text()
    except OSError:
        return None, {}, set()
    rows = csv.DictReader(sheet.splitlines())
    failed = {r.get("submission", "") for r in rows if r.get("status") == "error"}
    history = {}
    for path in sorted((out / HISTORY).glob("*.csv")):
        if path.is_file() and not path.is_symlink():
            history[path.name] = path.read_bytes()
    return sheet, history, failed


def settings_of(assignment) -> dict:
    """The assignment's settings as plain data (the defaults' when None)."""
    from doorlab.pset.rules.assignment import Assignment

    return (assignment or Assignment()).to_dict()


def check_only(only, submissions, previous, assignment, out: Path) -> None:
    """``--only``'s ids name submissions of a class graded with this assignment."""
    if not only:
        return
    if previous is None:
        raise ConfigError(
            f"--only regrades submissions of a class graded before; {str(out)!r} holds none: "
            "grade the class first"
        )
    ids = [s.id for s in submissions]
    unknown = [i for i in only if i not in ids]
    if unknown:
        shown = ", ".join(ids[:8]) + (f" ... ({len(ids)} in all)" if len(ids) > 8 else "")
        raise ConfigError(f"--only {unknown[0]!r} is no submission of this class; valid: {shown}")
    if previous.settings is not None and previous.settings != settings_of(assignment):
        raise ConfigError(
            "--only regrades with the class's assignment, and this --assignment differs from "
            "it: regrade the class with --resume (it re-scores what the change needs)"
        )


class Ledger:
    """One ``grade-all`` run's regrade bookkeeping: each submission's step and earlier
    results, its graded files' SHA-256, the gradings that identical files share, and the
    late policy applied to every result before it is written.

    Args:
        assignment: The run's assignment (None: the defaults).
        reference: The reference episodes' figures the run grades against.
    """

    def __init__(self, assignment, reference: dict) -> None:
        from doorlab.pset.rules.assignment import Assignment

        self.assignment = assignment or Assignment()
        self.reference = reference
        self.steps: dict[str, Step] = {}
        self.old: dict[str, dict] = {}
        self.digests: dict[str, str] = {}
        self.intakes: dict[str, object] = {}
        self.finished: dict[str, tuple[str, dict]] = {}  # digest -> (id, results before late)
        self.inflight: dict[str, str] = {}  # digest -> the id being graded
        self.waiting: dict[str, list] = {}  # digest -> submissions waiting for that grading
        self.requested: set[str] = set()
        self.rescored: list[str] = []
        self.own_dues: dict = {}  # submission id -> OwnDue (extensions.csv)
        self.adjustments: dict[str, list] = {}  # submission id -> Adjustment (adjustments.csv)

    # Planning ---------------------------------------------------------------------------

    def took(self, submission, files: dict[str, bytes], intake) -> str:
        """Notes what the intake took of ``submission``; returns its digest."""
        digest = taken_digest(files, intake)
        self.digests[submission.id] = digest
        self.intakes[submission.id] = intake
        return digest

    def _digest_of(self, submission) -> str | None:
        """Its files' digest now (None: not a folder or a zip, its earlier refusal stands).

        Raises:
            OSError: Its files could not all be read here (then it is graded again, never
                counted unchanged)."""
        from doorlab.errors import OutputError
        from doorlab.pset.grading.grader import take_files

        try:
            files, intake = take_files(submission.path)
        except OutputError:
            if not submission.path.exists():
                raise FileNotFoundError(0, "it is gone", str(submission.path)) from None
            return None
        if intake.unreadable:
            raise OSError(0, intake.unreadable[0])
        return self.took(submission, files, intake)

    def plan(
        self, submissions, previous, only: set[str], reference_changed: bool
    ) -> tuple[dict[str, dict], dict[str, dict]]:
        """Plans every submission of a class graded before (``previous``: batch's); returns
        the results kept as they are and the new results of those re-scored or re-judged
        (to be written), by id. The others are to be graded."""
        settings = self.assignment.to_dict()
        kept, rescored = {}, {}
        self.requested = set(only)
        for submission in submissions:
            if submission.path is None:
                continue
            old = previous.results.get(submission.id)
            if only and submission.id not in only:
                if old is None:  # --only grades what it names: a later --resume the rest
                    continue
                step = Step("keep")
            else:
                try:
                    digest = self._digest_of(submission) if old is not None else None
                except OSError as e:  # never counted unchanged: graded again (or says why not)
                    digest = f"unread:{e.strerror or e}"
                step = plan_step(
                    old,
                    digest,
                    settings,
                    failed=submission.id in previous.failed,
                    reference_changed=reference_changed,
                    requested=submission.id in only,
                )
            if old is not None:
                self.old[submission.id] = old
            if step.action in ("rescore", "rejudge"):
                try:
                    rescored[submission.id] = self.rescore(submission, old)
                except Exception as e:  # noqa: BLE001 - NeedsGrading, or results it cannot read
                    step = Step("grade", f"{step.why}; its stored figures do not suffice ({e})")
            if step.action == "keep":
                final = self.finish(submission, copy.deepcopy(old))
                why = adjusted_why(old, final)
                if why:
                    step = Step("adjust", why)
                    rescored[submission.id] = final
            self.steps[submission.id] = step
            if step.action == "keep":
                kept[submission.id] = old
            if step.action in ("keep", "adjust"):
                self._share(submission.id, old)
        return kept, rescored

    def rescore(self, submission, old: dict) -> dict:
        """``old`` re-scored or re-judged under the run's assignment and reference, the late
        policy applied (raises :class:`~doorlab.pset.grading.rescore.NeedsGrading`)."""
        from doorlab.pset.classroom.final_grade import restore
        from doorlab.pset.grading.rescore import rejudge

        new = rejudge(restore(old), self.assignment, self.reference)
        self.rescored.append(submission.id)
        self._share(submission.id, new)
        return self.finish(submission, new)

    # Identical files ----------------------------------------------------------------------

    def _share(self, submission_id: str, results: dict) -> None:
        digest = self.digests.get(submission_id) or stored_digest(results)
        extra = results.get("extra_data") or {}
        copied = (extra.get("batch") or {}).get("same_files_as")
        if digest and not copied and not extra.get("not_graded"):
            self.finished.setdefault(digest, (submission_id, results))

    def copy_for(self, submission) -> dict | None:
        """The results of an identical submission graded under this run's settings, for
        ``submission`` (its own intake's account; None: none yet)."""
        from doorlab.pset.grading.grader import with_intake

        digest = self.digests.get(submission.id)
        if digest is None or submission.id in self.requested or digest not in self.finished:
            return None
        original, results = self.finished[digest]
        out = with_intake(results, self.intakes[submission.id])
        out["extra_data"]["batch"] = {"same_files_as": original, "wall_time_s": 0.0}
        return out

    def wait(self, submission) -> bool:
        """Whether ``submission`` waits for an identical one being graded (then it is queued
        behind it); else notes that it is being graded."""
        digest = self.digests.get(submission.id)
        if digest is None:
            return False
        if digest in self.inflight and submission.id not in self.requested:
            self.waiting.setdefault(digest, []).append(submission)
            return True
        self.inflight[digest] = submission.id
        return False

    def released(self, submission, outcome: dict) -> list[tuple[object, dict]]:
        """The submissions that waited for ``submission``'s grading, each with its outcome."""
        digest = self.digests.get(submission.id)
        if digest is None or self.inflight.get(digest) != submission.id:
            return []
        del self.inflight[digest]
        if outcome.get("results") is not None:
            self._share(submission.id, outcome["results"])
        out = []
        for waiting in self.waiting.pop(digest, []):
            copied = self.copy_for(waiting)
            out.append((waiting, {"results": copied} if copied else dict(outcome)))
        return out

    # Every result written ------------------------------------------------------------------

    def finish(self, submission, results: dict) -> dict:
        """``results`` as written: the graded files' SHA-256 recorded, the final grade
        (:func:`doorlab.pset.classroom.final_grade.finalize`: the adjustments, the late
        policy from the submission's time and its own due date, the total's line)."""
        from doorlab.pset.classroom.final_grade import finalize
        from doorlab.pset.classroom.late import submission_time

        batch = results["extra_data"].setdefault("batch", {})
        digest = self.digests.get(submission.id) or stored_digest(results)
        if digest:
            batch["files_sha256"] = digest
        return finalize(
            results,
            self.assignment,
            submission_time(getattr(submission, "created_at", None)),
            own_due=self.own_dues.get(submission.id),
            adjustments=self.adjustments.get(submission.id, ()),
        )

    def changes(
        self,
        submissions,
        new_results: dict[str, dict],
        errors: dict[str, str],
        previous_rows: dict[str, dict] | None = None,
    ) -> list:
        """``changes.csv``'s rows: every submission this run regraded (not kept), and every
        kept one whose results differ from ``previous_rows`` (the sheet this run replaces,
        as read: an interrupted run's gradings, written after that sheet)."""
        rows = []
        for submission in submissions:
            step = self.steps.get(submission.id)
            names = "; ".join(p.get("name", "") for p in submission.submitters)
            new = new_results.get(submission.id)
            if step is None or step.action == "keep":
                before = (previous_rows or {}).get(submission.id)
                if before is not None and new is not None and _differs(before, new, submission):
                    old = _from_row(before)
                    rows.append(
                        change_row(submission.id, names, Step("grade", INTERRUPTED), old, new)
                    )
                continue
            old = self.old.get(submission.id)
            notes = adjustment_notes(old, new) if step.action != "adjust" else []
            if notes:  # graded or re-scored, and adjusted: both said
                step = Step(step.action, "; ".join([step.why, *notes]))
            rows.append(
                change_row(submission.id, names, step, old, new, errors.get(submission.id, ""))
            )
        return rows


def adjusted_why(old: dict, new: dict) -> str:
    """Why a kept result's final grade changed ("": it did not)."""
    if json_text(old) == json_text(new):
        return ""
    before, after = old.get("extra_data") or {}, new.get("extra_data") or {}
    parts = adjustment_notes(old, new)
    old_late, new_late = before.get("late") or {}, after.get("late") or {}
    if [old_late.get(k) for k in ("due", "extension")] != [
        new_late.get(k) for k in ("due", "extension")
    ]:
        extension = new_late.get("extension") or old_late.get("extension")
        parts.append(f"its due date changed ({extension or 'the course due date'})")
    elif old_late.get("penalty_points") != new_late.get("penalty_points") and not parts:
        parts.append("its late penalty changed")
    return "; ".join(parts) or "its results' total line (rewritten by this doorlab)"


def adjustment_notes(old: dict | None, new: dict | None) -> list[str]:
    """What changed of the instructor's adjustments between two results (added, removed)."""

    def reasons(results):
        extra = (results or {}).get("extra_data") or {}
        return list((extra.get("adjusted") or {}).get("reasons") or [])

    before, after = reasons(old), reasons(new)
    added = [a for a in after if a not in before]
    removed = [a for a in before if a not in after]
    parts = ["adjustments.csv: " + "; ".join(added)] if added else []
    if removed:
        parts.append("adjustments.csv no longer has: " + "; ".join(removed))
    return parts


def json_text(results: dict) -> str:
    """``results`` as canonical text (to compare two results: keys sorted, every number a
    float, so 20 and 20.0 are the same)."""
    import json

    def canonical(value):
        if isinstance(value, dict):
            return {str(k): canonical(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [canonical(v) for v in value]
        if isinstance(value, int) and not isinstance(value, bool):
            return float(value)
        return value

    return json.dumps(canonical(results), sort_keys=True, default=str)


def _differs(row: dict, results: dict, submission) -> bool:
    """Whether the sheet's ``row`` (as read) holds another total or test score than
    ``results``."""
    from doorlab.pset.classroom.roster import _cell, sheet_row

    new = sheet_row(submission, results)
    keys = [
        "total",
        "status",
        "seed",
        "late_penalty",
        "adjustment",
        *(t.key for t in verdicts.TESTS),
    ]
    return any(str(row.get(k, "")) != _cell(new.get(k)) for k in keys)


def _from_row(row: dict) -> dict:
    """A sheet row (as read) as the results ``change_row`` compares: the total and the
    tests' scores."""

    def number(text):
        try:
            return float(text)
        except (TypeError, ValueError):
            return None

    tests = [
        {"name": t.name, "score": number(row.get(t.key))}
        for t in verdicts.TESTS
        if number(row.get(t.key)) is not None
    ]
    return {"score": number(row.get("total")) or 0.0, "tests": tests}
