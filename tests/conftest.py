"""Shared fixtures: full episodes are expensive (~3-5 s each), so each is run once per session.

The suite runs on pytest-xdist's workers (``addopts`` in pyproject.toml: one per core), a test
file per worker at a time. A test's real-time section (``with alone():``: LCM processes paced
to the wall clock, with tolerances derived from their latency) runs alone: the other workers
finish the test they are in and wait (a lock shared by the run's workers, below), so a
real-time run never shares the cores with a simulation running as fast as it can.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shutil
import tempfile
import time
from functools import cache
from pathlib import Path

import file_order
import pytest
from shared_cache import RUN_DIR_ENV, run_dir

os.environ.setdefault("MPLBACKEND", "Agg")


def pytest_configure(config: pytest.Config) -> None:
    # The run's shared folder (tests/shared_cache.py, the locks below), made by the main
    # process before pytest-xdist starts its workers, which inherit the variable.
    if not hasattr(config, "workerinput") and RUN_DIR_ENV not in os.environ:
        config._doorlab_run_dir = tempfile.mkdtemp(prefix="doorlab-pytest-")
        os.environ[RUN_DIR_ENV] = config._doorlab_run_dir


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--record-durations",
        action="store_true",
        help="write each file's measured time to tests/durations.json (tests/file_order.py: "
        "the order the files are handed to the workers)",
    )


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The files in tests/file_order.py's order (the same on every worker: computed from the
    collection and durations.json only); the tests of a file keep theirs."""
    realtime = {item.path.name for item in items if "alone" in getattr(item, "fixturenames", ())}
    durations = file_order.read_durations()
    rank = {
        name: i
        for i, name in enumerate(
            file_order.file_order({i.path.name for i in items}, realtime, durations)
        )
    }
    items.sort(key=lambda item: rank[item.path.name])


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    times = _RECORDED.get("times")
    if times is not None:
        name = report.nodeid.split("::")[0].rsplit("/", 1)[-1]
        times[name] = times.get(name, 0.0) + report.duration


_RECORDED: dict[str, dict[str, float]] = {}
"""With --record-durations, in the main process: the times measured so far by file [s]."""


def pytest_sessionstart(session: pytest.Session) -> None:
    if session.config.getoption("record_durations") and not hasattr(session.config, "workerinput"):
        _RECORDED["times"] = {}


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    times = _RECORDED.pop("times", None)
    if times:  # the files this run measured replace theirs; the others are kept
        file_order.write_durations({**file_order.read_durations(), **times})


def pytest_unconfigure(config: pytest.Config) -> None:
    folder = getattr(config, "_doorlab_run_dir", None)
    if folder is not None:
        shutil.rmtree(folder, ignore_errors=True)
        os.environ.pop(RUN_DIR_ENV, None)


class _RunLock:
    """Under xdist, a lock shared by the run's workers: every test holds it shared; a test's
    real-time section (the ``alone`` fixture) holds it alone.

    The turnstile, taken before the main lock and dropped once that is held, makes a section
    that waits for the main lock also stop new tests from taking it shared, so it gets it as
    soon as the tests in progress end. A worker waits for the main lock only while holding
    the turnstile and for the turnstile only while holding nothing: no deadlock.
    """

    def __init__(self, folder: Path):
        self._lock = open(folder / "tests.lock", "a")  # held for the session
        self._turnstile = open(folder / "turnstile.lock", "a")

    def _take(self, mode: int) -> None:
        fcntl.flock(self._turnstile, fcntl.LOCK_EX)
        fcntl.flock(self._lock, mode)
        fcntl.flock(self._turnstile, fcntl.LOCK_UN)

    def shared(self) -> None:
        self._take(fcntl.LOCK_SH)

    def alone(self) -> None:
        self.release()
        self._take(fcntl.LOCK_EX)

    def release(self) -> None:
        fcntl.flock(self._lock, fcntl.LOCK_UN)


def _run_lock(config: pytest.Config) -> _RunLock | None:
    """This worker's lock (None when not under xdist: then nothing else runs)."""
    folder = run_dir()
    if not hasattr(config, "workerinput") or folder is None:
        return None
    if not hasattr(config, "_doorlab_run_lock"):
        config._doorlab_run_lock = _RunLock(folder)
    return config._doorlab_run_lock


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None):
    """Setup, call and teardown of each test (module fixtures included) hold the lock shared."""
    lock = _run_lock(item.config)
    if lock is not None:
        lock.shared()
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


@pytest.fixture
def alone(request):
    """``with alone(): ...``: a real-time section (LCM processes paced to the wall clock,
    tolerances derived from their latency) that runs while no other worker runs a test."""
    lock = _run_lock(request.config)

    @contextlib.contextmanager
    def section():
        if lock is None:
            yield
            return
        asked = time.monotonic()
        lock.alone()
        began = time.monotonic()
        try:
            yield
        finally:
            lock.release()
            lock.shared()
            _record_section(request.node.nodeid, began - asked, time.monotonic() - began)

    return section


SECTIONS_FILE = "alone_sections.jsonl"
"""In the run's folder: each real-time section's wait for the lock and its length [s]."""


def _record_section(test: str, waited: float, ran: float) -> None:
    with open(run_dir() / SECTIONS_FILE, "a") as f:
        f.write(json.dumps({"test": test, "waited": waited, "alone": ran}) + "\n")


def pytest_terminal_summary(terminalreporter, exitstatus, config) -> None:
    """What the real-time sections cost the run: while one waits for the lock (the other
    workers finishing the test they are in) and while it runs, its worker and then the
    others are idle (docs/development.md, "Which tests to run when")."""
    folder = run_dir()
    path = None if folder is None else folder / SECTIONS_FILE
    if hasattr(config, "workerinput") or path is None or not path.is_file():
        return
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    waited = sum(r["waited"] for r in rows)
    longest = max(rows, key=lambda r: r["waited"])
    terminalreporter.write_line(
        f"real-time sections: {len(rows)}, {sum(r['alone'] for r in rows):.0f} s alone, "
        f"{waited:.0f} s waiting for the other workers' tests (longest {longest['waited']:.0f} s, "
        f"{longest['test']})"
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
