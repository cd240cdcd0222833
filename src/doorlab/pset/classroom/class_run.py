"""One run of ``grade-all`` over a class, its bookkeeping: what to keep, re-score and grade
(:mod:`doorlab.pset.classroom.regrade`'s ledger), each submission taken here and sent to a
worker through the executor a few at a time, each finished one's results and row written as it
lands, the sheet rewritten after each (or, over an existing sheet, once at the end), the
progress bar, and at the end the summary, ``changes.csv`` and the class's pages and exports
(:mod:`doorlab.pset.classroom.class_outputs`).

:func:`doorlab.pset.classroom.grade_all.grade_class` drives it; the worker's side (what a
worker runs for one submission) is there too.
"""

from __future__ import annotations

import concurrent.futures
import json
import sys
from collections.abc import Callable

from doorlab.errors import OutputError
from doorlab.pset.classroom.class_folder import (
    CLASS_JSON,
    GRADES_CSV,
    REWRITTEN,
    SUMMARY_TXT,
    _commit,
    _write_text,
)
from doorlab.pset.classroom.class_statistics import summarize
from doorlab.pset.classroom.resources import memory_lines, room_problem, write_failure
from doorlab.pset.classroom.roster import Submission, sheet_row, sheet_text
from doorlab.pset.classroom.tables import INSTRUCTOR_FILES
from doorlab.runtime.interrupts import POLL_S, raise_if_interrupted

QUEUED_PER_WORKER = 2
"""Submissions taken and queued per worker at a time (their files held in memory)."""


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

    def grade(self, executor, todo: list[Submission], task: Callable[[dict], dict]) -> None:
        """Submits the submissions a few at a time per worker, each as ``task(payload)`` (the
        worker's side: :func:`doorlab.pset.classroom.grade_all.grade_task`); records each as it
        lands."""
        waiting = list(todo)
        futures: dict = {}
        queued = QUEUED_PER_WORKER * max(1, getattr(executor, "jobs", 1))
        while waiting or futures:
            while waiting and len(futures) < queued:
                submission = waiting.pop(0)
                payload = self.payload(submission)
                if payload is not None:
                    futures[executor.submit(task, payload)] = submission
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
        from doorlab.runtime.interrupts import deferred_signals

        results = outcome.get("results")
        released = self.ledger.released(submission, outcome)
        # Its results file and its row go together: a Ctrl-C meanwhile is raised after both
        # (else a results file without its row would be left, which --resume would not know).
        with deferred_signals():
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
