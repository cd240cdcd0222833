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

This module holds :func:`grade_class` and the worker's side (:func:`grade_task`); the class's
folder (its files' names, what ``--resume`` keeps, its files written atomically) is
:mod:`doorlab.pset.classroom.class_folder`'s, and a run's bookkeeping (planning, grading
through the executor, each finished submission, the sheet and the summary)
:mod:`doorlab.pset.classroom.class_run`'s.
"""

from __future__ import annotations

import atexit
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from doorlab.errors import ConfigError, DoorlabError
from doorlab.pset.classroom.class_folder import CLASS_FILES as CLASS_FILES
from doorlab.pset.classroom.class_folder import CLASS_JSON as CLASS_JSON
from doorlab.pset.classroom.class_folder import GRADES_CSV as GRADES_CSV
from doorlab.pset.classroom.class_folder import RESULTS_JSON as RESULTS_JSON
from doorlab.pset.classroom.class_folder import REWRITTEN as REWRITTEN
from doorlab.pset.classroom.class_folder import SUMMARY_TXT as SUMMARY_TXT
from doorlab.pset.classroom.class_folder import _check_out, _reserved_names, assignment_digest
from doorlab.pset.classroom.class_inputs import assignment_changes, cost_line, read_inputs
from doorlab.pset.classroom.class_run import QUEUED_PER_WORKER as QUEUED_PER_WORKER
from doorlab.pset.classroom.class_run import _ClassRun
from doorlab.pset.classroom.class_statistics import summarize as summarize
from doorlab.pset.classroom.regrade import check_only, settings_of
from doorlab.pset.classroom.resources import check_room, class_memory, worker_view_memory
from doorlab.pset.classroom.roster import find_submissions, sheet_row

# The names imported "as" themselves were defined here before the class's folder and a run's
# bookkeeping had modules of their own: they stay importable from here.


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
                run.grade(executor, todo, grade_task)
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
