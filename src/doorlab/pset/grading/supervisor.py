"""The grading supervisor: a grading request in, its results out; every job forked from it.

``python -I -m doorlab.pset.grading.supervisor supervise`` (started by
:func:`doorlab.pset.grading.grader.grade`; ``serve``: one request per line,
:class:`doorlab.pset.grading.grader.Supervisor`) reads the grading request as JSON on stdin, decides
how the student's code is isolated (:func:`doorlab.pset.isolation.choice.prepare`: the student's
view, or the request's policy where it cannot be built; before any student code runs), makes the
grading's cgroups (:mod:`doorlab.pset.isolation.cgroups`), imports what the jobs need (pydrake, the
checks, the episodes) and computes what does not depend on the submission (the controller's plant,
the grasp configuration, the reference helpers' table) once, then runs the jobs
(:mod:`doorlab.pset.grading.jobs`), judges them and writes the results as JSON on stdout. Its
private folders (the submission's copy, the grading's, the prepared view) and the grading's
cgroups are removed however it ends, a signal included.
"""

from __future__ import annotations

import json
import os
import re
import signal
import sys
import tempfile
import time
from pathlib import Path

from doorlab.pset.grading.jobs import _Jobs
from doorlab.pset.isolation import sandbox
from doorlab.runtime.folders import private_folder, remove_staged_folders

_EPISODE_ORDER = ("impedance", "velocity", "ik")
"""The episodes, longest first (closed doors: contact; open doors; the IK's joint-space plan)."""


def _order(jobs: set[str]) -> list[str]:
    """Longest first (episodes), so the processes finish together: the student's episodes
    (one at a time in the view) alternate with the reference's, then the unit tests."""

    def key(job: str) -> tuple:
        kind, _, name = job.partition(":")
        rank = _EPISODE_ORDER.index(name) if name in _EPISODE_ORDER else len(_EPISODE_ORDER)
        return (kind == "unit", rank, kind != "student", job)

    return sorted(jobs, key=key)


def _seed(request: dict, folder: Path, assignment) -> dict:
    """The grading's seed: ``--seed``'s, or from the assignment's and the graded files'."""
    from doorlab.pset.rules.assignment import files_digest, grading_seed
    from doorlab.pset.rules.verdicts import STUDENT_FILES

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


def _practice(drawn: dict, options: dict[str, dict], reference: dict) -> tuple[dict, dict]:
    """The students' doorlab grades against the handout's practice table
    (:mod:`doorlab.pset.handout.edition`): each unit test's expectations and draws, the reference
    helpers' table, the reference figures (unless given); returns (the random seed's record, the
    reference)."""
    from doorlab.pset.handout import edition

    table = edition.practice()
    for job, settings in options.items():
        kind, _, name = job.partition(":")
        settings["seed"] = table["seed"]
        if kind == "unit":
            settings["expect"] = table["units"][name]
        elif kind == "student" and settings.get("helpers", "reference") == "reference":
            settings["table"] = table["helpers"]  # a practised episode's: in the table
    source = (
        "the handout's practice draws (this doorlab holds no answer key: the course's "
        "grading draws its own from your files)"
    )
    drawn = {**drawn, "grading": table["seed"], "source": source}
    return drawn, reference or table["reference"]


def _job_options(specs, assignment, seed: int) -> dict[str, dict]:
    """Each job's options (:func:`run_job`): the grading seed; an episode's helpers."""
    from doorlab.pset.rules.verdicts import test_settings

    options: dict[str, dict] = {}
    for spec in specs:
        settings = test_settings(assignment, spec)
        for job in spec.needed_jobs(settings):
            options.setdefault(job, {"seed": seed})
            if job.startswith("student:") and spec.helpers:
                student = spec.uses_student_helpers(settings)
                options[job]["helpers"] = "student" if student else "reference"
    return options


def supervise(request: dict, prepared: dict | None = None) -> dict:
    """Runs the request's jobs and returns the Gradescope results (or ``{"grader_error"}``;
    ``{"reference"}`` for a ``reference_only`` request: the reference episodes' results).

    ``prepared``: a long-lived supervisor's cache of the student's view (prepared once).
    """
    from doorlab.errors import ConfigError
    from doorlab.pset.grading.scoring import results_from_jobs
    from doorlab.pset.rules.assignment import Assignment, assignment_from_dict
    from doorlab.pset.rules.verdicts import TESTS, test_settings

    if request.get("reference_only"):
        todo = _order({j for t in TESTS for j in t.jobs if j.startswith("reference:")})
        parallel = max(1, int(request.get("jobs", 2)))
        return {"reference": _run(None, todo, {}, request, parallel, prepared)[0]}
    if request.get("files") is not None:
        with private_folder(_prefix("submission")) as tmp:
            folder = _submission_folder(request["files"], tmp)
            return supervise({**request, "files": None, "folder": str(folder)}, prepared)
    folder = Path(request["folder"])
    try:
        data = request.get("assignment")
        assignment = assignment_from_dict(data) if data is not None else Assignment()
    except ConfigError as e:
        return {"grader_error": f"the assignment: {e}"}
    only = request.get("only")
    specs = [t for t in TESTS if only is None or t.name in only]
    from doorlab.pset.handout import edition

    if edition.students():  # only what the handout practises: nothing of a hidden test
        names = set(edition.practised(t.name for t in specs))
        specs = [t for t in specs if t.name in names]
    drawn = _seed(request, folder, assignment)
    options = _job_options(specs, assignment, drawn["grading"])
    needed = {j for t in specs for j in t.needed_jobs(test_settings(assignment, t))}
    results: dict[str, dict] = {}
    reference = request.get("reference") or {}
    if edition.students():  # no answer key here: the handout's practice table
        drawn, reference = _practice(drawn, options, reference)
    results.update({k: v for k, v in reference.items() if k in needed})
    todo = _order(needed - set(results))
    start = time.perf_counter()
    parallel = max(1, int(request.get("jobs", 2)))
    ran, isolation = _run(folder, todo, options, request, parallel, prepared)
    if isinstance(isolation, str):
        return {"grader_error": isolation}
    if request.get("network_isolated") and isolation is not None:
        if not isolation.network_isolated:  # checked before any job ran (see _run)
            return {"grader_error": _NO_NETWORK_NAMESPACE}
    cgroup = ran.pop(_CGROUP_KEY, None)
    results.update(ran)
    errors = [r["grader_error"] for r in results.values() if "grader_error" in r]
    if errors:
        return {"grader_error": errors[0]}
    elapsed = time.perf_counter() - start
    out = results_from_jobs(specs, results, elapsed, assignment, drawn, isolation)
    sandbox_facts = out.get("extra_data", {}).get("sandbox")
    if isinstance(sandbox_facts, dict) and cgroup is not None:
        sandbox_facts["cgroup"] = cgroup
    return out


_NO_NETWORK_NAMESPACE = (
    "this worker would run the student's code without a network namespace (no bubblewrap "
    "view, not root), so it could reach the cluster: not graded here"
)
_CGROUP_KEY = "_cgroup"
"""Where :func:`_run` puts what the grading's cgroups were (not a job)."""


def _run(folder, todo: list[str], options: dict, request: dict, parallel: int, prepared):
    """Runs ``todo`` in a private folder: (results by job, the isolation or why there is
    none)."""
    _warm(todo, options)
    with private_folder(_prefix("grade")) as workdir:
        os.chmod(workdir, 0o711)
        os.chdir(workdir)
        runner = groups = None
        try:
            student_jobs = [j for j in todo if not j.startswith("reference:")]
            isolation = _isolation(request, workdir, prepared) if student_jobs else None
            if isinstance(isolation, str):
                return {}, isolation
            if request.get("network_isolated") and isolation is not None:
                if not isolation.network_isolated:  # no student code runs: refused
                    return {}, isolation
            scale = float(request.get("time_limit_scale", 1.0))
            groups, cgroup = _grading_groups(isolation, request.get("view_memory_bytes"))
            if groups is not None:
                _OWN_GROUPS.append(groups)
            runner = _Jobs(folder, workdir, scale, isolation, options, groups)
            ran = runner.run(todo, parallel)
            if cgroup is not None:
                ran[_CGROUP_KEY] = cgroup
            return ran, isolation
        finally:
            if runner is not None:
                runner.close()
            sandbox.kill_descendants()
            if groups is not None:
                groups.close()
                _OWN_GROUPS.remove(groups)
            os.chdir("/")


def _submission_folder(files: dict[str, str], tmp: Path) -> Path:
    """A fresh stub folder in ``tmp`` (a private folder of this supervisor's) with the
    request's student files (base64) over its stubs; returns the folder."""
    import base64

    from doorlab.pset.handout.folder import init_folder
    from doorlab.pset.rules.verdicts import STUDENT_FILES

    folder = init_folder(tmp / "pset")
    for rel, data in files.items():
        if rel not in STUDENT_FILES:
            raise ValueError(f"not a student file: {rel!r}")
        (folder / rel).write_bytes(base64.b64decode(data))
    return folder


def _grading_groups(isolation, view_memory_bytes: int | None = None):
    """The grading's cgroups (:mod:`doorlab.pset.isolation.cgroups`; each view's memory limit
    ``view_memory_bytes``, :mod:`doorlab.pset.isolation.memory`'s plan) and what the results say
    of them: (groups or None, description or None without a student process)."""
    from doorlab.pset.isolation.cgroups import VIEW_MEMORY_BYTES, CgroupError, GradingGroups

    setup = None if isolation is None else isolation.cgroup_setup()
    if setup is None:
        return None, None
    if setup.version is None:
        return None, setup.describe()
    view_bytes = int(view_memory_bytes or VIEW_MEMORY_BYTES)
    try:
        groups = GradingGroups(setup, view_bytes)
    except CgroupError as e:
        return None, {"version": None, "why_none": str(e)}
    return groups, setup.describe(view_bytes)


def _warm(todo: list[str], options: dict[str, dict]) -> None:
    """Imports what the jobs need and computes what does not depend on the submission, once,
    before the jobs are forked (each would otherwise do it again)."""
    from doorlab.cell.station import make_controller_plant
    from doorlab.pset.grading import checks, episodes  # noqa: F401 - pydrake, the checks

    make_controller_plant()
    plans = [j for j in todo if j in ("student:velocity", "student:impedance")]
    if plans:
        episodes.grasp_configuration()
    helpers = [options.get(j, {}) for j in plans]
    if any(o.get("helpers", "reference") == "reference" and "table" not in o for o in helpers):
        from doorlab.pset.grading.answer_key import reference_helper_table

        reference_helper_table()


def _isolation(request: dict, workdir: Path, prepared: dict | None = None):
    """The grading's :class:`~doorlab.pset.isolation.choice.Isolation`, or why there is none (str).

    ``prepared``: a long-lived supervisor's cache (its ``"folder"``: where the student side
    is built once; the isolation by policy and hardened paths)."""
    from doorlab.pset.isolation.choice import IsolationError, prepare

    policy, harden = request.get("isolation", "require"), tuple(request.get("harden") or ())
    if prepared is not None and (policy, harden) in prepared:
        return prepared[(policy, harden)]
    where = workdir
    if prepared is not None:
        where = Path(tempfile.mkdtemp(prefix="view_", dir=prepared["folder"]))
        os.chmod(where, 0o711)
    try:
        isolation = prepare(where, policy, harden)
    except (IsolationError, OSError) as e:
        return str(e)
    if prepared is not None:
        prepared[(policy, harden)] = isolation
    return isolation


FOLDER_KINDS = ("supervisor", "submission", "grade")
"""A supervisor's private folders in ``TMPDIR``: ``doorlab_<kind>_<its pid>_<random>`` (its
long-lived one, the submission's copy, a grading's)."""
_FOLDER = re.compile(r"doorlab_(" + "|".join(FOLDER_KINDS) + r")_(\d+)_[a-z0-9_]{8}")
"""A supervisor's folder: its prefix and tempfile's 8 random characters (an older doorlab's,
without the pid, is too short to match)."""


def _prefix(kind: str) -> str:
    return f"doorlab_{kind}_{os.getpid()}_"


def _started_after(pid: int, when: float) -> bool:
    """Whether process ``pid`` started after ``when`` (a time.time()): not the one that
    made a folder then."""
    try:
        ticks = int(Path(f"/proc/{pid}/stat").read_bytes().rsplit(b")", 1)[1].split()[19])
        boot = next(
            float(line.split()[1])
            for line in Path("/proc/stat").read_text().splitlines()
            if line.startswith("btime ")
        )
    except (OSError, ValueError, IndexError, StopIteration):
        return False
    return boot + ticks / os.sysconf("SC_CLK_TCK") > when + 1.0


def remove_stale_folders(where: str | None = None) -> list[str]:
    """Removes the private folders of supervisors that are gone (killed outright, by SIGKILL
    or the kernel, before they could remove them): this user's folders in ``TMPDIR`` (or
    ``where``) named by :func:`_prefix` whose pid is not running, or is a later process.
    Returns the names removed."""
    import shutil

    folder = Path(where or tempfile.gettempdir())
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        match = _FOLDER.fullmatch(entry.name)
        if match is None:
            continue
        try:
            info = entry.stat(follow_symlinks=False)
        except OSError:
            continue
        if info.st_uid != os.geteuid() or not entry.is_dir(follow_symlinks=False):
            continue
        pid = int(match.group(2))
        if pid == os.getpid():
            continue
        try:
            os.kill(pid, 0)
            alive = not _started_after(pid, info.st_mtime)
        except ProcessLookupError:
            alive = False
        except PermissionError:
            alive = True
        if not alive:
            shutil.rmtree(entry.path, ignore_errors=True)
            removed.append(entry.name)
    return removed


_OWN_GROUPS: list = []
"""The cgroups of the grading running now (:mod:`doorlab.pset.isolation.cgroups`)."""


def _on_signal(signum, frame):
    """Ends the supervisor: its processes, its cgroups and its private folders (the
    submission's copy, the grading's, the prepared views: :func:`private_folder`'s, which
    ``os._exit`` would otherwise leave) go with it."""
    sandbox.kill_descendants()
    for groups in _OWN_GROUPS:
        groups.close()
    remove_staged_folders()
    os._exit(128 + signum)


def _supervisor_setup(*, interrupt: bool = True):
    """The supervisor's own settings; returns its answer stream (what it prints otherwise,
    and what Drake prints, goes to stderr). ``interrupt``: Ctrl-C ends it (else its parent,
    a batch's worker, ends it when the batch is interrupted)."""
    from doorlab.pset.isolation.memory import protect_trusted

    parent = os.getppid()
    protect_trusted()  # the OOM killer ends a student's process first, never this one
    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, _on_signal)
    if not interrupt:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    sandbox.die_with_parent(parent, signal.SIGTERM)
    sandbox.become_subreaper()
    sandbox.make_undumpable()
    answers = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)
    remove_stale_folders()  # of supervisors killed outright (SIGKILL, the OOM killer)
    return answers


def _answer(request: dict, prepared: dict | None = None) -> dict:
    """:func:`supervise`'s results, or the grader's error in one line where this machine
    failed it (a full ``TMPDIR``: ENOSPC; no temporary folder), never a traceback."""
    from doorlab.errors import DoorlabError

    try:
        return supervise(request, prepared)
    except (OSError, DoorlabError) as e:
        text = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
        where = f" ({e.filename})" if isinstance(e, OSError) and e.filename else ""
        return {"grader_error": f"the grader could not write its temporary files{where}: {text}"}


def supervise_main() -> int:
    """``supervise``: the request on stdin, the results on stdout."""
    answers = _supervisor_setup()
    request = json.loads(sys.stdin.read())
    results = _answer(request)
    answers.write(json.dumps(results, default=str))
    answers.flush()
    return 0


def serve_main() -> int:
    """``serve``: one request per line on stdin, one results line each on stdout, until
    stdin closes (:class:`doorlab.pset.grading.grader.Supervisor`)."""
    from doorlab.errors import DoorlabError

    answers = _supervisor_setup(interrupt=False)
    try:
        with private_folder(_prefix("supervisor")) as folder:
            os.chmod(folder, 0o711)
            prepared = {"folder": str(folder)}
            for line in sys.stdin:
                results = _answer(json.loads(line), prepared)
                answers.write(json.dumps(results, default=str) + "\n")
                answers.flush()
    except (OSError, DoorlabError) as e:  # no folder of its own: every request the error
        why = {"grader_error": f"the grader could not make its temporary folder: {e}"}
        for _line in sys.stdin:
            answers.write(json.dumps(why) + "\n")
            answers.flush()
    return 0


def main(argv: list[str]) -> int:
    """``supervise`` (one request on stdin) or ``serve`` (one per line)."""
    if argv[:1] == ["supervise"]:
        return supervise_main()
    if argv[:1] == ["serve"]:
        return serve_main()
    print(
        "usage: python -I -m doorlab.pset.grading.supervisor {supervise | serve}", file=sys.stderr
    )
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
