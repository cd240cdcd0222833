"""Every submission of a class graded in one command: ``doorlab pset grade-all``.

:func:`grade_class` finds the submissions (:mod:`doorlab.pset.classroom.roster`: Gradescope's
export, or a folder of folders and zips), simulates doorlab's reference episodes once for the whole
class (:func:`doorlab.pset.grading.grader.grade_reference`; or takes an earlier grading's), and
grades every submission through :mod:`doorlab.runtime.executor` (local worker processes, or a Dask
cluster with ``scheduler``):

- the one intake (:func:`doorlab.pset.grading.grader.take_files`) runs here and sends the worker
  only the submission's student files (a few kB; no shared file system needed); the worker grades
  them as ``doorlab pset grade`` does (:func:`doorlab.pset.grading.grader.grade_taken`: a fresh
  folder, the student's view, the sandbox), one test at a time, through a supervisor that
  lives as long as the worker (:class:`doorlab.pset.grading.grader.Supervisor`: pydrake imported and
  the student's view prepared once per worker, not per submission);
- a submission the grader fails to grade (a grader error, a worker lost) is a row with its
  error, never a lost class; ``--resume`` grades it again;
- each finished submission's ``DIR/<submission>/results.json`` (what Gradescope would show)
  is written atomically (a staging folder renamed into place), then ``DIR/grades.csv`` is
  rewritten atomically: Ctrl-C leaves a consistent sheet of the finished submissions, and
  ``--resume`` grades only what needs it (:mod:`doorlab.pset.classroom.regrade`: a submission whose
  files changed is graded again, a change of points or margins re-scores from the stored
  figures, the rest is kept; ``changes.csv`` says what changed, ``history/`` keeps the sheet
  replaced);
- submissions whose graded files are identical (the same SHA-256) are graded once: the
  grading seed comes from those files, so each would grade the same;
- the late policy (:mod:`doorlab.pset.classroom.late`) from each submission's time in the metadata;
  at the end, the class's pages and files (:mod:`doorlab.pset.classroom.class_outputs`: feedback
  pages, ``class.html``, ``summary.json``, gradebook exports).

``DIR`` is doorlab's folder (:mod:`doorlab.outputs.runs`: a manifest of what doorlab wrote;
``--force`` replaces only such a folder), but for the instructor's ``extensions.csv`` and
``adjustments.csv`` (:mod:`doorlab.pset.classroom.extensions`,
:mod:`doorlab.pset.classroom.adjustments`), which every run reads and none writes.
``DIR/class.json`` holds the reference figures and the assignment, so a resumed class
(``--resume``, ``--only``) is graded against the same reference and, without ``--assignment``,
the same assignment; a different ``--assignment`` is named, with what it costs, before anything
is simulated. A run over an existing sheet rewrites the sheet and the exports only when it
ends: an interrupted one leaves them as they were (its finished results are kept, and the next
run's ``changes.csv`` lists them).
"""

from __future__ import annotations

import atexit
import concurrent.futures
import hashlib
import json
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from doorlab.errors import ConfigError, DoorlabError, OutputError
from doorlab.pset.classroom.class_inputs import assignment_changes, cost_line, read_inputs
from doorlab.pset.classroom.class_statistics import summarize
from doorlab.pset.classroom.regrade import check_only, old_sheet, settings_of
from doorlab.pset.classroom.resources import (
    check_room,
    class_memory,
    memory_lines,
    room_problem,
    worker_view_memory,
    write_failure,
)
from doorlab.pset.classroom.roster import Submission, find_submissions, sheet_row, sheet_text
from doorlab.pset.classroom.tables import INSTRUCTOR_FILES
from doorlab.runtime.interrupts import POLL_S, raise_if_interrupted

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
QUEUED_PER_WORKER = 2
"""Submissions taken and queued per worker at a time (their files held in memory)."""


# The worker's side ---------------------------------------------------------------------------

_supervisor = None


def _worker_supervisor():
    """This worker process's supervisor (started at its first submission)."""
    global _supervisor
    if _supervisor is None:
        from doorlab.pset.grading.grader import Supervisor

        _supervisor = Supervisor()
        atexit.register(_supervisor.close)
    return _supervisor


def grade_task(payload: dict) -> dict:
    """Worker: grades one submission's taken files; returns ``{"results"}`` or, when the
    grader (not the student) failed, ``{"error"}``; never raises for that."""
    from doorlab.pset.grading.grader import grade_taken
    from doorlab.pset.isolation.intake import Intake
    from doorlab.pset.isolation.safe_text import clean_text
    from doorlab.pset.rules.assignment import assignment_from_dict

    start = time.perf_counter()
    try:
        data = payload.get("assignment")
        view_bytes = payload.get("view_memory_bytes") or worker_view_memory()
        results = grade_taken(
            payload["files"],
            Intake(**payload["intake"]),
            jobs=1,
            reference=payload["reference"],
            assignment=None if data is None else assignment_from_dict(data),
            isolation=payload["isolation"],
            supervisor=_worker_supervisor(),
            network_isolated=payload.get("network_isolated", False),
            view_memory_bytes=view_bytes,
        )
    except Exception as e:  # noqa: BLE001 - a grader's failure is a row, never a lost class
        text = str(e) if isinstance(e, DoorlabError) else f"{type(e).__name__}: {e}"
        return {"error": clean_text(text, 500)}
    results["extra_data"]["batch"] = {"wall_time_s": round(time.perf_counter() - start, 2)}
    return {"results": results}


# The class's folder ------------------------------------------------------------------------


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


# The class -----------------------------------------------------------------------------------


@dataclass
class ClassOutcome:
    """What :func:`grade_class` did.

    Attributes:
        rows: The sheet's rows (every submission), in order.
        graded: The submissions this run graded (ids; simulated, or copied from an identical
            submission's grading).
        kept: The submissions kept from ``out`` (``resume``).
        summary: The summary's lines.
        executor: Where the submissions were graded.
        rescored: The submissions re-scored or re-judged from their stored figures.
        changes: ``changes.csv``'s rows (:mod:`doorlab.pset.classroom.regrade`).
        problems: Files of the class folder that could not be written (one line each: a
            full disk), also in the summary.
    """

    rows: list[dict]
    graded: list[str]
    kept: list[str]
    summary: list[str]
    executor: str = ""
    rescored: list[str] = field(default_factory=list)
    changes: list[dict] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    @property
    def errors(self) -> int:
        """Rows whose grading failed (the grader's, not the student's)."""
        return sum(r.get("status") == "error" for r in self.rows)


def grade_class(
    source: str | Path,
    out: str | Path,
    *,
    assignment: object = None,
    jobs: int = 1,
    scheduler: str | None = None,
    scheduler_timeout_s: float | None = None,
    resume: bool = False,
    force: bool = False,
    reference: dict | None = None,
    isolation: str = "require",
    progress: bool = False,
    only: Sequence[str] = (),
    outputs: object = None,
    security: object = None,
    roster: str | Path | None = None,
    notice=None,
    insecure_cluster: bool = False,
) -> ClassOutcome:
    """Grades every submission in ``source`` into ``out`` (see the module docstring).

    Args:
        source: The submissions' folder (Gradescope's export, or folders and zips).
        out: The class's folder: ``grades.csv``, ``<submission>/results.json``,
            ``class.json``, ``summary.txt``.
        assignment: The course's settings (:class:`doorlab.pset.rules.assignment.Assignment`).
        jobs: Local worker processes (submissions graded at a time; ignored with
            ``scheduler``).
        scheduler: A Dask scheduler address ``tcp://HOST:PORT`` (None: local processes).
        scheduler_timeout_s: Each step of connecting to it [s].
        resume: Regrade the class in ``out``: keep what is still right, grade what changed,
            re-score what only needs it (:mod:`doorlab.pset.classroom.regrade`).
        force: Start over in an ``out`` that doorlab wrote (its sheet is kept in ``history/``).
        reference: The reference episodes' figures to grade against (an earlier grading's
            ``extra_data["reference"]``); None simulates them here, once (with ``resume``:
            the class's, unless given).
        isolation: ``"require"`` or ``"insecure"`` (as ``doorlab pset grade --insecure``).
        progress: A progress bar on stderr.
        only: Submissions (ids) to grade again, simulated, in a class graded before; the
            others are kept as they are.
        outputs: What to write at the end besides the sheet
            (:class:`doorlab.pset.classroom.class_outputs.Outputs`: exports, PDFs; None: the
            defaults).

        security: With ``scheduler``: a ``distributed.Security`` (a ``tls://`` cluster's
            certificates; default: Dask's configuration's). With a scheduler, a cluster whose
            workers would run the student's code without a network namespace is refused
            (:func:`doorlab.pset.classroom.cluster.check_workers`), and so is one that is not
            TLS or lets a client in without a key
            (:func:`doorlab.pset.classroom.cluster.check_cluster`).
        roster: The course's Canvas gradebook export, to fill ``canvas.csv`` from
            (:mod:`doorlab.pset.classroom.canvas`).
        notice: Called with each line to say before grading (what a different assignment
            costs); None: the lines go to the summary only.
        insecure_cluster: Grade on such a scheduler anyway (a one-line warning on stderr).

    Raises:
        ConfigError: No submissions; bad metadata; bad ``jobs``, ``scheduler`` or ``only``;
            ``only`` with another assignment; a cluster whose workers would let the
            student's code reach it. OutputError: ``out`` may not be written.
        GradingError: The reference episodes could not be simulated (nothing written).
        KeyboardInterrupt: After writing the sheet of the submissions finished so far.
    """
    from doorlab.runtime.executor import CONNECT_TIMEOUT_S, check_scheduler

    source, out = Path(source), Path(out)
    submissions = find_submissions(source, reserved=_reserved_names())
    if not submissions:
        raise ConfigError(f"{source} holds no submission (folders or .zip files)")
    if scheduler is not None:
        check_scheduler(scheduler)
    elif not isinstance(jobs, int) or isinstance(jobs, bool) or jobs < 1:
        raise ConfigError(f"jobs must be an integer >= 1, got {jobs!r}")
    previous = _check_out(out, submissions, resume=resume or bool(only), force=force)
    resumed = previous is not None and bool(previous.digest)
    given = assignment
    inputs = read_inputs(
        out,
        submissions,
        assignment,
        previous if resumed else None,
        requested=tuple(getattr(outputs, "exports", ()) or ()),
        roster=roster,
    )
    assignment, submissions = inputs.assignment, inputs.submissions
    digest = assignment_digest(assignment)
    check_only(only, submissions, previous if resumed else None, assignment, out)
    if resumed:
        reference_changed = reference is not None and reference != previous.reference
        reference = reference if reference is not None else previous.reference
    timeout_s = scheduler_timeout_s or CONNECT_TIMEOUT_S
    if scheduler is not None:  # before anything is written: the workers isolate the network
        from doorlab.pset.classroom.cluster import check_cluster, check_workers
        from doorlab.runtime.executor import _security, open_executor

        warning = check_cluster(scheduler, _security(security), insecure=insecure_cluster)
        if warning is not None:
            print(f"doorlab pset grade-all: warning: {warning}", file=sys.stderr)

        with open_executor(scheduler=scheduler, timeout_s=timeout_s, security=security) as ex:
            check_workers(ex, isolation)
    if reference is None:
        from doorlab.pset.grading.grader import grade_reference

        reference = grade_reference(jobs=min(3, max(1, jobs)) if scheduler is None else 3)
    run = _ClassRun(out, submissions, reference, assignment, isolation, progress)
    run.previous, run.outputs, run.inputs = previous, outputs, inputs
    run.ledger.own_dues, run.ledger.adjustments = inputs.own_dues, inputs.adjustments.grades
    run.summary_notes = list(inputs.notes)
    if resumed:
        run.plan(submissions, previous, set(only), reference_changed)
        changes = assignment_changes(previous.settings, settings_of(assignment))
        if given is not None and changes:  # named, with its cost, before simulating
            run.summary_notes.append(cost_line(changes, run.ledger))
            if notice is not None:
                notice(run.summary_notes[-1])
    elif previous is not None:  # --force over a class: every submission graded again
        from doorlab.pset.classroom.regrade import Step

        run.ledger.old = dict(previous.results)
        why = Step("grade", "--force: the class graded again from scratch")
        run.ledger.steps = {s.id: why for s in submissions if s.path is not None}
    run.network_isolated = scheduler is not None
    run.deferred = resumed and previous.sheet is not None
    for submission in submissions:
        if submission.id not in run.rows and submission.path is None:
            run.rows[submission.id] = sheet_row(submission, None)
        elif only and submission.id not in run.rows and submission.id not in only:
            error = "not graded yet (--only graded others; --resume grades it)"
            run.rows[submission.id] = sheet_row(submission, None, error=error)
    todo = [s for s in submissions if s.id not in run.rows and s.id not in run.planned]
    run.memory = class_memory(jobs, len(todo), scheduler)
    check_room(out, tmpdir=scheduler is None)  # before anything is written
    run.local = scheduler is None
    settings = settings_of(assignment)
    info = {"reference": reference, "assignment_sha256": digest, "assignment": settings}
    info["source"] = str(source)
    run.start(info, resume=resumed, force=force, todo=todo)
    interrupted = True
    try:
        run.apply_planned()
        if todo:
            from doorlab.runtime.executor import open_executor

            with open_executor(
                jobs=min(jobs, len(todo)),
                scheduler=scheduler,
                timeout_s=timeout_s,
                security=security,
            ) as executor:
                run.executor = executor.description
                run.grade(executor, todo)
        interrupted = False
    except KeyboardInterrupt as e:
        e.doorlab_left = run.left_text()  # what the command line says was left
        raise
    finally:
        run.finish(interrupted=interrupted)
    return ClassOutcome(
        [run.rows[s.id] for s in submissions if s.id in run.rows],
        run.graded,
        run.kept,
        run.summary,
        run.executor,
        run.rescored,
        run.changes,
        run.problems,
    )


class _ClassRun:
    """One run over a class: its rows, its folder's files, its progress bar."""

    def __init__(self, out, submissions, reference, assignment, isolation, progress):
        from doorlab.pset.rules.verdicts import TESTS

        self.out = out
        self.order = [s.id for s in submissions]
        self.reference, self.assignment, self.isolation = reference, assignment, isolation
        self.progress = progress
        self.keys = [t.key for t in TESTS]
        self.rows: dict[str, dict] = {}
        self.graded: list[str] = []
        self.kept: list[str] = []
        self.summary: list[str] = []
        self.executor = "none (every submission was in the folder)"
        self.started = False
        self.bar = None
        self.network_isolated = False  # a cluster's gradings: no network for the student
        from doorlab.pset.classroom.regrade import Ledger

        self.ledger = Ledger(assignment, reference)
        self.submissions = {s.id: s for s in submissions}
        self.previous = self.outputs = None
        self.planned: dict[str, dict] = {}  # re-scored results, written once the folder is
        self.results: dict[str, dict] = {}  # every result in the sheet, by id
        self.errors: dict[str, str] = {}
        self.rescored: list[str] = []
        self.changes: list[dict] = []
        self.inputs = None  # class_inputs.ClassInputs
        self.summary_notes: list[str] = []
        self.deferred = False  # over an existing sheet: the sheet is written when the run ends
        self.memory = None  # the views' memory plan (doorlab.pset.isolation.memory)
        self.local = True  # local workers (their TMPDIR is this machine's)
        self.problems: list[str] = []  # files that could not be written (one line each)

    def left_text(self) -> str | None:
        """What an interrupted run over an existing sheet left (None: a new class's sheet
        of the finished submissions, as the command line says it)."""
        if not self.deferred:
            return None
        done = len(self.graded) + len(self.planned)
        return (
            f"the sheet and the exports in {str(self.out)!r} are the previous run's, unchanged; "
            f"{done} submission(s) finished and their results are kept (the next --resume "
            "lists them in changes.csv and grades the rest)"
        )

    def plan(self, submissions, previous, only: set[str], reference_changed: bool) -> None:
        """A class graded before: what to keep, re-score and grade
        (:mod:`doorlab.pset.classroom.regrade`)."""
        kept, self.planned = self.ledger.plan(submissions, previous, only, reference_changed)
        for submission in submissions:
            if submission.id in kept:
                self.rows[submission.id] = sheet_row(submission, kept[submission.id])
                self.results[submission.id] = kept[submission.id]
                self.kept.append(submission.id)
        self.rescored = list(self.ledger.rescored)

    def apply_planned(self) -> None:
        """Writes the re-scored results (their rows, the sheet)."""
        for sid, results in self.planned.items():
            _commit(self.out, sid, results)
            self.rows[sid] = sheet_row(self.submissions[sid], results)
            self.results[sid] = results
        if self.planned and not self.deferred:
            self.write_sheet()

    def start(self, info: dict, *, resume: bool, force: bool, todo: list) -> None:
        """Creates the folder (a new class) and writes the class's file and sheet."""
        from doorlab.runtime.folders import staged_output

        if not (resume and self.out.is_dir()):
            with staged_output(self.out, force=force, keep=INSTRUCTOR_FILES):
                pass
        self.started = True
        _write_text(self.out, CLASS_JSON, json.dumps(info, indent=1) + "\n")
        if not self.deferred:
            self.write_sheet()
        if self.progress and todo:
            from tqdm import tqdm

            self.bar = tqdm(
                total=len(self.order),
                initial=len(self.rows),
                unit="submission",
                file=sys.stderr,
                dynamic_ncols=True,
                desc="grade-all",
            )

    def payload(self, submission: Submission) -> dict | None:
        """What a worker needs to grade ``submission`` (None: taken here already)."""
        from doorlab.pset.grading.grader import grade_taken, take_files
        from doorlab.pset.isolation.intake import Intake
        from doorlab.pset.rules.verdicts import STUDENT_FILES

        short = room_problem(self.out, tmpdir=self.local)
        if short is not None:  # the grader's: --resume grades it once there is room
            self.done(submission, {"error": f"not graded: {short}; --resume grades it"})
            return None
        try:
            files, intake = take_files(submission.path)
        except OutputError as e:  # not a folder or a zip: nothing to grade, every test 0
            if not submission.path.exists():  # gone since it was listed: the grader's
                self.done(submission, {"error": str(e)})
                return None
            intake = Intake(missing=list(STUDENT_FILES), refused=str(e))
            self.done(submission, {"results": grade_taken({}, intake, assignment=self.assignment)})
            return None
        except OSError as e:
            self.done(submission, {"error": str(write_failure(submission.path, e))})
            return None
        if intake.unreadable:  # this machine could not read it all: no grade of a part
            why = f"cannot read the submission here ({intake.unreadable[0]}); --resume grades it"
            self.done(submission, {"error": why})
            return None
        self.ledger.took(submission, files, intake)
        if intake.refused is not None:  # over a bound: not graded, no worker needed
            self.done(submission, {"results": grade_taken({}, intake, assignment=self.assignment)})
            return None
        copied = self.ledger.copy_for(submission)
        if copied is not None:  # identical files graded already: the same results
            self.done(submission, {"results": copied})
            return None
        if self.ledger.wait(submission):  # identical files being graded: their results
            return None
        return {
            "files": files,
            "intake": intake.to_dict(),
            "reference": self.reference,
            "assignment": None if self.assignment is None else self.assignment.to_dict(),
            "isolation": self.isolation,
            "network_isolated": self.network_isolated,
            "view_memory_bytes": None if self.memory is None else self.memory.view_bytes,
        }

    def grade(self, executor, todo: list[Submission]) -> None:
        """Submits the submissions a few at a time per worker; records each as it lands."""
        waiting = list(todo)
        futures: dict = {}
        queued = QUEUED_PER_WORKER * max(1, getattr(executor, "jobs", 1))
        while waiting or futures:
            while waiting and len(futures) < queued:
                submission = waiting.pop(0)
                payload = self.payload(submission)
                if payload is not None:
                    futures[executor.submit(grade_task, payload)] = submission
            if not futures:
                continue
            raise_if_interrupted()  # a Ctrl-C whose exception Python dropped
            done, _ = concurrent.futures.wait(
                futures, timeout=POLL_S, return_when=concurrent.futures.FIRST_COMPLETED
            )
            for future in done:
                submission = futures.pop(future)
                try:
                    error = future.exception()
                except concurrent.futures.CancelledError:  # a cluster that lost the task
                    error = RuntimeError("the grading was cancelled (its worker was lost)")
                if isinstance(error, KeyboardInterrupt):
                    raise KeyboardInterrupt
                if error is not None:  # the worker died or could not run the task
                    outcome = {"error": f"{type(error).__name__}: {error}"}
                else:
                    outcome = future.result()
                self.done(submission, outcome)

    def done(self, submission: Submission, outcome: dict) -> None:
        """Writes a finished submission's results and row, then the sheet; then those of the
        submissions with identical files that waited for it."""
        results = outcome.get("results")
        released = self.ledger.released(submission, outcome)
        if results is not None:
            results = self.ledger.finish(submission, results)
            try:
                _commit(self.out, submission.id, results)
            except OutputError as e:  # a full disk: the grader's error, graded again later
                results, outcome = None, {"error": f"{e}; --resume grades it again"}
        if results is not None:
            self.rows[submission.id] = sheet_row(submission, results)
            self.results[submission.id] = results
        else:
            error = str(outcome.get("error") or "no results")
            self.rows[submission.id] = sheet_row(submission, None, error=error)
            self.errors[submission.id] = error
        self.graded.append(submission.id)
        if not self.deferred:
            self.write_sheet()
        if self.bar is not None:
            bad = sum(r.get("status") == "error" for r in self.rows.values())
            self.bar.set_postfix_str(f"{bad} grading errors", refresh=False)
            self.bar.update(1)
        for waiting, copied in released:
            self.done(waiting, copied)

    def write_sheet(self) -> None:
        rows = [self.rows[i] for i in self.order if i in self.rows]
        self.write(GRADES_CSV, sheet_text(rows, self.keys))

    def write(self, name: str, text: str) -> bool:
        """:func:`_write_text`; a failure (a full disk) is one line in the summary, and the file
        stays as it was (the sheet: the rows finished before)."""
        try:
            _write_text(self.out, name, text)
            return True
        except OutputError as e:
            self.problem(str(e))
            return False

    def problem(self, line: str) -> None:
        if line not in self.problems:
            self.problems.append(line)

    def finish(self, *, interrupted: bool = False) -> None:
        """The sheet of what finished, whatever ended the run; the summary; the changes and
        the sheet replaced; then (not after Ctrl-C) the class's pages and exports."""
        from doorlab.pset.classroom import class_outputs

        if self.bar is not None:
            self.bar.close()
        if not self.started or (interrupted and self.deferred):
            return  # an interrupted regrade: the previous sheet and exports stay
        self.write_sheet()
        rows = [self.rows[i] for i in self.order if i in self.rows]
        self.summary = self.summary_notes + summarize(rows, self.keys, len(self.order))
        self.summary += memory_lines(self.memory, self.results, self.graded, local=self.local)
        order = [self.submissions[i] for i in self.order]
        before = self.previous.rows if self.deferred else None
        self.changes = self.ledger.changes(order, self.results, self.errors, before)
        if self.previous is not None and self.previous.sheet is not None:
            try:
                class_outputs.write_changes(self.out, self.previous, self.changes, _write_text)
            except OutputError as e:
                self.problem(str(e))
            self.summary.append(class_outputs.changes_line(self.changes))
        self.write(SUMMARY_TXT, "\n".join([*self.summary, *self.problems]) + "\n")
        if not interrupted:
            try:
                self.summary += class_outputs.write_class_outputs(
                    self.out,
                    order,
                    rows,
                    self.results,
                    self.ledger.assignment,
                    self.outputs,
                    _write_text,
                    None if self.inputs is None else self.inputs.exports,
                )
            except (OSError, OutputError) as e:  # a full disk: nothing half-recorded is left
                from doorlab.runtime.folders import remove_unrecorded

                why = e.strerror if isinstance(e, OSError) else str(e).rsplit(": ", 1)[-1]
                self.problem(
                    f"cannot write the class's pages and exports in {self.out} ({why}): the "
                    "next run writes them"
                )
                remove_unrecorded(self.out, REWRITTEN)
            self.write(SUMMARY_TXT, "\n".join([*self.summary, *self.problems]) + "\n")
        self.summary += self.problems
