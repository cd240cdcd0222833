"""The problem set's autograder: Gradescope-format JSON, every verdict on the trusted side.

:func:`grade` starts the *supervisor* (:mod:`doorlab.pset.grading.jobs`, in Python's isolated mode,
its working directory outside the folder), which runs every job in a trusted process of its
own: a unit test of one student function, a student episode, or a reference episode. The
student's code runs in a separate, sandboxed process (:mod:`doorlab.pset.isolation.sandbox`) that
only answers numbers over a channel (:mod:`doorlab.pset.isolation.channel`); the trusted side draws
the inputs, runs the simulations, and computes every figure and verdict
(:mod:`doorlab.pset.grading.checks`, :mod:`doorlab.pset.grading.episodes`), so nothing the
submission does can write its own score. Episode thresholds that depend on the physics are relative
to doorlab's reference solution, simulated in the same grading (or passed in, ``reference=``).
"""

from __future__ import annotations

import base64
import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

from doorlab.errors import DoorlabError, OutputError
from doorlab.pset.grading.jobs import EPISODE_TIME_LIMIT_S, UNIT_TIME_LIMIT_S, trusted_environment
from doorlab.pset.isolation.safe_text import clean_json, clean_text
from doorlab.pset.rules.verdicts import (
    ARC_END_MARGIN,
    DOOR_OPENING_MARGIN,
    IK_POSITION_TOLERANCE,
    IK_RADIAL_MARGIN,
    TESTS,
    VELOCITY_ORIENTATION_MARGIN,
    TestSpec,
)

__all__ = [
    "ARC_END_MARGIN",
    "DOOR_OPENING_MARGIN",
    "EPISODE_TIME_LIMIT_S",
    "IK_POSITION_TOLERANCE",
    "IK_RADIAL_MARGIN",
    "VELOCITY_ORIENTATION_MARGIN",
    "TestSpec",
    "TESTS",
    "UNIT_TIME_LIMIT_S",
    "GradingError",
    "Supervisor",
    "grade",
    "grade_reference",
    "grade_submission",
    "grade_taken",
    "take_files",
    "with_intake",
    "load_reference",
    "pretty_format_json_results",
    "write_results",
]


class GradingError(DoorlabError):
    """The grader itself could not grade (its sandbox cannot start, its process failed):
    no verdict, rather than zeros the submission did not earn."""


def grade(
    folder: str | Path | None,
    *,
    files: dict[str, bytes] | None = None,
    jobs: int = 2,
    reference: dict[str, dict] | None = None,
    only: Sequence[str] | None = None,
    time_limit_scale: float = 1.0,
    assignment: object = None,
    seed: int | None = None,
    isolation: str = "require",
    harden: Sequence[str | Path] = (),
    supervisor: Supervisor | None = None,
    network_isolated: bool = False,
    view_memory_bytes: int | None = None,
) -> dict:
    """Grades a problem-set folder; returns the Gradescope results (write them with
    :func:`write_results`).

    Returns only after every process the grading started (the student's included, however
    detached) is dead. The folder is not written to.

    Args:
        folder: The folder written by ``doorlab pset init`` (the submission); None with
            ``files``.
        files: The student files' bytes by their place in the folder (what
            :func:`take_files` took): graded over a fresh stub folder, which the supervisor
            writes in its own private folder.
        jobs: Tests run at a time.
        reference: Results of the ``reference:*`` jobs to reuse (e.g. an earlier grading's
            ``extra_data["reference"]``); None simulates them in this grading.
        only: Names of the tests to run (default: all, :data:`TESTS`).
        time_limit_scale: Multiplies every test's time limit.
        assignment: The course's settings (:class:`doorlab.pset.rules.assignment.Assignment`:
            points, margins, visibility, random seed, the episodes' helpers); None: the defaults.
        seed: The grading's seed (``--seed``: replays a recorded grading's random inputs);
            None derives it from the assignment's random seed and the folder's graded files.
        isolation: What to do where the student's view (bubblewrap) cannot be built:
            ``"require"`` refuses (GradingError, before any student code runs),
            ``"insecure"`` grades without it, ``"self-check"`` too (a student checking their
            own folder), ``"autograder"`` falls back to another user after making the
            grader's files and ``harden`` unreadable to it (root only; Gradescope). See
            :mod:`doorlab.pset.isolation.choice`; the results say what held.
        harden: Paths the autograder's fallback makes unreadable to the student's user.
        supervisor: A :class:`Supervisor` that serves several gradings, one at a time (a
            batch's worker); None starts one for this grading.
        network_isolated: Refuse (GradingError) unless the student's code gets a network
            namespace of its own (a grading on a Dask cluster's worker: else its code could
            reach the cluster).
        view_memory_bytes: Each student's view's memory limit [bytes] (a class's
            :func:`doorlab.pset.isolation.memory.plan`); None: this machine's room for ``jobs``
            views (:mod:`doorlab.pset.isolation.memory`).

    Returns:
        Gradescope's results: ``{"score", "visibility", "output", "output_format",
        "test_output_format", "test_name_format", "tests": [{"name", "number", "score",
        "max_score", "status", "visibility", "output", "output_format"}], "execution_time",
        "extra_data": {"max_score", "seed", "reference", "sandbox"}}`` (``seed``: the grading
        grading seed and where it came from, the graded files' SHA-256; ``reference``: the reference
        episodes' figures, reusable as the ``reference`` argument; ``sandbox``: how the
        student's code ran: the isolation mode and what each student process observed of
        itself, limits).

    Raises:
        GradingError: The grader could not run (the student's code cannot be isolated as
            ``isolation`` requires; the sandbox's user cannot run this Python); no results,
            rather than zeros the submission did not earn.
    """
    request = {
        "folder": None if folder is None else str(Path(folder).resolve()),
        "files": None
        if files is None
        else {k: base64.b64encode(v).decode() for k, v in files.items()},
        "jobs": int(jobs),
        "reference": reference,
        "only": None if only is None else list(only),
        "time_limit_scale": float(time_limit_scale),
        "assignment": None if assignment is None else assignment.to_dict(),
        "seed": None if seed is None else int(seed),
        "isolation": isolation,
        "harden": [str(p) for p in harden],
        "network_isolated": bool(network_isolated),
        "view_memory_bytes": _view_memory(view_memory_bytes, jobs),
    }
    if supervisor is not None:
        return supervisor.run(request)
    proc = subprocess.Popen(
        [sys.executable, "-I", "-m", "doorlab.pset.grading.supervisor", "supervise"],
        cwd="/",
        env=trusted_environment(),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
    )
    try:
        out, _ = proc.communicate(json.dumps(request).encode())
    except BaseException:
        _end(proc)
        raise
    return _answer(out, proc.returncode)


def _view_memory(view_memory_bytes: int | None, jobs: int) -> int:
    """Each view's memory limit: the one given, else this machine's room for ``jobs``
    views of one grading (the least a view is given where there is less room)."""
    if view_memory_bytes is not None:
        return int(view_memory_bytes)
    from doorlab.pset.isolation.memory import plan

    return plan(views=jobs, gradings=1, strict=False).view_bytes


def _end(proc: subprocess.Popen) -> None:
    """Ends a supervisor now: it kills everything below it, then exits."""
    proc.terminate()
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def _answer(out: bytes, code: int | None) -> dict:
    """The results a supervisor answered, or GradingError."""
    try:
        results = json.loads(out.decode())
    except (UnicodeDecodeError, ValueError):
        results = None
    if not isinstance(results, dict) or code not in (0, None):
        raise GradingError(f"the grading process failed (exit code {code})")
    if "grader_error" in results:
        raise GradingError(clean_text(f"cannot grade: {results['grader_error']}", 2000))
    return results


class Supervisor:
    """A grading supervisor that serves many gradings, one after the other
    (``python -I -m doorlab.pset.grading.supervisor serve``): its imports, the grader's caches and
    the preparation of the student's view once, not per submission. Each grading is otherwise
    what :func:`grade` starts: its own folder, its own student's view, and every process it
    started dead before its results are returned. Thread-safe (one grading at a time); use
    as a context manager, or :meth:`close`.
    """

    def __init__(self) -> None:
        import threading

        self._proc: subprocess.Popen | None = None
        self._lock = threading.Lock()

    def run(self, request: dict) -> dict:
        """The results of one grading request (see :func:`grade`).

        Raises:
            GradingError: As :func:`grade`.
        """
        with self._lock:
            if self._proc is None or self._proc.poll() is not None:
                self._proc = subprocess.Popen(
                    [sys.executable, "-I", "-m", "doorlab.pset.grading.supervisor", "serve"],
                    cwd="/",
                    env=trusted_environment(),
                    stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE,
                )
            proc = self._proc
            try:
                proc.stdin.write(json.dumps(request).encode() + b"\n")
                proc.stdin.flush()
                line = proc.stdout.readline()
            except BaseException:
                self._proc = None
                _end(proc)
                raise
            if not line:
                self._proc = None
                _end(proc)
                return _answer(b"", proc.returncode)
            return _answer(line, None)

    def close(self) -> None:
        """Ends the supervisor (it exits when its input closes)."""
        with self._lock:
            proc, self._proc = self._proc, None
        if proc is None:
            return
        try:
            proc.stdin.close()
            proc.wait(timeout=30)
        except (OSError, subprocess.TimeoutExpired):
            _end(proc)
        proc.stdout.close()

    def __enter__(self) -> Supervisor:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def grade_reference(*, jobs: int = 2) -> dict[str, dict]:
    """doorlab's reference episodes alone (what every grading compares with), to pass as
    :func:`grade`'s ``reference`` to many gradings.

    Raises:
        GradingError: The grader could not run, or a reference episode failed.
    """
    request = {"reference_only": True, "jobs": int(jobs)}
    proc = subprocess.Popen(
        [sys.executable, "-I", "-m", "doorlab.pset.grading.supervisor", "supervise"],
        cwd="/",
        env=trusted_environment(),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
    )
    try:
        out, _ = proc.communicate(json.dumps(request).encode())
    except BaseException:
        _end(proc)
        raise
    reference = _answer(out, proc.returncode).get("reference")
    for job, result in (reference or {}).items():
        if not isinstance(result.get("figures"), dict):
            why = clean_text(str(result.get("error") or "no figures"), 500)
            raise GradingError(f"doorlab's reference episode {job} failed: {why}")
    if not reference:
        raise GradingError("the grading process answered no reference episodes")
    return reference


def grade_submission(
    source: str | Path,
    *,
    jobs: int = 2,
    reference: dict[str, dict] | None = None,
    assignment: object = None,
    seed: int | None = None,
    require_files: bool = False,
    isolation: str = "require",
    harden: Sequence[str | Path] = (),
    supervisor: Supervisor | None = None,
    only: Sequence[str] | None = None,
    view_memory_bytes: int | None = None,
) -> dict:
    """Grades a submission as every grading path does (``doorlab pset grade``, the folder's
    ``test_pset_5a.py``, Gradescope's ``run_autograder``, ``doorlab pset grade-all``): its
    student files taken by the one intake (:func:`take_files`: flat files, a folder, a
    folder under another, a zip; a missing file's stub), graded in a fresh folder
    (:func:`grade_taken`).

    A submission over an intake bound is not graded: every test 0, the reason in its output.
    The temporary folders are gone when this returns (or raises).

    Args:
        source: The submission: a folder, or a zip file.
        jobs, reference, assignment, isolation, harden, supervisor, only: As for
            :func:`grade`.
        view_memory_bytes: As for :func:`grade`.
        seed: The grading's random seed, as for :func:`grade`.
        require_files: Refuse (OutputError) a submission that holds none of the student
            files (``doorlab pset grade``: a mistyped folder, a notebook alone); without it
            such a submission is not graded either (the one intake's rule): every test 0,
            the reason in the results (Gradescope, ``grade-all``).

    Returns:
        :func:`grade`'s results; their top-level ``output`` says which doorlab graded, what was
        taken from the submission and the grading seed; ``extra_data["submission"]`` lists it.

    Raises:
        OutputError: ``source`` is neither a folder, a zip nor a file; with
            ``require_files``, it holds none of the student files.
        GradingError: As for :func:`grade`.
    """
    files, intake = take_files(source)
    if require_files and intake.nothing:
        raise OutputError(f"{source} is not graded: {intake.refused}")
    return grade_taken(
        files,
        intake,
        jobs=jobs,
        reference=reference,
        assignment=assignment,
        seed=seed,
        isolation=isolation,
        harden=harden,
        supervisor=supervisor,
        only=only,
        view_memory_bytes=view_memory_bytes,
    )


def take_files(source: str | Path):
    """The one intake (:mod:`doorlab.pset.isolation.intake`) of ``source``: its student files' bytes
    by their place in the folder (those taken; a missing one is graded as its stub), and
    the :class:`~doorlab.pset.isolation.intake.Intake` (what was taken, missing, refused).

    Raises:
        OutputError: ``source`` does not exist, or is neither a folder nor a zip file.
    """
    from doorlab.pset.isolation.intake import take

    if not Path(source).exists():
        raise OutputError(f"{source} does not exist")
    return take(source)


def grade_taken(
    files: dict[str, bytes],
    intake,
    *,
    jobs: int = 2,
    reference: dict[str, dict] | None = None,
    assignment: object = None,
    seed: int | None = None,
    isolation: str = "require",
    harden: Sequence[str | Path] = (),
    supervisor: Supervisor | None = None,
    only: Sequence[str] | None = None,
    network_isolated: bool = False,
    view_memory_bytes: int | None = None,
) -> dict:
    """Grades what :func:`take_files` took: a fresh stub folder with ``files`` over its stubs
    (:func:`grade`), or, for a submission the intake refused, every test 0 with the reason.
    Arguments as for :func:`grade`; returns :func:`grade_submission`'s results."""
    from importlib.metadata import version

    from doorlab import __version__
    from doorlab.pset.grading.scoring import results_not_graded
    from doorlab.pset.rules.verdicts import TESTS

    if intake.refused is not None:
        from doorlab.pset.rules.assignment import Assignment

        specs = [t for t in TESTS if only is None or t.name in only]
        results = results_not_graded(specs, intake.refused, assignment or Assignment())
    else:
        # The supervisor writes the fresh folder in its own private folder (it removes it
        # however it ends, a signal included): nothing of the student's is left in /tmp.
        results = grade(
            None,
            files=files,
            jobs=jobs,
            reference=reference,
            assignment=assignment,
            seed=seed,
            isolation=isolation,
            harden=harden,
            supervisor=supervisor,
            only=only,
            network_isolated=network_isolated,
            view_memory_bytes=view_memory_bytes,
        )
    header = f"Graded by doorlab {__version__} (Drake {version('drake')})."
    grading = str(results.get("output") or "")
    taken = intake.summary() if intake.refused is None else ""  # else the output says why
    results["output"] = "\n".join(filter(None, [header, taken, grading]))
    results["extra_data"]["submission"] = intake.to_dict()
    results["extra_data"]["grading_output"] = grading
    return results


def with_intake(results: dict, intake) -> dict:
    """A copy of ``results`` (another submission's grading of the same files) with
    ``intake``'s account of what was taken from this submission: its top-level output and
    ``extra_data.submission`` (the rest is the same: the same files grade the same)."""
    import copy

    out = copy.deepcopy(results)
    header = str(out.get("output") or "").split("\n", 1)[0]
    grading = str(out["extra_data"].get("grading_output") or "")
    taken = intake.summary() if intake.refused is None else ""  # as grade_taken writes it
    out["output"] = "\n".join(filter(None, [header, taken, grading]))
    out["extra_data"]["submission"] = intake.to_dict()
    return out


def write_results(results: dict, path: str | Path) -> Path:
    """Writes Gradescope JSON atomically: a new file in the same folder, flushed to disk,
    renamed over ``path`` (a reader sees the old file or the whole new one)."""
    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
        try:
            with os.fdopen(fd, "w") as f:
                f.write(json.dumps(clean_json(results), indent=2, default=str) + "\n")
                f.flush()
                os.fsync(f.fileno())
            os.chmod(tmp, 0o644)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    except OSError as e:
        raise OutputError(f"cannot write {path}: {e.strerror or e}") from None
    return path


def isolation_warning(results: dict) -> str | None:
    """The summary's first line when the student's code ran without the minimal root (None
    when it ran in it, or when no student process ran)."""
    facts = (results.get("extra_data") or {}).get("sandbox") or {}
    mode = facts.get("mode") if isinstance(facts, dict) else None
    if mode in (None, "bwrap"):
        return None
    why = facts.get("why_no_minimal_root") or "unknown"
    return clean_text(
        f"NOT ISOLATED ({facts.get('policy')}): the student's code ran {facts.get('held')} "
        f"(why: {why})"
    )


def pretty_format_json_results(path: str | Path) -> str:
    """A readable summary of a results file: whether the student's code ran isolated (a
    first line when it did not), its top-level output (the doorlab that graded, what was taken
    from the submission, the grading seed), one block per test and the total. Every text is
    cleaned (:func:`~doorlab.pset.isolation.safe_text.clean_text`): nothing in it can move the
    terminal's cursor or colour the lines."""
    data = json.loads(Path(path).read_text())
    warning = isolation_warning(data)
    lines = [] if warning is None else [warning]
    check = (data.get("extra_data") or {}).get("self_check")
    check = check if isinstance(check, dict) else {}
    if check.get("source"):
        lines.append(clean_text(f"Graded with {check['source']}.", 300))
    lines += clean_text(str(data.get("output") or "")).splitlines()
    notes = check.get("notes") if isinstance(check.get("notes"), dict) else {}
    for t in data["tests"]:
        mark = "PASS" if t["score"] >= t["max_score"] else "FAIL"
        name = clean_text(t["name"], 200)
        note = f" ({clean_text(str(notes[t['name']]), 200)})" if t["name"] in notes else ""
        lines.append(f"[{mark}] {name}: {t['score']:g} / {t['max_score']:g}{note}")
        text = (t.get("extra_data") or {}).get("text_output", t.get("output", ""))
        for line in clean_text(str(text)).splitlines():  # an HTML output's text
            lines.append(f"    {line}")
    not_run = [t for t in check.get("not_run") or [] if isinstance(t, dict)]
    for t in not_run:
        name, why = clean_text(str(t.get("name")), 200), clean_text(str(t.get("why")), 200)
        lines.append(
            f"[LATER] {name}: {float(t.get('points') or 0):g} points, not run here ({why})"
        )
    total = sum(t["max_score"] for t in data["tests"])
    if isinstance(check.get("course_points"), (int, float)):
        total = float(check["course_points"])
    hidden = check.get("hidden_points")
    hidden = float(hidden) if isinstance(hidden, (int, float)) else 0.0
    line = f"Total score: {data['score']:g} / {total + hidden:g}"
    parts = []
    if not_run:
        later = sum(float(t.get("points") or 0) for t in not_run)
        parts.append(f"{later:g} of them in tests this check does not run")
    if hidden:
        parts.append(f"{hidden:g} in hidden tests: graded by your course, not shown or run here")
    lines.append(line + (f" ({'; '.join(parts)})" if parts else ""))
    return "\n".join(lines)


def load_reference(path: str | Path) -> dict[str, dict]:
    """The reference episodes' figures of an earlier results file (its
    ``extra_data["reference"]``), to pass as :func:`grade`'s ``reference``.

    Raises:
        OutputError: The file cannot be read or holds no reference figures.
    """
    try:
        data = json.loads(Path(path).read_text())
        reference = data["extra_data"]["reference"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise OutputError(f"{path}: not a results file with reference figures ({e})") from None
    if not isinstance(reference, dict) or not reference:
        raise OutputError(f"{path}: its results hold no reference figures")
    return reference


def main(argv: Sequence[str]) -> int:
    """``python -I -m doorlab.pset.grading.grader FOLDER [RESULTS_JSON] [--reference FILE]
    [--insecure | --self-check] [--course COURSE_YAML]`` (the folder's ``test_pset_5a.py``
    runs it with ``--self-check``, and ``--course`` when the folder has the handout's
    ``course.yaml``: a student checking their own work needs no isolation from it): grades
    FOLDER's student files as Gradescope does (:func:`grade_submission`), writes the JSON
    (default ``test_results.json`` in the working directory) and prints the summary."""
    import argparse

    from doorlab.errors import interrupt_exit_code

    parser = argparse.ArgumentParser(
        prog="test_pset_5a.py", description="Grades the problem-set folder."
    )
    parser.add_argument("folder", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("out", nargs="?", type=Path, default=Path("test_results.json"))
    parser.add_argument(
        "--reference", type=Path, help="reuse the reference episodes of an earlier results file"
    )
    parser.add_argument(
        "--insecure",
        action="store_true",
        help="grade even where the student's code cannot be isolated (the results say so)",
    )
    parser.add_argument(
        "--self-check",
        action="store_true",
        help="a student checking their own folder: grade isolated where possible, else not",
    )
    parser.add_argument(
        "--course",
        type=Path,
        default=None,
        help="the course's settings (the handout's course.yaml): its points, margins, random seed "
        "and the tests it lets students run",
    )
    args = parser.parse_args(argv)
    folder, out = args.folder.resolve(), args.out.resolve()
    course = None if args.course is None else args.course.resolve()
    os.chdir("/")  # nothing of the folder in this process either
    try:
        from doorlab.pset.handout.course import default_check, load_course

        check = default_check() if course is None else load_course(course)
        reference = None if args.reference is None else load_reference(args.reference)
        policy = "self-check" if args.self_check else "insecure" if args.insecure else "require"
        results = grade_submission(
            folder,
            reference=reference,
            isolation=policy,
            assignment=check.assignment,
            only=check.run,
        )
        if args.self_check or course is not None:
            results["extra_data"]["self_check"] = check.to_dict()
        write_results(results, out)
    except DoorlabError as e:
        print(f"test_pset_5a.py: {e}", file=sys.stderr)
        return 1 if isinstance(e, GradingError) else 2  # as doorlab's CLI
    except KeyboardInterrupt as e:
        return interrupt_exit_code(e)
    print(pretty_format_json_results(out))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
