"""The grader's processes: the supervisor and one trusted process per job.

``python -I -m doorlab.pset.jobs supervise`` (started by :func:`doorlab.pset.grader.grade`)
reads the grading request as JSON on stdin, decides how the student's code is isolated
(:func:`doorlab.pset.isolation.prepare`: the student's view, or the request's policy where
it cannot be built; before any student code runs), runs the jobs ``parallel`` at a time,
judges them and writes the results as JSON on stdout. Each job runs in
``python -I -m doorlab.pset.jobs job ...``: a reference episode, or a test that starts the
student's process (:class:`~doorlab.pset.student.StudentProcess`), talks to it and judges
what it answers. Both are *trusted*: Python's isolated mode (no working directory, no
``PYTHON*`` variables, no user site on ``sys.path``), a working directory in the grading's
private folder, doorlab's code from the installed package only, nothing of the submission
imported. Both are child subreapers and kill every descendant before they answer; the
supervisor answers only after the last job and every process below it are dead.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from doorlab.pset import sandbox

UNIT_TIME_LIMIT_S = 60.0
"""Time limit of a unit test [s] (a correct one takes 2-5 s)."""
EPISODE_TIME_LIMIT_S = 150.0
"""Time limit of an episode [s] (a correct one takes 5-15 s on a busy 2-core machine)."""
JOB_MARGIN_S = 30.0
"""How much longer than its test's limit a trusted job process may run before the
supervisor kills it [s] (it enforces the limit itself; this catches a hung grader)."""
STDERR_KEPT_CHARS = 2000
"""Characters of a trusted job's own stderr kept for a failure's message."""


def time_limit(job: str, scale: float) -> float:
    """The time limit of ``job`` [s]."""
    base = UNIT_TIME_LIMIT_S if job.startswith("unit:") else EPISODE_TIME_LIMIT_S
    return base * scale


def trusted_environment() -> dict[str, str]:
    """The trusted processes' environment: the grader's, one BLAS thread (the processes
    are single-threaded work, and no thread may exist when the student's process forks)."""
    env = dict(os.environ)
    env.update(MPLBACKEND="Agg", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    return env


# One job, in its own trusted process ------------------------------------------------------


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    line = text.splitlines()[0][:500] if text else ""
    return f"{type(e).__name__}: {line}".rstrip(": ")


def run_job(
    job: str,
    folder: Path,
    workdir: Path,
    limit: float,
    isolation_file: Path,
    options: dict | None = None,
) -> dict:
    """Runs one job in this process and returns its JSON-ready result.

    ``isolation_file``: the grading's :class:`~doorlab.pset.isolation.Isolation` (JSON).
    ``options``: ``seed`` (a unit test's random draws: the grading seed) and ``helpers`` (a task 2
    or 3 episode: ``reference`` or ``student``, whose calc_p_Q and calc_R_WL7_ref it runs).
    """
    from doorlab.pset.channel import ProtocolError
    from doorlab.pset.isolation import Isolation
    from doorlab.pset.student import SandboxError, StudentFailure, StudentProcess

    options = options or {}

    kind, _, name = job.partition(":")
    try:
        if kind == "reference":
            from doorlab.pset.episodes import reference_episode

            return {"figures": reference_episode(name)}
        isolation = Isolation.from_json(isolation_file.read_text())
        # The student's process starts first (no thread may exist at its fork), then the
        # grader's side imports Drake while it starts.
        with StudentProcess(folder, workdir, job, limit, isolation) as student:
            try:
                if kind == "unit":
                    from doorlab.pset.checks import UNIT_CHECKS

                    result = UNIT_CHECKS[name](student, options.get("seed"))
                else:
                    from doorlab.pset.episodes import student_episode

                    helpers = options.get("helpers", "reference")
                    result = {"figures": student_episode(student, name, helpers=helpers)}
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


def job_main(argv: list[str]) -> int:
    """``job JOB FOLDER WORKDIR LIMIT PARENT_PID ISOLATION_JSON_FILE OPTIONS_JSON``: the result
    as JSON on stdout."""
    job, folder, workdir, limit, parent, isolation, options = argv
    result_fd = os.dup(1)
    os.dup2(2, 1)  # anything printed (Drake's warnings) goes to stderr, not into the result
    sandbox.die_with_parent(int(parent))
    sandbox.become_subreaper()
    sandbox.make_undumpable()
    result = run_job(
        job, Path(folder), Path(workdir), float(limit), Path(isolation), json.loads(options)
    )
    with os.fdopen(result_fd, "w") as out:
        out.write(json.dumps(result, default=str))
    return 0


# The supervisor ------------------------------------------------------------------------------


class _Jobs:
    """Runs trusted job processes and kills whatever outlives them."""

    def __init__(
        self, folder: Path, workdir: Path, scale: float, isolation: Path, options: dict[str, dict]
    ):
        self.folder, self.workdir, self.scale = folder, workdir, scale
        self.isolation = isolation
        self.options = options  # job -> its options (run_job)
        self.active: set[int] = set()
        self.lock = threading.Lock()

    def run(self, job: str) -> dict:
        limit = time_limit(job, self.scale)
        jobdir = self.workdir / job.replace(":", "_")
        jobdir.mkdir()
        os.chmod(jobdir, 0o711)  # the student's user reaches its scratch folder, lists nothing
        argv = [sys.executable, "-I", "-m", "doorlab.pset.jobs", "job", job]
        argv += [str(self.folder), str(jobdir), repr(limit), str(os.getpid())]
        argv.append(str(self.isolation))
        argv.append(json.dumps(self.options.get(job, {})))
        start = time.perf_counter()
        with self.lock:  # no orphan hunt (below) between the spawn and its registration
            proc = subprocess.Popen(
                argv,
                cwd=jobdir,
                env=trusted_environment(),
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
            )
            self.active.add(proc.pid)
        try:
            out, err = proc.communicate(timeout=limit + JOB_MARGIN_S)
            result = self._parse(out, err, proc.returncode)
        except subprocess.TimeoutExpired:
            proc.kill()
            result = {"passed": False, "error": f"time limit: still running after {limit:.0f} s"}
        finally:
            proc.wait()
            with self.lock:
                self.active.discard(proc.pid)
                # Orphans of a job that died come here (we are their subreaper): kill them.
                sandbox.kill_descendants(keep=self.active, unreaped=self.active)
            proc.communicate()  # closes the pipes (nothing holds them any more)
        result["seconds"] = time.perf_counter() - start
        return result

    @staticmethod
    def _parse(out: bytes, err: bytes, code: int) -> dict:
        try:
            result = json.loads(out.decode())
            if isinstance(result, dict):
                return result
        except (UnicodeDecodeError, ValueError):
            pass
        tail = err.decode("utf-8", "replace")[-STDERR_KEPT_CHARS:]
        how = f"killed by signal {-code}" if code < 0 else f"exit code {code}"
        return {
            "passed": False,
            "error": f"the grader's process for this test ended without a result ({how})",
            "output": tail,
        }


def _order(jobs: set[str]) -> list[str]:
    # Longest first (episodes), so the workers finish together.
    return sorted(jobs, key=lambda j: (j.startswith("unit:"), j))


def _seed(request: dict, folder: Path, assignment) -> dict:
    """The grading's seed: ``--seed``'s, or from the assignment's and the graded files'."""
    from doorlab.pset.assignment import files_digest, grading_seed
    from doorlab.pset.verdicts import STUDENT_FILES

    digest = files_digest(folder, STUDENT_FILES)
    if request.get("seed") is not None:
        return {
            "grading": int(request["seed"]),
            "source": "given with --seed",
            "files_sha256": digest,
        }
    return {
        "grading": grading_seed(assignment.seed, digest),
        "source": "from the assignment's random seed and your files' SHA-256",
        "files_sha256": digest,
    }


def _job_options(specs, assignment, seed: int) -> dict[str, dict]:
    """Each job's options (:func:`run_job`): the grading seed; an episode's helpers."""
    from doorlab.pset.verdicts import test_settings

    options: dict[str, dict] = {}
    for spec in specs:
        settings = test_settings(assignment, spec)
        for job in spec.needed_jobs(settings):
            options.setdefault(job, {"seed": seed})
            if job.startswith("student:") and spec.helpers:
                student = spec.uses_student_helpers(settings)
                options[job]["helpers"] = "student" if student else "reference"
    return options


def supervise(request: dict) -> dict:
    """Runs the request's jobs and returns the Gradescope results (or ``{"grader_error"}``)."""
    from doorlab.errors import ConfigError
    from doorlab.pset.assignment import Assignment, assignment_from_dict
    from doorlab.pset.verdicts import TESTS, results_from_jobs, test_settings

    folder = Path(request["folder"])
    try:
        data = request.get("assignment")
        assignment = assignment_from_dict(data) if data is not None else Assignment()
    except ConfigError as e:
        return {"grader_error": f"the assignment: {e}"}
    only = request.get("only")
    specs = [t for t in TESTS if only is None or t.name in only]
    drawn = _seed(request, folder, assignment)
    options = _job_options(specs, assignment, drawn["grading"])
    needed = {j for t in specs for j in t.needed_jobs(test_settings(assignment, t))}
    results: dict[str, dict] = {}
    reference = request.get("reference") or {}
    results.update({k: v for k, v in reference.items() if k in needed})
    todo = _order(needed - set(results))
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="doorlab_grade_") as tmp:
        workdir = Path(tmp)
        os.chmod(workdir, 0o711)
        os.chdir(workdir)
        try:
            student_jobs = [j for j in todo if not j.startswith("reference:")]
            isolation = _isolation(request, workdir) if student_jobs else None
            if isinstance(isolation, str):
                return {"grader_error": isolation}
            isolation_file = workdir / "isolation.json"
            isolation_file.write_text(isolation.to_json() if isolation else "{}")
            os.chmod(isolation_file, 0o600)
            scale = float(request.get("time_limit_scale", 1.0))
            runner = _Jobs(folder, workdir, scale, isolation_file, options)
            with ThreadPoolExecutor(max_workers=max(1, int(request.get("jobs", 2)))) as pool:
                for job, result in zip(todo, pool.map(runner.run, todo), strict=True):
                    results[job] = result
        finally:
            sandbox.kill_descendants()
            os.chdir("/")
    errors = [r["grader_error"] for r in results.values() if "grader_error" in r]
    if errors:
        return {"grader_error": errors[0]}
    elapsed = time.perf_counter() - start
    return results_from_jobs(specs, results, elapsed, assignment, drawn, isolation)


def _isolation(request: dict, workdir: Path):
    """The grading's :class:`~doorlab.pset.isolation.Isolation`, or why there is none (str)."""
    from doorlab.pset.isolation import IsolationError, prepare

    try:
        return prepare(workdir, request.get("isolation", "require"), request.get("harden") or ())
    except (IsolationError, OSError) as e:
        return str(e)


def _on_signal(signum, frame):
    sandbox.kill_descendants()
    os._exit(128 + signum)


def supervise_main() -> int:
    """``supervise``: the request on stdin, the results on stdout."""
    parent = os.getppid()
    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, _on_signal)
    sandbox.die_with_parent(parent, signal.SIGTERM)
    sandbox.become_subreaper()
    sandbox.make_undumpable()
    request = json.loads(sys.stdin.read())
    results = supervise(request)
    sys.stdout.write(json.dumps(results, default=str))
    sys.stdout.flush()
    return 0


def main(argv: list[str]) -> int:
    if argv[:1] == ["supervise"]:
        return supervise_main()
    if argv[:1] == ["job"]:
        return job_main(argv[1:])
    print("usage: python -I -m doorlab.pset.jobs {supervise | job ...}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
