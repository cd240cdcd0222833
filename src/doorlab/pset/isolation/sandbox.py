"""The untrusted process: where a submission's code runs, and how it is contained (Linux).

:func:`spawn` starts a process under these limits, all applied between ``fork`` and ``exec``
(so before the first instruction of the new process; the caller must not have started
threads of its own yet, see :func:`spawn`):

- **resources** (``setrlimit``): address space (:data:`MEMORY_LIMIT_BYTES`), CPU time (the
  test's time limit), size of any file written (:data:`FILE_SIZE_LIMIT_BYTES`), processes and
  threads (:data:`PROCESS_LIMIT` beyond what its user already runs), open files, no core dumps;
- **its own session** (``setsid``), and ``PR_SET_NO_NEW_PRIVS`` (no set-user-ID program
  can give it privileges back); it gets ``SIGKILL`` if the process that started it dies;
- **another user** (``switch_user``): student code runs as :func:`sandbox_identity`
  (``$DOORLAB_SANDBOX_USER``, else a user named ``doorlab-student`` if the machine has one,
  else ``nobody``) when the grader is root; inside the student's view
  (:mod:`doorlab.pset.isolation.bwrap_root`) the worker switches to it itself, since bwrap must
  start as root.

The view (bubblewrap: a minimal read-only root, its own PID, network, IPC and UTS
namespaces) is built by :mod:`doorlab.pset.isolation.bwrap_root`; the command :func:`spawn` runs is
bwrap then.

**Every descendant dies with its test.** A child can leave the process group and the
session (``setsid``) or be orphaned by a double fork, so killing the group is not enough.
The grader's processes are *child subreapers* (``PR_SET_CHILD_SUBREAPER``): an orphan of
any depth is re-parented to the nearest of them instead of to init, so every process the
submission started stays a descendant of the grader, whatever its session or group.
:func:`kill_descendants` walks ``/proc`` for them, ``SIGKILL`` s them all, reaps the ones
that became its children, and repeats until none is left (a process forking meanwhile
only adds descendants for the next pass). Inside the view the same holds twice over: the
student's processes live in a PID namespace whose init (bwrap's) dies with its parent, which
takes every process of the namespace with it.

Output: :class:`OutputCollector` drains the process's stdout and stderr (one pipe) in a
thread, keeps the first and last :data:`OUTPUT_KEPT_BYTES`, counts the rest and stops the
process past :data:`OUTPUT_LIMIT_BYTES`, so no amount of printing grows the grader.
"""

from __future__ import annotations

import ctypes
import math
import os
import pwd
import resource
import select
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from doorlab.pset.isolation.memory import set_oom_score_adj

MEMORY_LIMIT_BYTES = 2 << 30
"""Address space of the student's process [bytes] (2 GiB; Python with pydrake and the arm
model maps about 0.5 GiB)."""
FILE_SIZE_LIMIT_BYTES = 32 << 20
"""Largest file the student's process may write [bytes] (32 MiB)."""
PROCESS_LIMIT = 64
"""Processes and threads the student's user may start beyond those it already runs."""
OPEN_FILES_LIMIT = 256
"""File descriptors of the student's process."""
OUTPUT_LIMIT_BYTES = 8 << 20
"""Output (stdout and stderr together) after which the test is stopped [bytes] (8 MiB)."""
OUTPUT_KEPT_BYTES = 1500
"""Bytes kept from the start and from the end of a test's output."""

SANDBOX_USER_ENV = "DOORLAB_SANDBOX_USER"
"""Environment variable naming the user (or uid) student code runs as when the grader is root."""
DEDICATED_USER = "doorlab-student"
"""The user preferred when it exists (create it with ``useradd --system --no-create-home
--shell /usr/sbin/nologin doorlab-student``); otherwise ``nobody``."""

PR_SET_PDEATHSIG = 1
PR_SET_DUMPABLE = 4
PR_SET_CHILD_SUBREAPER = 36
PR_SET_NO_NEW_PRIVS = 38
CLONE_NEWIPC = 0x08000000
CLONE_NEWNET = 0x40000000
CLONE_NEWUSER = 0x10000000
"""``unshare`` flags (linux/sched.h; Python has ``os.unshare`` from 3.12 only)."""

_libc = ctypes.CDLL(None, use_errno=True)


def _check(result: int, what: str) -> None:
    if result != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"{what}: {os.strerror(err)}")


def prctl(option: int, value: int) -> None:
    """``prctl(option, value)``; raises OSError on failure."""
    _check(_libc.prctl(option, ctypes.c_ulong(value), 0, 0, 0), f"prctl({option})")


def unshare(flags: int) -> None:
    """``unshare(flags)``: new namespaces for this process; raises OSError."""
    _check(_libc.unshare(ctypes.c_int(flags)), f"unshare({flags:#x})")


def become_subreaper() -> None:
    """Makes this process the child subreaper of its descendants (orphans come back here)."""
    prctl(PR_SET_CHILD_SUBREAPER, 1)


def die_with_parent(parent_pid: int, signum: int = signal.SIGKILL) -> None:
    """Sends ``signum`` to this process when its parent dies (SIGKILL now if it already has)."""
    prctl(PR_SET_PDEATHSIG, signum)
    if os.getppid() != parent_pid:
        os.kill(os.getpid(), signal.SIGKILL)


def make_undumpable() -> None:
    """No ptrace and no /proc/PID/{mem,fd,environ} of this process for its own user."""
    prctl(PR_SET_DUMPABLE, 0)


@dataclass(frozen=True)
class Identity:
    """Who student code runs as."""

    name: str
    uid: int
    gid: int


def sandbox_identity() -> Identity | None:
    """The user student code runs as when the grader is root; None when it is not (then
    student code runs as the grader's own user: only the other limits hold).

    Raises:
        OSError: ``$DOORLAB_SANDBOX_USER`` names no user, or names root.
    """
    if os.geteuid() != 0:
        return None
    wanted = os.environ.get(SANDBOX_USER_ENV, "").strip()
    try:
        if wanted:
            entry = pwd.getpwuid(int(wanted)) if wanted.isdigit() else pwd.getpwnam(wanted)
        else:
            try:
                entry = pwd.getpwnam(DEDICATED_USER)
            except KeyError:
                entry = pwd.getpwnam("nobody")
    except KeyError:
        raise OSError(f"{SANDBOX_USER_ENV}={wanted or 'nobody'}: no such user") from None
    if entry.pw_uid == 0:
        raise OSError(f"{SANDBOX_USER_ENV}: student code must not run as root")
    return Identity(entry.pw_name, entry.pw_uid, entry.pw_gid)


@dataclass(frozen=True)
class Limits:
    """Resource limits of one student process."""

    cpu_seconds: float
    memory_bytes: int = MEMORY_LIMIT_BYTES
    file_size_bytes: int = FILE_SIZE_LIMIT_BYTES
    processes: int = PROCESS_LIMIT
    open_files: int = OPEN_FILES_LIMIT
    output_bytes: int = OUTPUT_LIMIT_BYTES
    oom_score_adj: int | None = None  # its rank for the OOM killer (doorlab.pset.isolation.memory)


def count_tasks(uid: int) -> int:
    """Threads of every process whose real uid is ``uid`` (what RLIMIT_NPROC counts)."""
    total = 0
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            status = Path(entry.path, "status").read_text()
        except OSError:
            continue
        fields = dict(line.split(":", 1) for line in status.splitlines() if ":" in line)
        try:
            if int(fields["Uid"].split()[0]) == uid:
                total += int(fields["Threads"])
        except (KeyError, ValueError, IndexError):
            continue
    return total


def _preexec(
    limits: Limits,
    identity: Identity | None,
    switch_user: bool,
    nproc: int,
    parent_pid: int,
    cgroup_fds: Sequence[int] = (),
    new_namespaces: int = 0,
) -> Callable[[], None]:
    cpu = max(1, math.ceil(limits.cpu_seconds))
    settings = [
        (resource.RLIMIT_CPU, (cpu, cpu + 2)),
        (resource.RLIMIT_AS, (limits.memory_bytes, limits.memory_bytes)),
        (resource.RLIMIT_FSIZE, (limits.file_size_bytes, limits.file_size_bytes)),
        (resource.RLIMIT_CORE, (0, 0)),
        (resource.RLIMIT_NOFILE, (limits.open_files, limits.open_files)),
        (resource.RLIMIT_NPROC, (nproc, nproc)),
    ]

    def preexec() -> None:
        # Runs in the child between fork and exec (after setsid): no threads, no imports.
        if (
            cgroup_fds
        ):  # first: everything it starts is in the group (doorlab.pset.isolation.cgroups)
            pid = str(os.getpid()).encode()
            for fd in cgroup_fds:
                os.write(fd, pid)
        if new_namespaces:  # as root, before the switch of user (doorlab.pset.isolation.choice)
            unshare(new_namespaces)
        for which, value in settings:
            resource.setrlimit(which, value)
        if limits.oom_score_adj is not None:  # before the switch: as root, also its floor
            set_oom_score_adj(limits.oom_score_adj)
        if switch_user and identity is not None:
            os.setgroups([])
            os.setresgid(identity.gid, identity.gid, identity.gid)
            os.setresuid(identity.uid, identity.uid, identity.uid)
        prctl(PR_SET_NO_NEW_PRIVS, 1)
        die_with_parent(parent_pid)  # after setuid, which clears the parent-death signal

    return preexec


def spawn(
    argv: Sequence[str],
    *,
    cwd: Path,
    env: dict[str, str],
    limits: Limits,
    identity: Identity | None,
    switch_user: bool = True,
    pass_fds: Sequence[int] = (),
    output: int | None = None,
    cgroup_fds: Sequence[int] = (),
    new_namespaces: int = 0,
) -> subprocess.Popen:
    """Starts the untrusted process: stdin from /dev/null, stdout and stderr into one pipe
    (``proc.stdout``, binary), its own session, the limits above.

    Call it before this process starts threads of its own (the limits are set between fork
    and exec, where only async-signal-safe work is safe in a threaded process).

    Args:
        argv: The command (bwrap's, for a student process in its view). cwd: Its working
            directory. env: Its whole environment. limits: Resource limits.
        identity: The user its code runs as (None: this process's); the process limit
            counts that user's processes.
        switch_user: Switch to ``identity`` before exec (False: the command does it, as
            the worker in the view does).
        pass_fds: Descriptors it inherits (the channel's).
        output: A descriptor for its stdout and stderr (None: a pipe, ``proc.stdout``).
        cgroup_fds: A cgroup's ``cgroup.procs`` files open for writing
            (:meth:`doorlab.pset.isolation.cgroups.Group.join_descriptors`): the process joins the
            group before its first instruction, and its ``pids.max`` bounds its processes
            instead of ``RLIMIT_NPROC`` (which counts the user's tasks on the whole machine,
            those of every other grading too).
        new_namespaces: :func:`unshare` flags (``CLONE_NEWNET | CLONE_NEWIPC``: the
            separate-user fallback as root, which has no view): its own network and IPC.
    """
    uid = os.getuid() if identity is None else identity.uid
    if cgroup_fds:
        nproc = resource.getrlimit(resource.RLIMIT_NPROC)[1]  # the group's pids.max holds
    else:
        nproc = count_tasks(uid) + limits.processes
    return subprocess.Popen(
        list(argv),
        cwd=cwd,
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE if output is None else output,
        stderr=subprocess.STDOUT,
        pass_fds=tuple(pass_fds),
        start_new_session=True,
        preexec_fn=_preexec(
            limits, identity, switch_user, nproc, os.getpid(), cgroup_fds, new_namespaces
        ),
    )


# Every descendant -------------------------------------------------------------------------


def _process_table() -> dict[int, tuple[int, str]]:
    """pid -> (parent pid, state letter) of every process."""
    table = {}
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            stat = Path(entry.path, "stat").read_bytes()
        except OSError:
            continue
        # "pid (comm) state ppid ...": comm may hold spaces and parentheses.
        fields = stat[stat.rfind(b")") + 2 :].split()
        if len(fields) >= 2:
            table[int(entry.name)] = (int(fields[1]), fields[0].decode())
    return table


def descendants(root: int, *, keep: Iterable[int] = ()) -> list[tuple[int, int, str]]:
    """(pid, parent pid, state) of every descendant of ``root``, except the subtrees rooted
    at ``keep``."""
    table = _process_table()
    children: dict[int, list[int]] = {}
    for pid, (ppid, _) in table.items():
        children.setdefault(ppid, []).append(pid)
    skip = set(keep)
    out, todo = [], list(children.get(root, []))
    while todo:
        pid = todo.pop()
        if pid in skip or pid not in table:
            continue
        out.append((pid, *table[pid]))
        todo.extend(children.get(pid, []))
    return out


def kill_descendants(
    *, keep: Iterable[int] = (), unreaped: Iterable[int] = (), timeout: float = 10.0
) -> int:
    """SIGKILLs every descendant of this process (but the subtrees at ``keep``) until none
    is alive, reaping those that are (or become) its children, except ``unreaped`` (children
    a ``subprocess.Popen`` will wait for). Returns how many processes it killed.

    Without the subreaper flag an orphan could escape to init; see the module docstring.
    """
    me = os.getpid()
    keep, unreaped = set(keep), set(unreaped)
    killed: set[int] = set()
    deadline = time.monotonic() + timeout
    while True:
        found = descendants(me, keep=keep)
        alive = [pid for pid, _, state in found if state not in "ZX"]
        for pid in alive:
            try:
                os.kill(pid, signal.SIGKILL)
                killed.add(pid)
            except (ProcessLookupError, PermissionError):
                pass
        for pid, ppid, _ in found:
            if ppid == me and pid not in unreaped:
                try:
                    os.waitpid(pid, os.WNOHANG)
                except ChildProcessError:
                    pass
        if not alive or time.monotonic() > deadline:
            return len(killed)
        time.sleep(0.002)


# Output -----------------------------------------------------------------------------------


class OutputCollector:
    """Drains a pipe in a thread: keeps its first and last ``kept`` bytes and counts all.

    Past ``limit`` bytes it calls ``on_overflow`` once (the caller stops the test) and goes
    on reading and discarding, so a writer never blocks and the memory held stays bounded.
    :meth:`drain` takes what is in the pipe now, in the caller's thread: the student's process
    flushes what it printed before it answers, so once an answer is in, that output is in the
    pipe, and a loaded machine that has not yet scheduled the thread must not lose it (the
    feedback once showed an error without the lines printed before it).
    """

    def __init__(
        self,
        stream,
        *,
        limit: int = OUTPUT_LIMIT_BYTES,
        kept: int = OUTPUT_KEPT_BYTES,
        on_overflow: Callable[[], None] | None = None,
    ):
        self._fd = stream.fileno()
        os.set_blocking(self._fd, False)  # the thread waits in select, then reads what is there
        self._stream = stream
        self.limit = limit
        self._kept = kept
        self._on_overflow = on_overflow
        self.head = bytearray()
        self._tail = bytearray()
        self.total = 0
        self.overflowed = False
        self._lock = threading.Lock()  # one reader at a time: the thread or drain()
        self._ended = False
        self._thread = threading.Thread(target=self._run, name="student-output", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            try:
                select.select([self._fd], [], [], 0.5)
            except (OSError, ValueError):
                break
            with self._lock:
                if self._read_available():
                    break
        self._stream.close()

    def _read_available(self) -> bool:
        """Reads what the pipe holds now (under the lock); True at its end (every writer gone)."""
        if self._ended:
            return True
        while True:
            try:
                chunk = os.read(self._fd, 1 << 16)
            except BlockingIOError:
                return False
            except OSError:
                chunk = b""
            if not chunk:
                self._ended = True
                return True
            self._take(chunk)

    def _take(self, chunk: bytes) -> None:
        self.total += len(chunk)
        if len(self.head) < self._kept:
            take = self._kept - len(self.head)
            self.head += chunk[:take]
            chunk = chunk[take:]
        if chunk:
            self._tail += chunk
            if len(self._tail) > self._kept:
                del self._tail[: len(self._tail) - self._kept]
        if self.total > self.limit and not self.overflowed:
            self.overflowed = True
            if self._on_overflow is not None:
                self._on_overflow()

    def drain(self) -> None:
        """Takes what the pipe holds now, at once (see the class)."""
        with self._lock:
            self._read_available()

    def join(self, timeout: float) -> None:
        """Waits for the end of the output (every writer gone) at most ``timeout`` [s]."""
        self._thread.join(timeout)

    def text(self) -> str:
        """The kept output, with a marker for what was left out."""
        head = self.head.decode("utf-8", "replace")
        omitted = self.total - len(self.head) - len(self._tail)
        if omitted <= 0 and not self._tail:
            return head
        tail = bytes(self._tail).decode("utf-8", "replace")
        middle = f"\n[... {omitted} bytes left out ...]\n" if omitted > 0 else ""
        return head + middle + tail
