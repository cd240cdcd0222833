"""Issue 31: no submission of a class reaches a classmate's grade.

Each attack of the issue is rebuilt from the untouched stubs, in a class graded by
``grade-all --jobs 2`` beside honest submissions (the answer key), against the session's
reference episodes (``pset_fixtures.reference``): a submission that forks until EAGAIN, on and
off, beside 6 honest ones; a submission whose 50 busy children share a one-CPU group with an
honest one. Each attack lasts until the honest ones are graded (the test stops it then), so
they are graded under it on a fast host and a loaded one alike; they keep full
marks and the status ``graded``: each grading is a cgroup of its own
(:mod:`doorlab.pset.isolation.cgroups`), its views' processes bounded by their own
``pids.max``, its CPU share its own. Tests that make cgroups run as root on a machine whose
cgroups this user may write (they skip, saying why, elsewhere).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pset_fixtures
import pytest
from pset_attacks import _insert, evidence

from doorlab.pset.classroom.grade_all import GRADES_CSV, RESULTS_JSON, grade_class
from doorlab.pset.grading.grader import TESTS
from doorlab.pset.handout.folder import init_folder
from doorlab.pset.isolation import cgroups

FULL = sum(t.max_score for t in TESTS)
SETUP = cgroups.probe()
needs_cgroups = pytest.mark.skipif(
    SETUP.version is None or os.geteuid() != 0,
    reason=f"needs root and writable cgroups ({SETUP.reason or 'not root'})",
)

STOPPABLE = r"""
import ctypes, signal, time
if control_period != 0.005:  # the unit test's draws: not the episode, fail at once
    raise NotImplementedError("CalcTorqueCommand: the attack is in the episode only")
ctypes.CDLL(None).prctl(15, NAME.encode(), 0, 0, 0)  # PR_SET_NAME: the test finds it by name
stop = []
signal.signal(signal.SIGUSR1, lambda *_: stop.append(time.time()))
end = time.monotonic() + SECONDS
"""
"""The start of an attack in the impedance plan's CalcTorqueCommand (the first call of the
first test a grading runs, its impedance episode): it names its process NAME and lasts until
the test sends it SIGUSR1 (:func:`stopped_when`: once the honest gradings are done) or for
SECONDS, its bound. The unit test's calls (control_period other than the episode's 0.005 s)
fail at once: a second dose there would only lengthen the attacker's grading."""

FORK_CYCLER = (
    STOPPABLE
    + r"""
import errno, json, os
ev = {"eagain": 0, "most": 0, "rounds": 0, "start": time.time()}
while time.monotonic() < end and not (stop and ev["rounds"] >= ROUNDS):
    children = []  # on: fork until the kernel refuses, hold; off: let them go
    while True:
        try:
            pid = os.fork()
        except OSError as e:
            if e.errno == errno.EAGAIN:
                ev["eagain"] += 1
            break
        if pid == 0:
            time.sleep(1.0)
            os._exit(0)
        children.append(pid)
    ev["most"] = max(ev["most"], len(children))
    ev["rounds"] += 1
    for pid in children:
        os.waitpid(pid, 0)
    time.sleep(0.3)
ev["end"] = time.time()
ev["stopped"] = stop[0] if stop else None
print("EVIDENCE forks " + json.dumps(ev))
raise NotImplementedError("CalcTorqueCommand: forked until EAGAIN")
"""
)
"""Forks until the kernel refuses (EAGAIN), on and off, until stopped (at least ROUNDS
rounds of about 1.7 s, measured)."""

BUSY_CHILDREN = (
    STOPPABLE
    + r"""
import json, os
start = time.time()
children = []
for _ in range(CHILDREN):
    pid = os.fork()
    if pid == 0:
        while time.monotonic() < end:
            pass
        os._exit(0)
    children.append(pid)
while not stop and time.monotonic() < end:
    time.sleep(0.05)
for pid in children:
    os.kill(pid, signal.SIGKILL)
for pid in children:
    os.waitpid(pid, 0)
ev = {"children": len(children), "start": start, "end": time.time()}
ev["stopped"] = stop[0] if stop else None
print("EVIDENCE busy " + json.dumps(ev))
raise NotImplementedError("CalcTorqueCommand: busy children")
"""
)
"""CHILDREN processes that spin until the attack is stopped, then it fails (the evidence: when
they started and stopped, on the machine's clock)."""

ATTACK_BOUND_S = 120.0
"""The longest an attack lasts [s] if the test never stops it: below its episode's time limit
(150 s), so that it ends by itself and its evidence reaches the results, and far beyond an
honest grading (9 s on an idle 2-core machine, 66 s measured beside a CPU burner on both
cores)."""


def _named(name: str) -> list[int]:
    """The processes whose name is ``name`` and whose parent's is not (an attack's first)."""

    def comm(pid: str) -> str | None:
        try:
            return Path(f"/proc/{pid}/comm").read_text().strip()
        except OSError:
            return None

    found = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        if comm(pid) != name:
            continue
        try:
            stat = Path(f"/proc/{pid}/stat").read_text()
        except OSError:
            continue
        parent = stat[stat.rfind(")") + 2 :].split()[1]
        if comm(parent) != name:
            found.append(int(pid))
    return found


@contextlib.contextmanager
def stopped_when(done: Callable[[], bool], name: str):
    """While the block runs: once ``done()``, SIGUSR1 to the attack named ``name``, every
    second until the block ends. So the attack lasts as long as what the test measures beside
    it, however fast the host is."""
    finished = threading.Event()

    def watch() -> None:
        while not finished.wait(0.2):
            if done():
                for pid in _named(name):
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(pid, signal.SIGUSR1)
                finished.wait(1.0)

    thread = threading.Thread(target=watch, name="stop-the-attack", daemon=True)
    thread.start()
    try:
        yield
    finally:
        finished.set()
        thread.join()


@pytest.fixture(scope="module")
def reference() -> dict:
    return pset_fixtures.reference()


def _class(root: Path, honest: int, attacker: tuple[str, dict], where: str = "calc_p_Q") -> Path:
    """``honest`` copies of the answer key and one attacker (stubs, ``where`` replaced)."""
    export = root / "export"
    export.mkdir(parents=True)
    key = init_folder(root / "key", solutions=True)
    for i in range(honest):
        shutil.copytree(key, export / f"honest_{i}")
    folder = init_folder(export / "attacker")
    code, values = attacker
    _insert(folder, where, code, values)
    subprocess.run(["chmod", "-R", "a+rX", str(root)], check=True)
    return export


def _rows(out: Path) -> dict[str, dict]:
    import csv

    with open(out / GRADES_CSV, newline="") as f:
        return {row["submission"]: row for row in csv.DictReader(f)}


@needs_cgroups
@pytest.mark.slow
def test_six_honest_submissions_beside_a_fork_cycler_keep_full_marks(tmp_path, reference):
    """The fork cycler hits its own view's limit (EAGAIN) again and again while 6 honest
    submissions are graded on the other worker: every one of them 14 and graded. It cycles
    until they are (the test stops it then: :func:`stopped_when`), so it lasts through their
    whole grading whatever the host's speed."""
    values = {"NAME": "doorlab-forker", "SECONDS": ATTACK_BOUND_S, "ROUNDS": 5}
    export = _class(tmp_path, 6, (FORK_CYCLER, values), where="impedance")
    out = tmp_path / "out"
    honest = [out / f"honest_{i}" / RESULTS_JSON for i in range(6)]
    with stopped_when(lambda: all(p.is_file() for p in honest), values["NAME"]):
        outcome = grade_class(export, out, reference=reference, jobs=2)
    rows = _rows(out)
    for i in range(6):
        row = rows[f"honest_{i}"]
        assert (row["status"], float(row["total"])) == ("graded", FULL), row
    assert rows["attacker"]["status"] == "graded", rows["attacker"]
    results = json.loads((out / "attacker" / RESULTS_JSON).read_text())
    forks = evidence(results)["forks"]
    assert forks["eagain"] >= 5 and forks["rounds"] >= 5, forks  # one EAGAIN a round
    # Its own view's limit, not the machine's: at most pids.max less the view's own tasks.
    assert 50 <= forks["most"] <= cgroups.VIEW_TASKS, forks
    assert results["extra_data"]["sandbox"]["cgroup"]["version"] == SETUP.version
    assert outcome.errors == 0
    # It cycled until the honest ones were graded (identical files: one grading, copied),
    # or for its whole bound if that came first.
    honest_done = max(p.stat().st_mtime for p in honest)
    assert forks["stopped"] is None or forks["stopped"] >= honest_done, (honest_done, forks)
    print(f"the fork cycler: {forks}; the honest ones done {honest_done - forks['start']:.1f} s in")


DASK_PATCH = r"""
import json, os, re, socket
ev = {"addresses": [], "connect": {}}
for pid in [p for p in os.listdir("/proc") if p.isdigit()]:  # the scheduler's address
    try:
        text = open(f"/proc/{pid}/cmdline", "rb").read().decode(errors="replace")
    except OSError:
        continue
    ev["addresses"] += re.findall(r"(?:tcp|tls)://[\w.:\[\]-]+", text)
for address in [*ev["addresses"], ADDRESS]:  # and the real one, as if it leaked anyway
    host, port = address.split("://", 1)[1].rsplit(":", 1)
    try:
        socket.create_connection((host, int(port)), timeout=5).close()
        ev["connect"][address] = "connected"
    except OSError as e:
        ev["connect"][address] = type(e).__name__
print("EVIDENCE dask " + json.dumps(ev))
raise NotImplementedError("calc_p_Q: no scheduler reached")
"""
"""calc_p_Q: finds the Dask scheduler's address and connects to it (to Client.run a patch)."""


@pytest.mark.slow
def test_the_student_s_code_cannot_reach_a_tls_cluster_and_nothing_connects_without_its_key(
    tmp_path, reference
):
    """A class graded on a Dask cluster doorlab starts (TLS, a key made for it): the
    attacker's code finds no scheduler address in /proc and cannot connect to the real one
    from its view (its own network namespace: loopback only); outside the view, a client
    without the cluster's key cannot connect, one with it can."""
    distributed = pytest.importorskip("distributed")
    from distributed.comm import connect

    from doorlab.pset.classroom.cluster import local_cluster

    with local_cluster(1) as cluster:
        address = cluster.address
        export = _class(tmp_path, 0, (DASK_PATCH, {"ADDRESS": address}))
        out = tmp_path / "out"
        grade_class(export, out, reference=reference, scheduler=address, security=cluster.security)
        # Outside the view, without the key: no plain client, no TLS client of another key
        # (connections, not Clients: a Client that failed to start may hang in its __del__).
        with pytest.raises(TypeError, match="TLS expects"):
            asyncio.run(connect(address, timeout=5))
        other = distributed.Security.temporary().get_connection_args("client")
        with pytest.raises((OSError, TimeoutError)):
            asyncio.run(connect(address, timeout=5, **other))
        with distributed.Client(address, security=cluster.security, timeout=10) as client:
            assert client.scheduler_info()["type"] == "Scheduler"
    rows = _rows(out)
    assert rows["attacker"]["status"] == "graded", rows
    results = json.loads((out / "attacker" / RESULTS_JSON).read_text())
    found = evidence(results)["dask"]
    assert found["addresses"] == [], found
    assert found["connect"] == {address: "ConnectionRefusedError"}, found
    assert results["extra_data"]["sandbox"]["network_isolated"] is True


def test_the_cluster_doorlab_starts_leaves_dask_s_default_port_to_the_course(recwarn):
    """local_cluster's scheduler serves its HTTP routes (health, metrics) on a free loopback
    port, not on Dask's default 8787, where a course's own dashboard usually is: with
    127.0.0.1:8787 held (here, or by whoever holds it already), it starts without Dask's
    "Port 8787 is already in use" warning. (It warned before; two gradings on clusters of
    their own side by side did too.)"""
    pytest.importorskip("distributed")
    from doorlab.pset.classroom.cluster import local_cluster

    with socket.socket() as held:
        with contextlib.suppress(OSError):  # taken already: held by someone else, as wanted
            held.bind(("127.0.0.1", 8787))
            held.listen()
        with local_cluster(1) as cluster:
            assert cluster.address.startswith("tls://127.0.0.1:")
    messages = [str(w.message) for w in recwarn]
    assert not [m for m in messages if "8787" in m], messages


def test_a_cluster_whose_workers_would_not_isolate_the_network_is_refused():
    """--scheduler where a worker's gradings would run the student's code without a network
    namespace (no view, not root): refused in one line before anything is graded."""
    from concurrent.futures import Future

    from doorlab.errors import ConfigError
    from doorlab.pset.classroom.cluster import check_workers

    class Worker:
        def __init__(self, facts):
            self.facts = facts

        def submit(self, fn, *args):
            future = Future()
            future.set_result(self.facts)
            return future

    bare = {"mode": "none", "network_isolated": False, "reason": "bwrap is not installed"}
    with pytest.raises(ConfigError, match="without a network namespace") as refused:
        check_workers(Worker(bare), "insecure")
    assert "\n" not in str(refused.value) and "bwrap is not installed" in str(refused.value)
    view = {"mode": "bwrap", "network_isolated": True, "reason": ""}
    assert check_workers(Worker(view), "require") == view


def _one_cpu(name: str) -> cgroups.Group:
    """A cgroup of one CPU (a quota: as in a Gradescope container), below this process's."""
    base = cgroups.Group(SETUP, {k: Path(v) for k, v in SETUP.bases.items()})
    group = base.child(name, holds_groups=True)
    if SETUP.version == 2:
        (group.folders["unified"] / "cpu.max").write_text("100000 100000")
    else:
        (group.folders["cpu"] / "cpu.cfs_period_us").write_text("100000")
        (group.folders["cpu"] / "cpu.cfs_quota_us").write_text("100000")
    return group


@needs_cgroups
@pytest.mark.slow
def test_an_honest_submission_beside_50_busy_children_in_one_cpu_keeps_full_marks(
    tmp_path, reference
):
    """``grade-all --jobs 2`` in a group of one CPU: the attacker's first test starts 50
    processes that spin until the honest submission is graded (the test stops them then:
    :func:`stopped_when`); graded meanwhile, it gets its grading's share of the CPU (each
    grading is a cgroup with the same weight): it is 14 and graded. (Before each grading had
    its cgroup, it had 2 of 52 shares while they spun, about 0.04 CPU here: with the children
    spinning for 140 s in half a CPU its first episode, 150 s, did not answer in time: 12/14.)"""
    values = {"NAME": "doorlab-busy", "SECONDS": ATTACK_BOUND_S, "CHILDREN": 50}
    busy = (BUSY_CHILDREN, values)
    export = _class(tmp_path, 1, busy, where="impedance")
    out = tmp_path / "out"
    reference_file = tmp_path / "reference.json"
    reference_file.write_text(json.dumps({"extra_data": {"reference": reference}}))
    group = _one_cpu(f"doorlab-test-{os.getpid()}")
    fds = group.join_descriptors()
    argv = ["pset", "grade-all", str(export), "--out", str(out), "--jobs", "2"]
    try:
        with stopped_when((out / "honest_0" / RESULTS_JSON).is_file, values["NAME"]):
            proc = subprocess.run(
                [sys.executable, "-m", "doorlab.cli", *argv, "--reference", str(reference_file)],
                capture_output=True,
                text=True,
                timeout=900,
                pass_fds=fds,
                preexec_fn=lambda: cgroups.join_by_descriptors(fds),
            )
        used = group.cpu_seconds()
    finally:
        for fd in fds:
            os.close(fd)
        group.remove()
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = _rows(out)
    assert (rows["honest_0"]["status"], float(rows["honest_0"]["total"])) == ("graded", FULL)
    assert rows["attacker"]["status"] == "graded", rows["attacker"]
    results = json.loads((out / "attacker" / RESULTS_JSON).read_text())
    impedance = next(t for t in results["tests"] if t["name"].startswith("Task 3 episode"))
    # Its own failure: it ends by itself (its 50 children took its view's share of the CPU
    # from its own main process, which they starve, yet it sleeps, then raises).
    assert impedance["score"] == 0 and "busy children" in impedance["output"], impedance["output"]
    busy = evidence(results)["busy"]
    assert busy["children"] == 50
    # The children spun until the honest grading was done (its results written, the
    # grading's last step), or for their whole bound if that came first.
    honest_done = (out / "honest_0" / RESULTS_JSON).stat().st_mtime
    assert busy["stopped"] is None or busy["stopped"] >= honest_done, (honest_done, busy)
    print(
        f"the class used {used:.1f} CPU-s in the one-CPU group; the honest grading ended "
        f"{honest_done - busy['start']:.1f} s after the children started, "
        f"{busy['end'] - honest_done:.1f} s before they stopped"
    )


CLOCK = r"""
import json, sys, time
from doorlab.pset.rules.clock import Clock
clock = Clock(LIMIT)
if MODE == "busy":  # the trusted side computing, starved by the quota
    while clock.remaining() > 0:
        pass
else:  # the trusted side waiting for a student that sleeps
    while clock.remaining() > 0:
        time.sleep(0.01)
print(json.dumps({"wall": clock.wall(), "waited": clock.waited(), "starved": clock.starved()}))
"""


@pytest.mark.slow
@needs_cgroups
@pytest.mark.parametrize("mode", ["busy", "sleep"])
def test_a_test_s_time_is_what_it_had_and_starvation_is_the_grader_s_error(tmp_path, mode):
    """Issue 31: a test's clock counts wall time less the time its process waited for a
    CPU: in a group of 2% of a CPU, a 1-s budget lasts several seconds of wall time, and when
    it is spent with the student's processes starved, that is the grader's error (a message
    saying so), not a verdict; a test whose student sleeps (no quota) spends its budget in
    wall time, and that is the student's."""
    group = cgroups.Group(SETUP, {k: Path(v) for k, v in SETUP.bases.items()}).child(
        f"doorlab-test-clock-{os.getpid()}-{mode}"
    )
    if mode == "busy":  # the quota would throttle the sleeper's wake-ups too: not for it
        if SETUP.version == 2:
            (group.folders["unified"] / "cpu.max").write_text("2000 100000")
        else:
            (group.folders["cpu"] / "cpu.cfs_period_us").write_text("100000")
            (group.folders["cpu"] / "cpu.cfs_quota_us").write_text("2000")
    fds = group.join_descriptors()
    code = f"LIMIT = 1.0\nMODE = {mode!r}\n" + CLOCK
    try:
        proc = subprocess.run(
            [sys.executable, "-c", code],
            capture_output=True,
            text=True,
            timeout=120,
            pass_fds=fds,
            preexec_fn=lambda: cgroups.join_by_descriptors(fds),
        )
    finally:
        for fd in fds:
            os.close(fd)
        group.remove()
    assert proc.returncode == 0, proc.stderr[-2000:]
    facts = json.loads(proc.stdout)
    if mode == "busy":
        # 2% of a CPU: the budget's second of CPU-run time took far more wall time.
        assert facts["wall"] > 3.0 and facts["waited"] > 2.0, facts
        assert facts["starved"] is not None and "too loaded" in facts["starved"], facts
    else:
        assert 0.95 <= facts["wall"] < 2.0 and facts["waited"] < 0.5 * facts["wall"], facts
        assert facts["starved"] is None, facts


SLEEPER = r"""
import time
time.sleep(60)
raise NotImplementedError("calc_p_Q: slept")
"""


@pytest.mark.slow
def test_a_supervisor_ended_by_sigterm_leaves_no_folder_behind(tmp_path, monkeypatch):
    """A batch worker's supervisor ends with its worker (SIGTERM, as a Dask worker's end or
    Ctrl-C of grade-all brings): the grading is the grader's error, and nothing of it is left
    in its TMPDIR: not its own folder, not the grading's, not the submission's copy (the
    student's files)."""
    from doorlab.pset.grading.grader import Supervisor, take_files

    folder = init_folder(tmp_path / "sleeper")
    _insert(folder, "calc_p_Q", SLEEPER, {})
    files, intake = take_files(folder)
    tmp = tmp_path / "tmp"
    tmp.mkdir(mode=0o755)
    monkeypatch.setenv("TMPDIR", str(tmp))
    supervisor = Supervisor()
    thread, outcome = pset_fixtures.grade_in_thread(files, intake, supervisor)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not any(
        p.name.startswith("doorlab_submission_") for p in tmp.iterdir()
    ):
        time.sleep(0.05)
    time.sleep(2)  # the grading under way: its student process sleeping
    made = sorted(p.name.split("_")[1] for p in tmp.iterdir())
    os.kill(supervisor._proc.pid, signal.SIGTERM)
    thread.join(60)
    supervisor.close()
    assert {"supervisor", "submission", "grade"} <= set(made), made
    assert "error" in outcome, outcome
    left = sorted(p.name for p in tmp.iterdir())
    assert left == [], left


@pytest.mark.slow
@needs_cgroups
def test_a_trusted_process_killed_as_by_the_oom_killer_is_the_grader_s_error(tmp_path):
    """A trusted job process killed by SIGKILL from outside (what the kernel's OOM killer
    does) while its student sleeps: the grading is the grader's error, naming the signal,
    never a failed test the student did not fail."""
    from doorlab.pset.grading.grader import GradingError, Supervisor, grade

    folder = init_folder(tmp_path / "sleeper")
    _insert(folder, "calc_p_Q", SLEEPER, {})
    subprocess.run(["chmod", "-R", "a+rX", str(tmp_path)], check=True)
    only = [t.name for t in TESTS if t.key == "calc_p_Q_unit"]
    supervisor = Supervisor()
    outcome = {}

    def run() -> None:
        try:
            outcome["results"] = grade(folder, only=only, supervisor=supervisor)
        except GradingError as e:
            outcome["error"] = str(e)

    import threading

    thread = threading.Thread(target=run)
    thread.start()
    try:
        deadline, killed = time.monotonic() + 120, []
        while time.monotonic() < deadline and not killed:
            time.sleep(0.2)
            pid = supervisor._proc.pid if supervisor._proc is not None else 0
            base = Path(SETUP.bases["unified" if SETUP.version == 2 else "pids"])
            for procs in base.glob(f"{cgroups.PREFIX}{pid}-*/trusted/cgroup.procs"):
                for job in procs.read_text().split():
                    os.kill(int(job), signal.SIGKILL)
                    killed.append(int(job))
        thread.join(120)
    finally:
        supervisor.close()
    assert killed, "no trusted job process was found"
    assert "error" in outcome, outcome.get("results", {}).get("score")
    assert "ended without a result (killed by signal 9" in outcome["error"], outcome["error"]


@needs_cgroups
def test_a_fork_the_view_cannot_make_refuses_that_test_and_the_view_serves_on(tmp_path):
    """The view's first process cannot fork a test's process (its group's pids.max leaves no
    room): that test is refused with a message (the grader's error), and the view is still
    there for the next test once there is room."""
    from doorlab.pset.isolation.choice import prepare
    from doorlab.pset.isolation.handle import SandboxError
    from doorlab.pset.isolation.student_view import ForkedStudent, StudentView

    work = tmp_path / "work"
    work.mkdir(mode=0o711)
    os.chmod(tmp_path, 0o755)
    folder = init_folder(tmp_path / "stubs")
    subprocess.run(["chmod", "-R", "a+rX", str(tmp_path)], check=True)
    isolation = prepare(work)
    groups = cgroups.GradingGroups(SETUP)
    try:
        group = groups.student("view0")
        view = StudentView(isolation, work, "view0", 60.0, group)
        try:
            group.set_tasks(len(group.pids()))  # bwrap and the first process: no more
            with pytest.raises(SandboxError, match="refused this test: it could not fork"):
                ForkedStudent(view, folder, "unit:calc_p_Q", 30.0)
            assert view.alive()
            group.set_tasks(cgroups.VIEW_TASKS)
            with ForkedStudent(view, folder, "unit:calc_R_WL7_ref", 30.0) as student:
                assert student.facts.get("pid_namespace") is True
        finally:
            view.close()
    finally:
        groups.close()
