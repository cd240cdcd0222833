"""Shared fixtures: full episodes are expensive (~3-5 s each), so each is run once per session.

The suite runs on pytest-xdist's workers (``addopts`` in pyproject.toml; ``-n auto`` is
:func:`pytest_xdist_auto_num_workers`), a test file per worker at a time. A test's real-time
section (``with realtime():``: LCM processes paced to the wall clock, with tolerances derived
from their latency) must get a core the moment its processes wake. Where they can have
real-time priority (tests/realtime_priority.py: as root), they do, and ordinary tests run
beside them: one of the workers (a worker per core) runs the real-time files while the others
keep the cores busy. Elsewhere a real-time test runs beside nothing but other real-time tests
(tests/run_lock.py), on every worker at the start of the run.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import threading
import time
from collections.abc import Callable
from functools import cache
from typing import TypeVar

import file_order
import pytest
import realtime_priority
import run_cost
from run_lock import RunLock, read_waits
from shared_cache import RUN_DIR_ENV, run_dir

os.environ.setdefault("MPLBACKEND", "Agg")
T = TypeVar("T")


def pytest_configure(config: pytest.Config) -> None:
    # The run's shared folder (tests/shared_cache.py, the locks below), made by the main
    # process before pytest-xdist starts its workers, which inherit the variable.
    if not hasattr(config, "workerinput") and RUN_DIR_ENV not in os.environ:
        config._doorlab_run_dir = tempfile.mkdtemp(prefix="doorlab-pytest-")
        os.environ[RUN_DIR_ENV] = config._doorlab_run_dir
    if not hasattr(config, "workerinput"):
        config._doorlab_start = run_cost.mark()  # what the run costs (the summary's CPU line)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--record-durations",
        action="store_true",
        help="write each file's measured time and CPU to tests/durations.json "
        "(tests/file_order.py: the order the files are handed to the workers)",
    )


REALTIME_FILES = "realtime_files.json"
"""In the run's folder: the names of the files with real-time tests, written by the workers'
collections for the scheduler (:func:`pytest_xdist_make_scheduler`)."""


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The files in tests/file_order.py's order (the same on every worker: computed from the
    collection and durations.json only); the tests of a file keep theirs."""
    realtime = {item.path.name for item in items if _is_realtime(item)}
    folder = run_dir()
    if hasattr(config, "workerinput") and folder is not None:  # for the scheduler
        partial = folder / f".{REALTIME_FILES}.{config.workerinput['workerid']}"
        partial.write_text(json.dumps(sorted(realtime)))
        os.replace(partial, folder / REALTIME_FILES)
    durations, cpu = file_order.read_durations(), file_order.read_cpu()
    rank = {
        name: i
        for i, name in enumerate(
            file_order.file_order({i.path.name for i in items}, realtime, durations, cpu)
        )
    }
    items.sort(key=lambda item: rank[item.path.name])


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int | None:
    """``-n auto``: a worker per core, no more (more workers than cores would make every
    test's own timing a statement about an overloaded host). Where the paced processes have
    real-time priority, the real-time files go to one worker as one unit of work and the
    others run ordinary tests meanwhile. PYTEST_XDIST_AUTO_NUM_WORKERS, if set, is
    pytest-xdist's to read."""
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None
    return run_cost.cores()


@pytest.hookimpl(tryfirst=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log):
    """``--dist loadfile`` with the real-time files in bins (tests/file_order.py): a bin is
    one unit of work, each other file one, in the collection's order. At real-time priority
    one bin (one worker runs them all, beside the others' ordinary tests), else a bin per
    worker (every worker runs them at the start, beside nothing else). It survives a worker
    that dies (tests/xdist_scheduler.py)."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist_scheduler import RealtimeBins

    def bins(workers: int) -> dict[str, str]:
        path = run_dir() / REALTIME_FILES
        realtime = json.loads(path.read_text()) if path.is_file() else []
        durations = file_order.read_durations()
        count = 1 if realtime_priority.problem() is None else workers
        return file_order.realtime_bins(realtime, durations, count)

    return RealtimeBins(config, log, bins)


CPU_PROPERTY = "cpu_s"
"""With --record-durations: a phase report's CPU [s] (its worker's and the processes it
waited for meanwhile), in the report's user_properties."""


_PHASE_START: dict[str, run_cost.Mark] = {}
"""With --record-durations, in a worker: where the test's current phase began."""


def pytest_runtest_logstart(nodeid: str, location) -> None:
    if _RECORDING.get("on"):
        _PHASE_START["mark"] = run_cost.mark()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo):
    """Each phase's report carries its CPU (with --record-durations): from the end of the
    previous phase (the test's start for its setup) to now."""
    outcome = yield
    start = _PHASE_START.get("mark")
    if start is not None:
        end = _PHASE_START["mark"] = run_cost.mark()
        outcome.get_result().user_properties.append((CPU_PROPERTY, run_cost.used(start, end)))


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    times, cpu = _RECORDED.get("times"), _RECORDED.get("cpu")
    if times is not None and cpu is not None:
        name = report.nodeid.split("::")[0].rsplit("/", 1)[-1]
        times[name] = times.get(name, 0.0) + report.duration
        used = dict(report.user_properties).get(CPU_PROPERTY, 0.0)
        cpu[name] = cpu.get(name, 0.0) + float(used)


_RECORDED: dict[str, dict[str, float]] = {}
"""With --record-durations, in the main process: the times and CPU measured so far by
file [s]."""


_RECORDING: dict[str, bool] = {}
"""{"on": True} in every process of a run with --record-durations."""


def pytest_sessionstart(session: pytest.Session) -> None:
    if session.config.getoption("record_durations"):
        _RECORDING["on"] = True
        if not hasattr(session.config, "workerinput"):
            _RECORDED.update(times={}, cpu={})


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    times, cpu = _RECORDED.pop("times", None), _RECORDED.pop("cpu", None)
    if times:  # the files this run measured replace theirs; the others are kept
        file_order.write_durations(
            {**file_order.read_durations(), **times}, {**file_order.read_cpu(), **(cpu or {})}
        )


def pytest_unconfigure(config: pytest.Config) -> None:
    folder = getattr(config, "_doorlab_run_dir", None)
    if folder is not None:
        shutil.rmtree(folder, ignore_errors=True)
        os.environ.pop(RUN_DIR_ENV, None)


def _run_lock(config: pytest.Config) -> RunLock | None:
    """This worker's lock (None when not under xdist: then nothing else runs)."""
    folder = run_dir()
    if not hasattr(config, "workerinput") or folder is None:
        return None
    if not hasattr(config, "_doorlab_run_lock"):
        config._doorlab_run_lock = RunLock(folder, config.workerinput["workerid"])
    return config._doorlab_run_lock


def _is_realtime(item: pytest.Item) -> bool:
    """Whether the test has real-time sections (the ``realtime`` fixture)."""
    return "realtime" in getattr(item, "fixturenames", ())


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None):
    """Setup, call and teardown of each test (module fixtures included) in the lock
    (tests/run_lock.py): as an ordinary test, or as a real-time one (the ``realtime``
    fixture); no lock where the paced processes have real-time priority."""
    lock = _run_lock(item.config) if realtime_priority.problem() else None
    if lock is not None:
        lock.realtime() if _is_realtime(item) else lock.test()
    try:
        yield
    finally:
        if lock is not None:
            lock.release()


GRADER_TEST_FILES = {
    "test_pset.py",
    "test_pset_sandbox.py",
    "test_pset_autograder.py",
    "test_pset_isolation.py",
    "test_pset_semester.py",
}
"""Test files that grade: the grader runs student code in bubblewrap's minimal root, or not
at all (doorlab.pset.isolation.choice)."""


@cache
def _bubblewrap_problem() -> str | None:
    """Why bwrap cannot run a sandbox here (None: it can)."""
    import subprocess

    bwrap = shutil.which("bwrap")
    if bwrap is None:
        return "bubblewrap (bwrap) is not installed (Debian/Ubuntu: apt-get install bubblewrap)"
    user = [] if os.geteuid() == 0 else ["--unshare-user"]
    argv = [bwrap, "--unshare-pid", "--unshare-net", *user, "--ro-bind", "/", "/", "true"]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    if proc.returncode != 0:
        return f"bwrap cannot make its namespaces here: {proc.stderr.strip()[:200]}"
    return None


def pytest_runtest_setup(item: pytest.Item) -> None:
    """The grading tests need bubblewrap: without it they skip saying so (fail under
    CI=true, whose .ci/run installs it)."""
    if item.path.name not in GRADER_TEST_FILES:
        return
    problem = _bubblewrap_problem()
    if problem is None:
        return
    if os.environ.get("CI") == "true":
        pytest.fail(f"the grader's tests need bubblewrap: {problem}")
    pytest.skip(f"the grader's tests need bubblewrap: {problem}")


@pytest.fixture(scope="session", autouse=True)
def _session_working_directory(tmp_path_factory):
    """Module and session fixtures run in a folder of the run's own: nothing they write
    relative to the working directory lands in the checkout, and nothing there (a user's
    ``doorlab_out/``) changes what they see."""
    previous = os.getcwd()
    os.chdir(tmp_path_factory.mktemp("cwd"))
    yield
    os.chdir(previous)


@pytest.fixture(autouse=True)
def _working_directory(tmp_path_factory, monkeypatch):
    """Each test runs in an empty folder of its own (a command a test runs without ``cwd``
    writes its default output folder there, never into the checkout or another test's)."""
    monkeypatch.chdir(tmp_path_factory.mktemp("cwd"))


@pytest.fixture
def realtime(request):
    """``with realtime(): ...``: a real-time section (LCM processes paced to the wall clock,
    tolerances derived from their latency), the test's own process at real-time priority and
    its paced processes started with it (tests/realtime_priority.py) where it can be had.
    Elsewhere a test that asks for this fixture runs, setup to teardown, while no other worker
    runs an ordinary test (tests/run_lock.py); its work outside the sections must then be
    light (one thread, a second or so), or go through ``heavy``. The sections are timed for
    the run's summary."""

    @contextlib.contextmanager
    def section():
        began = time.monotonic()
        try:
            with realtime_priority.realtime_process():  # the test's own listener, answers
                yield
        finally:
            if run_dir() is not None:
                _record_section(request.node.nodeid, began, time.monotonic())

    return section


def run_at_idle_priority(call: Callable[[], T]) -> T:
    """``call()`` in a thread of Linux's idle scheduling class (``SCHED_IDLE``): it runs only
    on a core that no other process wants, so a real-time section's processes, woken, take
    the core at once. Returns its result or raises its exception."""
    box: dict = {}

    def target() -> None:
        try:
            if hasattr(os, "SCHED_IDLE"):
                os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))  # this thread only
            box["value"] = call()
        except BaseException as e:  # handed to the caller
            box["error"] = e

    thread = threading.Thread(target=target, name="heavy")
    thread.start()
    thread.join()
    if "error" in box:
        raise box["error"]
    return box["value"]


@pytest.fixture
def heavy():
    """``heavy(call)``: a real-time test's heavy work (a one-process episode running flat
    out); returns ``call()``. Where the paced processes lack real-time priority it runs at
    idle priority (:func:`run_at_idle_priority`), so that it never delays another worker's
    real-time section beside it; else as any other work (ordinary tests run beside anyway)."""
    if realtime_priority.problem() is None:
        return lambda call: call()
    return run_at_idle_priority


SECTIONS_FILE = "realtime_sections.jsonl"
"""In the run's folder: each real-time section's start and end (``time.monotonic()``, the same
clock in every worker) [s]."""


def _record_section(test: str, began: float, ended: float) -> None:
    with open(run_dir() / SECTIONS_FILE, "a") as f:
        f.write(json.dumps({"test": test, "began": began, "ended": ended}) + "\n")


def _covered(intervals: list[tuple[float, float]]) -> float:
    """The length of the union of the intervals [s]."""
    total, end = 0.0, -float("inf")
    for a, b in sorted(intervals):
        if b > end:
            total += b - max(a, end)
            end = b
    return total


def pytest_terminal_summary(terminalreporter, exitstatus, config) -> None:
    """What the real-time sections cost the run: how long they ran, side by side or not, and
    how long workers waited for their turn (idle: tests/run_lock.py) (docs/development.md);
    the docs' blocks the docs tests ran (tests/doc_commands.py), each with its time; and the
    CPU the run used against its cores' time (tests/run_cost.py)."""
    if not hasattr(config, "workerinput"):
        import doc_commands

        start = getattr(config, "_doorlab_start", None)
        if start is not None:  # the workers are reaped by now: their CPU is counted
            terminalreporter.write_line(run_cost.summary(start, run_cost.mark(), run_cost.cores()))

        for row in doc_commands.report():
            terminalreporter.write_line(
                f"docs: {row['page']} block {row['block']} (line {row['line']}): {row['how']}"
                + (f", {row['seconds']:.0f} s" if row["how"] == "ran" else "")
                + f": {row['first'][:70]}"
            )
    folder = run_dir()
    path = None if folder is None else folder / SECTIONS_FILE
    if hasattr(config, "workerinput") or path is None or not path.is_file():
        return
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    summed = sum(r["ended"] - r["began"] for r in rows)
    covered = _covered([(r["began"], r["ended"]) for r in rows])
    waits = read_waits(folder)
    waited = {
        kind: sum(w["waited"] for w in waits if w["for"] == kind) for kind in ("test", "realtime")
    }
    terminalreporter.write_line(
        f"real-time sections: {len(rows)}, {summed:.0f} s in all, {covered:.0f} s of the run's "
        f"wall time; workers idle waiting for their turn: {waited['test']:.0f} s before ordinary "
        f"tests, {waited['realtime']:.0f} s before real-time ones"
    )


@cache
def _run(controller: str, doors: str, knots: int | None, inner_loop: str = "stiffness"):
    from doorlab.cell.geometry import default_door_geometry
    from doorlab.config import Scenario
    from doorlab.episode.controllers import run_controller
    from doorlab.episode.metrics import compute_metrics

    scenario = Scenario(controller=controller, doors=doors)
    scenario.station.inner_loop.kind = inner_loop
    if knots is not None:
        scenario.ik.knots = knots
    result, arc = run_controller(scenario)
    metrics = compute_metrics(result, scenario, default_door_geometry())
    return scenario, result, arc, metrics


@pytest.fixture(scope="session")
def episode():
    """episode(controller, doors, knots=None, inner_loop="stiffness") -> (scenario, result, arc,
    metrics), memoized."""

    def get(controller: str, doors: str, knots: int | None = None, inner_loop: str = "stiffness"):
        return _run(controller, doors, knots, inner_loop)

    return get
