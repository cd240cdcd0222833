"""A grading's student view, with a process in it that forks the student process of each test.

Starting a student process is most of a unit test's cost (bubblewrap, an interpreter, numpy
and pydrake's modules: about 0.4 CPU-second, against a few milliseconds of the test's own
work). So a grading in the student's view (:mod:`doorlab.pset.isolation.bwrap_root`) starts one
:class:`StudentView` (two where two tests at a time would otherwise leave a core idle: see
:class:`doorlab.pset.grading.jobs._Jobs`), and every test's student process is forked from the first
process of a view (:mod:`doorlab.pset.isolation.zygote`), which imported those modules once, as the
sandbox user, and runs none of the student's code. The grader runs one test at a time in a
view, and each test still gets:

- a view as fresh as a new one: before the fork, every other process of the view is killed
  and reaped and its private ``/tmp`` and ``/dev/shm`` are emptied (by that first process,
  which the student's processes cannot signal, trace or read: it is the PID namespace's
  init and undumpable), so the test sees no process, file or note of the tests before it;
- a fresh process: forked, its own session, its own scratch copy of the submission
  (``/pset/<test>``), its own descriptors (its channel, its output), its own CPU limit (the
  other limits are the view's, set before its first instruction), the honesty guard
  installed before the student's code loads;
- when the test ends, :class:`ForkedStudent` kills the process, every process below it and
  every process of the view still holding one of the test's pipes (a child that kept its
  stdout), and waits until they are gone.

A view serves one grading (one submission): it ends with it, and every process in it. Two
views of one grading share only the sandbox user (its keyrings, cleared before each test).
"""

from __future__ import annotations

import json
import math
import os
import select
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

from doorlab.pset.isolation import bwrap_root, sandbox
from doorlab.pset.isolation.cgroups import CgroupError
from doorlab.pset.isolation.channel import Channel
from doorlab.pset.isolation.choice import Isolation
from doorlab.pset.isolation.handle import (
    SandboxError,
    StudentProcess,
    copy_submission,
    student_environment,
)
from doorlab.pset.isolation.memory import VIEW_OOM_SCORE_ADJ
from doorlab.pset.isolation.seccomp import FilterError, filter_descriptor
from doorlab.pset.rules.clock import remaining

VIEW_START_TIMEOUT_S = 60.0
"""How long a view's first process may take to start and import [s] (about 1 s idle)."""
KILL_TIMEOUT_S = 10.0
"""How long killing a test's processes may take before the grader gives up [s]."""
LOG_KEPT_BYTES = 2000
"""Bytes of a view's own output kept for the message when it cannot start."""


def _status_fields(pid: int) -> dict[str, str]:
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return {}
    return dict(line.split(":\t", 1) for line in text.splitlines() if ":\t" in line)


def _start_time(pid: int) -> int | None:
    """The process's start time (clock ticks since boot): with the pid, its identity."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_bytes()
    except OSError:
        return None
    fields = stat[stat.rfind(b")") + 2 :].split()
    return int(fields[19]) if len(fields) > 19 else None


def _pipe_inodes(pid: int) -> set[int]:
    out = set()
    try:
        fds = os.listdir(f"/proc/{pid}/fd")
    except OSError:
        return out
    for fd in fds:
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if target.startswith("pipe:["):
            out.add(int(target[6:-1]))
    return out


def kill_process(pid: int, start: int | None) -> None:
    """SIGKILLs ``pid`` and every process below it, if ``pid`` is still the process that
    started at ``start`` (not a later one that got its number)."""
    if start is None or _start_time(pid) != start:
        return
    for child, _, _ in sandbox.descendants(pid):
        try:
            os.kill(child, signal.SIGKILL)
        except OSError:
            pass
    try:
        os.kill(pid, signal.SIGKILL)
    except OSError:
        pass


class StudentView:
    """One view (bubblewrap) and its first process, which forks the tests' student processes,
    one at a time.

    Args:
        isolation: The grading's isolation (mode ``"bwrap"``).
        workdir: The grading's private folder (the view's scratch and log go in it).
        key: The view's name (its folder in ``workdir``).
        cpu_seconds: The first process's CPU limit [s] (each test lowers its own).
        group: The view's cgroup (:meth:`doorlab.pset.isolation.cgroups.GradingGroups.student`: its
            processes, memory and CPU counted together), or None.

    Raises:
        SandboxError: The view cannot be started (not the student's doing).
    """

    def __init__(
        self, isolation: Isolation, workdir: Path, key: str, cpu_seconds: float, group=None
    ):
        self.isolation = isolation
        self.key = key
        self.group = group
        self.root = workdir / f"view_{key}"
        self.root.mkdir(mode=0o711)
        os.chmod(self.root, 0o711)  # the student's user reaches its scratch, lists nothing
        identity = isolation.user()
        drop = None if identity is None else (identity.uid, identity.gid)
        # The tests' folders go in it, each the sandbox user's; the folder itself is the
        # grader's (0711 as root: the student's code can write none of its own there).
        self.scratch = self.root / "scratch"
        self.scratch.mkdir(mode=0o711 if drop is not None else 0o700)
        os.chmod(self.scratch, 0o711 if drop is not None else 0o700)
        plan = isolation.plan()
        tmp_dirs = bwrap_root.job_tmp_dirs(plan, self.root / "tmp", drop)
        self.control, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        self._log = open(self.root / "log", "w+b")  # noqa: SIM115 - closed in close()
        groups, seccomp = [], None
        try:
            seccomp = filter_descriptor()
            argv = bwrap_root.bwrap_argv(
                plan,
                self.scratch,
                tmp_dirs,
                as_root=identity is not None,
                as_pid_1=True,
                seccomp_fd=seccomp,
                scratch_tmpfs=True,
            )
            argv += [plan.python, "-I", "-S", "-B", "-c", bwrap_root.zygote_code(plan, drop)]
            argv += [str(theirs.fileno()), json.dumps(isolation.guard)]
            groups = group.join_descriptors() if group is not None else []
            self.proc = sandbox.spawn(
                argv,
                cwd=self.scratch,
                env=student_environment(bwrap_root.SCRATCH_MOUNT, "/tmp"),
                limits=sandbox.Limits(cpu_seconds=cpu_seconds, oom_score_adj=VIEW_OOM_SCORE_ADJ),
                identity=identity,
                switch_user=False,
                pass_fds=(theirs.fileno(), seccomp),
                output=self._log.fileno(),
                cgroup_fds=groups,
            )
        except (OSError, subprocess.SubprocessError, CgroupError, FilterError) as e:
            self.control.close()
            self._log.close()
            raise SandboxError(f"cannot start the student's view: {e}") from None
        finally:
            theirs.close()
            for fd in [*groups, *([] if seccomp is None else [seccomp])]:
                os.close(fd)
        self.pid = None
        if self._ready(time.monotonic() + VIEW_START_TIMEOUT_S):
            self.pid = self.host_pid(1, parent=self.proc.pid)
        if self.pid is None:
            why = self._log_tail()
            self.close()
            raise SandboxError(f"the student's view did not start: {why}")

    def _ready(self, deadline: float) -> bool:
        poller = select.poll()
        poller.register(self.control.fileno(), select.POLLIN)
        timeout = max(0.0, deadline - time.monotonic())
        if not poller.poll(int(timeout * 1e3)):
            return False
        try:
            message = json.loads(self.control.recv(4096).decode())
        except (OSError, UnicodeDecodeError, ValueError):
            return False
        return isinstance(message, dict) and "ready" in message

    def _log_tail(self) -> str:
        try:
            self._log.seek(0, os.SEEK_END)
            size = self._log.tell()
            self._log.seek(max(0, size - LOG_KEPT_BYTES))
            text = self._log.read().decode("utf-8", "replace").strip()
        except (OSError, ValueError):
            text = ""
        code = self.proc.poll()
        return text or ("exit code " + str(code) if code is not None else "no answer")

    def host_pid(self, ns_pid: int, *, parent: int | None = None) -> int | None:
        """The pid outside the view of the view's process ``ns_pid`` (below ``parent``,
        default the view's first process), or None."""
        root = self.pid if parent is None else parent
        if root is None:
            return None
        for pid, _, _ in sandbox.descendants(root):
            nspid = _status_fields(pid).get("NSpid", "").split()
            if nspid and nspid[-1] == str(ns_pid):
                return pid
        return None

    def processes(self) -> list[int]:
        """Every process of the view but its first (pids outside the view)."""
        return [] if self.pid is None else [p for p, _, _ in sandbox.descendants(self.pid)]

    def alive(self) -> bool:
        return self.proc.poll() is None

    def close(self) -> None:
        """Ends the view: its first process exits when the control socket closes, and the
        kernel kills every process of its PID namespace; bwrap is waited for."""
        self.control.close()
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._log.close()
        shutil.rmtree(self.root, ignore_errors=True)  # a view started again takes its name


class ForkedStudent(StudentProcess):
    """A test's student process forked in a :class:`StudentView`: as
    :class:`~doorlab.pset.isolation.handle.StudentProcess` for the checks and episodes.

    Args:
        student_view: The view. folder: The submission. name: The test's job name.
        time_limit: Wall and CPU time for the whole test [s].
        on_start: Called with (pid outside the view, its start time) once the process said
            hello (its parent, the trusted job's supervisor, can then kill it if the job dies).
    """

    def __init__(
        self,
        student_view: StudentView,
        folder: Path,
        name: str,
        time_limit: float,
        on_start=None,
    ):
        self.view = student_view
        self._on_start = on_start
        self.host = None
        self._code: int | None = None
        self._status: socket.socket | None = None
        self._inodes: set[int] = set()
        super().__init__(
            folder, student_view.root, name, time_limit, student_view.isolation, student_view.group
        )

    def _start(self, folder: Path, workdir: Path, stem: str) -> None:
        self.scratch = self.view.scratch / stem
        self._private.append(self.scratch)
        try:
            copy_submission(folder, self.scratch, self.isolation.user())
        except OSError as e:
            raise SandboxError(f"cannot copy the submission: {e}") from None
        request_r, self._request_w = os.pipe()
        self._answer_r, answer_w = os.pipe()
        output_r, output_w = os.pipe()
        os.set_blocking(self._request_w, False)
        self._status, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        theirs_fds = [request_r, answer_w, output_w, theirs.fileno()]
        self._inodes = {os.fstat(fd).st_ino for fd in theirs_fds[:3]}
        message = {"op": "fork", "scratch": stem, "cpu_seconds": math.ceil(self.limits.cpu_seconds)}
        try:
            socket.send_fds(self.view.control, [json.dumps(message).encode()], theirs_fds)
        except OSError as e:
            raise SandboxError(f"the student's view is gone ({e.strerror or e})") from None
        finally:
            for fd in theirs_fds[:3]:
                os.close(fd)
            theirs.close()
        self.channel = Channel(self._answer_r, self._request_w)
        self._output_stream = os.fdopen(output_r, "rb", buffering=0)
        first = self._next_status(self.deadline)
        if not isinstance(first, dict) or not isinstance(first.get("pid"), int):
            os.close(self._answer_r)
            os.close(self._request_w)
            self._output_stream.close()
            why = first.get("refused") if isinstance(first, dict) else None
            if isinstance(why, str):
                raise SandboxError(f"the student's view refused this test: {why}")
            raise SandboxError(f"the student's view did not fork a process ({first})")
        self._ns_pid = first["pid"]

    def _next_status(self, deadline) -> dict | None:
        """The next message on the test's status socket (None: none before ``deadline``,
        or the socket closed)."""
        poller = select.poll()
        poller.register(self._status.fileno(), select.POLLIN)
        timeout = max(0.0, remaining(deadline))
        if not poller.poll(int(math.ceil(timeout * 1e3))):
            return None
        try:
            data = self._status.recv(4096)
            message = json.loads(data.decode()) if data else None
        except (OSError, UnicodeDecodeError, ValueError):
            return None
        return message if isinstance(message, dict) else None

    def _started(self) -> None:
        # Before any request: the process with this number is the fresh fork.
        host = self.view.host_pid(self._ns_pid)
        if host is not None:
            self.host = (host, _start_time(host))
            group = self.view.group
            self.deadline.watch_student(host, group.cpu_seconds if group is not None else None)
            if self._on_start is not None:
                self._on_start(*self.host)

    def _stop(self) -> None:
        if self.host is not None:
            kill_process(*self.host)

    def _test_processes(self) -> list[int]:
        """The test's process, every process below it, every process of the view holding
        one of the test's pipes."""
        own = set()
        if self.host is not None and _start_time(self.host[0]) == self.host[1]:
            own = {self.host[0], *(p for p, _, _ in sandbox.descendants(self.host[0]))}
        return [p for p in self.view.processes() if p in own or _pipe_inodes(p) & self._inodes]

    def _end(self) -> None:
        deadline = time.monotonic() + KILL_TIMEOUT_S
        while time.monotonic() < deadline:
            found = self._test_processes()
            if not found:
                break
            for pid in found:
                try:
                    os.kill(pid, signal.SIGKILL)
                except OSError:
                    pass
            time.sleep(0.002)
        self._exit_code(timeout=max(0.0, min(2.0, deadline - time.monotonic())))
        if self._status is not None:
            self._status.close()

    def _exit_code(self, timeout: float) -> int | None:
        if self._code is not None or self._status is None or self._status.fileno() < 0:
            return self._code
        deadline = time.monotonic() + timeout
        while self._code is None:
            message = self._next_status(deadline)
            if message is None:
                return None
            if isinstance(message.get("signal"), int):
                self._code = -message["signal"]
            elif isinstance(message.get("exit"), int):
                self._code = message["exit"]
        return self._code

    def _running(self) -> bool:
        return self._exit_code(0.0) is None
