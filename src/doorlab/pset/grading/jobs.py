"""The grader's trusted processes: one per job, forked from the supervisor.

The supervisor (:mod:`doorlab.pset.grading.supervisor`: ``python -I -m
doorlab.pset.grading.supervisor supervise``, started by :func:`doorlab.pset.grading.grader.grade`)
runs a grading's jobs ``parallel`` at a time (:class:`_Jobs`), each in a trusted process *forked*
from it (:func:`run_job`): a reference episode, or a test that asks the student's process for
numbers and judges them. In the student's view the student processes are forked too, each from the
first process of a view (:mod:`doorlab.pset.isolation.student_view`); without the view each job
starts its own (:class:`~doorlab.pset.isolation.handle.StudentProcess`).

The supervisor and its jobs are *trusted*: Python's isolated mode (no working directory, no
``PYTHON*`` variables, no user site on ``sys.path``), a working directory in the grading's
private folder, doorlab's code from the installed package only, nothing of the submission
imported. The supervisor forks only while it runs no thread of its own; the jobs are child
subreapers and kill every descendant before they answer; the supervisor answers only after
the last job and every process below it are dead.
"""

from __future__ import annotations

import json
import os
import selectors
import signal
import sys
import tempfile
import time
import traceback
from pathlib import Path

from doorlab.pset.isolation import sandbox
from doorlab.pset.rules.clock import EPISODE_TIME_LIMIT_S, UNIT_TIME_LIMIT_S

JOB_MARGIN_S = 30.0
"""How much longer than its test's longest time (:data:`doorlab.pset.rules.clock.HARD_FACTOR`
times its limit, in wall time) a trusted job process may run before the supervisor kills it
[s] (it enforces the limit itself; this catches a hung or starved grader: the grader's error)."""
STDERR_KEPT_CHARS = 2000
"""Characters of a trusted job's own stderr kept for a failure's message."""


def time_limit(job: str, scale: float) -> float:
    """The time limit of ``job`` [s]."""
    base = UNIT_TIME_LIMIT_S if job.startswith("unit:") else EPISODE_TIME_LIMIT_S
    return base * scale


def trusted_environment() -> dict[str, str]:
    """The trusted processes' environment: the grader's, one BLAS thread (the processes
    are single-threaded work, and no thread may exist when the supervisor forks)."""
    env = dict(os.environ)
    env.update(MPLBACKEND="Agg", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    return env


# One job, in its own trusted process ------------------------------------------------------


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    line = text.splitlines()[0][:500] if text else ""
    return f"{type(e).__name__}: {line}".rstrip(": ")


def _student(job, folder, workdir, limit, isolation, student_view, on_start, group=None):
    from doorlab.pset.isolation.handle import StudentProcess

    if student_view is None:
        return StudentProcess(folder, workdir, job, limit, isolation, group)
    from doorlab.pset.isolation.student_view import ForkedStudent

    return ForkedStudent(student_view, folder, job, limit, on_start=on_start)


def run_job(
    job: str,
    folder: Path,
    workdir: Path,
    limit: float,
    isolation: object,
    options: dict | None = None,
    *,
    student_view: object = None,
    on_start=None,
    student_group: object = None,
) -> dict:
    """Runs one job in this process and returns its JSON-ready result.

    Args:
        job: ``reference:NAME``, ``unit:NAME`` or ``student:NAME``.
        folder: The submission. workdir: The job's private folder. limit: Its time [s].
        isolation: The grading's :class:`~doorlab.pset.isolation.choice.Isolation` (None for a
            reference episode).
        options: ``seed`` (a unit test's random draws: the grading seed) and ``helpers`` (a
            task 2 or 3 episode: ``reference`` or ``student``, whose calc_p_Q and
            calc_R_WL7_ref it runs).
        student_view: The :class:`~doorlab.pset.isolation.student_view.StudentView` whose first
            process forks the student's process (None: start one, as without the view).
        on_start: Called with the student's process (pid, start time) once it said hello.
        student_group: The cgroup of a student process started without the view (None:
            none, or the view's).
    """
    from doorlab.pset.isolation.channel import ProtocolError
    from doorlab.pset.isolation.handle import SandboxError, StudentFailure

    options = options or {}

    kind, _, name = job.partition(":")
    try:
        if kind == "reference":
            from doorlab.pset.grading.answer_key import reference_episode

            return {"figures": reference_episode(name)}
        # The student's process starts first (no thread may exist at its fork), then the
        # grader's side imports Drake while it starts.
        student = _student(
            job, folder, workdir, limit, isolation, student_view, on_start, student_group
        )
        with student:
            try:
                if kind == "unit":
                    from doorlab.pset.grading.checks import UNIT_CHECKS

                    expect = options.get("expect")
                    if expect is None:  # the answer key (the students' doorlab has none)
                        from doorlab.pset.grading.answer_key import EXPECTATIONS

                        expect = EXPECTATIONS[name](options.get("seed"))
                    result = UNIT_CHECKS[name](student, expect)
                else:
                    from doorlab.pset.grading.episodes import student_episode

                    helpers = options.get("helpers", "reference")
                    table = options.get("table")
                    if helpers == "reference" and table is None:
                        from doorlab.pset.grading.answer_key import reference_helper_table

                        table = reference_helper_table()
                    result = {
                        "figures": student_episode(student, name, helpers=helpers, table=table)
                    }
            except StudentFailure as e:
                result = {"passed": False, "error": str(e), "output": e.detail}
            except ProtocolError as e:  # an answer that does not hold what was asked
                message = f"your code's process answered something invalid: {e}"
                result = {"passed": False, "error": message}
            result["sandbox"] = student.facts
            return result
    except StudentFailure as e:
        return {"passed": False, "error": str(e), "output": e.detail}
    except SandboxError as e:
        return {"grader_error": str(e)}
    except Exception as e:  # noqa: BLE001 - what the student's answers did to the episode
        who = "doorlab's reference" if kind == "reference" else "with your code"
        return {"passed": False, "error": f"{_first_line(e)} ({who})"}
    finally:
        sandbox.kill_descendants()


# The supervisor ------------------------------------------------------------------------------


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


class _Running:
    """A forked job: its pid, its result pipe and what it has sent, its stderr file."""

    def __init__(self, job: str, pid: int, fd: int, err, limit: float):
        self.job, self.pid, self.fd, self.err = job, pid, fd, err
        from doorlab.pset.rules.clock import HARD_FACTOR

        self.start = time.perf_counter()
        self.deadline = time.monotonic() + HARD_FACTOR * limit + JOB_MARGIN_S
        self.limit = limit
        self.data = bytearray()
        self.students: list[tuple[int, int | None]] = []
        self.view: str | None = None  # the key of the view its student's process runs in


class _Jobs:
    """Forks a trusted process per job, ``parallel`` at a time, and kills whatever outlives
    them. Holds the grading's student views (:mod:`doorlab.pset.isolation.student_view`): each runs
    one test at a time; the first is started for the first student job, a second (up to
    ``parallel``) only when a slot would otherwise stay idle (the reference episodes all
    started)."""

    def __init__(
        self, folder: Path, workdir: Path, scale: float, isolation, options: dict, groups=None
    ):
        self.folder, self.workdir, self.scale = folder, workdir, scale
        self.isolation = isolation
        self.options = options  # job -> its options (run_job)
        self.groups = groups  # the grading's cgroups (doorlab.pset.isolation.cgroups), or None
        self.views: dict = {}
        self.running: dict[int, _Running] = {}
        self.selector = selectors.DefaultSelector()

    def _in_view(self, job: str) -> bool:
        """Whether ``job``'s student process runs in one of the grading's views."""
        mode = None if self.isolation is None else self.isolation.mode
        return mode == "bwrap" and not job.startswith("reference:")

    def _view(self, key: str):
        from doorlab.pset.isolation.student_view import StudentView

        old = self.views.get(key)
        if old is not None and not old.alive():  # the kernel ended it (a test's memory)
            old.close()
            del self.views[key]
        if key not in self.views:
            limit = max(UNIT_TIME_LIMIT_S, EPISODE_TIME_LIMIT_S) * self.scale
            group = None if self.groups is None else self.groups.views.get(key)
            if self.groups is not None and group is None:
                group = self.groups.student(key)
            self.views[key] = StudentView(self.isolation, self.workdir, key, limit, group)
        return self.views[key]

    def _next(self, pending: list[str], parallel: int) -> tuple[str, str | None] | None:
        """The job to start now and its view's key (None: no view): the student's tests
        first (they are the longest chain), in a view no running test uses, then the
        others, each in ``pending``'s order."""
        tests = [j for j in pending if self._in_view(j)]
        others = [j for j in pending if not self._in_view(j)]
        busy = {r.view for r in self.running.values()}
        free = [k for k in self.views if k not in busy]
        if tests and (free or not self.views):
            return tests[0], free[0] if free else "view0"
        if others:
            return others[0], None
        if tests and len(self.views) < parallel:
            return tests[0], f"view{len(self.views)}"
        return None

    def run(self, todo: list[str], parallel: int) -> dict[str, dict]:
        results: dict[str, dict] = {}
        pending = list(todo)
        while pending or self.running:
            while len(self.running) < parallel and (chosen := self._next(pending, parallel)):
                job, key = chosen
                pending.remove(job)
                try:
                    student_view = None if key is None else self._view(key)
                except Exception as e:  # noqa: BLE001 - SandboxError: the grader's failure
                    results[job] = {"grader_error": str(e)}
                    continue
                self._fork(job, student_view, key)
            if not self.running:
                continue
            timeout = max(0.0, min(r.deadline for r in self.running.values()) - time.monotonic())
            for key, _ in self.selector.select(timeout):
                running = key.data
                chunk = os.read(running.fd, 1 << 16)
                if chunk:
                    running.data += chunk
                    self._note_students(running)
                else:
                    results[running.job] = self._finish(running, timed_out=False)
            now = time.monotonic()
            for running in [r for r in self.running.values() if r.deadline <= now]:
                results[running.job] = self._finish(running, timed_out=True)
        return results

    def _fork(self, job: str, student_view, key: str | None = None) -> None:
        limit = time_limit(job, self.scale)
        jobdir = self.workdir / job.replace(":", "_")
        jobdir.mkdir()
        os.chmod(jobdir, 0o711)  # the student's user reaches its scratch folder, lists nothing
        result_r, result_w = os.pipe()
        err = tempfile.TemporaryFile(dir=self.workdir)
        others = [r.fd for r in self.running.values()]
        parent = os.getpid()
        student_group = None  # a student process without the view: a group of its own
        if self.groups is not None and student_view is None and not job.startswith("reference:"):
            student_group = self.groups.student("student_" + job.replace(":", "_"))
        oom_before = self.groups.trusted.oom_kills() if self.groups is not None else 0
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:  # the job's trusted process
            code = 1
            try:
                os.close(result_r)
                for fd in others:
                    os.close(fd)
                if self.groups is not None:
                    self.groups.trusted.join()
                code = _job_process(
                    job,
                    self,
                    jobdir,
                    limit,
                    student_view,
                    result_w,
                    err.fileno(),
                    parent,
                    student_group,
                )
            finally:
                os._exit(code)
        os.close(result_w)
        running = _Running(job, pid, result_r, err, limit)
        running.view = key
        running.oom_before = oom_before
        self.running[pid] = running
        self.selector.register(result_r, selectors.EVENT_READ, running)

    @staticmethod
    def _note_students(running: _Running) -> None:
        """The student processes a job reported (lines before its result)."""
        for line in bytes(running.data).split(b"\n")[:-1]:
            try:
                message = json.loads(line)
            except ValueError:
                continue
            student = message.get("student") if isinstance(message, dict) else None
            if isinstance(student, list) and student not in running.students:
                running.students.append(tuple(student))

    def _finish(self, running: _Running, *, timed_out: bool) -> dict:
        from doorlab.pset.isolation.student_view import kill_process

        self.selector.unregister(running.fd)
        del self.running[running.pid]
        if timed_out:
            try:
                os.kill(running.pid, signal.SIGKILL)
            except OSError:
                pass
        _, status = os.waitpid(running.pid, 0)
        os.close(running.fd)
        result = None if timed_out else self._parse(running)
        if result is None:
            for pid, start in running.students:  # a job that died: its student's process
                kill_process(pid, start)
            if timed_out:  # it enforces the test's time itself: the grader hung or starved
                seconds = time.perf_counter() - running.start
                message = (
                    f"the grader's process for this test was still running after {seconds:.0f} "
                    f"s of wall time (its test's limit: {running.limit:.0f} s; a loaded "
                    "machine, or the grader hung)"
                )
                result = {"grader_error": message}
            else:
                result = self._failure(running, status, self._oom_killed(running))
        running.err.close()
        # Orphans of a job that died come here (we are their subreaper): kill them.
        keep = {*self.running, *(v.proc.pid for v in self.views.values())}
        sandbox.kill_descendants(keep=keep, unreaped=keep)
        result["seconds"] = time.perf_counter() - running.start
        return result

    @staticmethod
    def _parse(running: _Running) -> dict | None:
        lines = bytes(running.data).split(b"\n")
        for line in reversed(lines):
            try:
                message = json.loads(line.decode())
            except (UnicodeDecodeError, ValueError):
                continue
            if isinstance(message, dict) and isinstance(message.get("result"), dict):
                return message["result"]
        return None

    def _oom_killed(self, running: _Running) -> bool:
        """Whether the kernel killed a trusted process of the grading for want of memory
        while ``running`` ran."""
        if self.groups is None:
            return False
        return self.groups.trusted.oom_kills() > getattr(running, "oom_before", 0)

    @staticmethod
    def _failure(running: _Running, status: int, oom: bool = False) -> dict:
        """A trusted process that ended without a result: the grader's failure (out of
        memory, a crash, a signal from outside), never the student's verdict."""
        from doorlab.pset.isolation.safe_text import clean_text

        running.err.seek(0, os.SEEK_END)
        size = running.err.tell()
        running.err.seek(max(0, size - STDERR_KEPT_CHARS))
        tail = running.err.read().decode("utf-8", "replace")
        if os.WIFSIGNALED(status):
            how = f"killed by signal {os.WTERMSIG(status)}"
            if oom or os.WTERMSIG(status) == signal.SIGKILL:
                how += " (out of memory?)" if not oom else ": the machine ran out of memory"
        else:
            how = f"exit code {os.WEXITSTATUS(status)}"
        last = clean_text(tail.strip().splitlines()[-1], 300) if tail.strip() else ""
        message = f"the grader's process for this test ended without a result ({how})"
        return {"grader_error": message + (f": {last}" if last else "")}

    def close(self) -> None:
        """Ends the views (every process in them dies with them)."""
        for student_view in self.views.values():
            student_view.close()
        self.views.clear()
        self.selector.close()


def _job_process(
    job, jobs: _Jobs, jobdir, limit, student_view, result_w, err_fd, parent, student_group=None
) -> int:
    """The forked job: its trusted process's settings, the job, its result on ``result_w``.
    (Its signals are the supervisor's: a signal kills what it started, then ends it.)"""
    os.dup2(err_fd, 1)  # anything printed (Drake's warnings) goes to the job's stderr file
    os.dup2(err_fd, 2)
    sandbox.die_with_parent(parent)
    sandbox.become_subreaper()
    sandbox.make_undumpable()
    os.chdir(jobdir)

    def started(pid: int, start: int | None) -> None:
        _write_all(result_w, json.dumps({"student": [pid, start]}).encode() + b"\n")

    try:
        result = run_job(
            job,
            jobs.folder,
            jobdir,
            limit,
            jobs.isolation,
            jobs.options.get(job, {}),
            student_view=student_view,
            on_start=started,
            student_group=student_group,
        )
    except BaseException:  # noqa: BLE001 - the grader's own failure: its stderr says why
        traceback.print_exc()
        return 1
    _write_all(result_w, json.dumps({"result": result}, default=str).encode() + b"\n")
    return 0
