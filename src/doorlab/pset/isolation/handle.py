"""The trusted side's handle on one student process (:mod:`doorlab.pset.isolation.worker`).

:class:`StudentProcess` copies the submission to a scratch folder (its working directory),
starts the worker there under :mod:`doorlab.pset.isolation.sandbox`'s limits, in the student's view
(:mod:`doorlab.pset.isolation.bwrap_root`) when the grading has one
(:mod:`doorlab.pset.isolation.choice`), and asks it for numbers over
:mod:`doorlab.pset.isolation.channel`. Whatever goes wrong on that side (an exception in the
student's code, a crash, an exit, a signal, a limit, a hang, garbage on the channel, the honesty
boundary) becomes a :class:`StudentFailure` whose message says so in a student's words (cleaned:
:func:`doorlab.pset.isolation.safe_text.clean_text`); the process and every descendant are killed
when the test ends.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from doorlab.pset.isolation import bwrap_root, sandbox
from doorlab.pset.isolation.cgroups import CgroupError
from doorlab.pset.isolation.channel import (
    KIND_ARRAY,
    Channel,
    ChannelClosed,
    ChannelTimeout,
    ProtocolError,
    as_text,
    parse_array,
    parse_json,
)
from doorlab.pset.isolation.choice import Isolation
from doorlab.pset.isolation.memory import STUDENT_OOM_SCORE_ADJ, verdict
from doorlab.pset.isolation.safe_text import clean_text
from doorlab.pset.isolation.seccomp import FilterError, filter_descriptor
from doorlab.pset.rules.clock import Clock

MAX_SUBMISSION_BYTES = 64 << 20
"""Largest submission copied to the scratch folder [bytes]."""
MAX_DETAIL_CHARS = 3000
"""Longest detail (traceback and printed output) kept for a test's output."""
TICK_SIZE = 30
"""Floats of a tick's request: q, q_cmd, v, tau_ext (7 each), t_plan, control_period."""
ANSWER_SIZE = 14
"""Floats of a tick's answer: q_ref and tau_ff (7 each)."""


class StudentFailure(Exception):
    """The student's code failed this test: ``str()`` is the message, ``detail`` the
    traceback and printed output (both capped)."""

    def __init__(self, message: str, detail: str = ""):
        super().__init__(clean_text(message))
        self.detail = clean_text(detail)


class SandboxError(Exception):
    """The grader could not run the student's process (not the student's doing)."""


def copy_submission(folder: Path, dest: Path, identity: sandbox.Identity | None) -> None:
    """Copies the submission: folders, regular files (no compiled ``.pyc``: what runs is
    the source) and symbolic links as links (never their targets: the copy is made by the
    grader's user); owned by ``identity``.

    Raises:
        StudentFailure: The submission is larger than :data:`MAX_SUBMISSION_BYTES`.
    """
    total = 0
    dest.mkdir(mode=0o700)
    for root, dirs, files in os.walk(folder, followlinks=False):
        rel = Path(root).relative_to(folder)
        dirs[:] = [d for d in dirs if d != "__pycache__"]
        for d in list(dirs):
            src = Path(root, d)
            if src.is_symlink():
                dirs.remove(d)
                os.symlink(os.readlink(src), dest / rel / d)
            else:
                (dest / rel / d).mkdir()
        for f in files:
            src, dst = Path(root, f), dest / rel / f
            st = os.lstat(src)
            if stat.S_ISLNK(st.st_mode):
                os.symlink(os.readlink(src), dst)
            elif stat.S_ISREG(st.st_mode) and not f.endswith(".pyc"):
                total += st.st_size
                if total > MAX_SUBMISSION_BYTES:
                    raise StudentFailure(
                        f"the submission holds more than {MAX_SUBMISSION_BYTES >> 20} MiB"
                    )
                shutil.copyfile(src, dst, follow_symlinks=False)
    if identity is not None:
        for root, dirs, files in os.walk(dest):
            for name in [*dirs, *files]:
                os.lchown(Path(root, name), identity.uid, identity.gid)
        os.chown(dest, identity.uid, identity.gid)


SHARED_TEMP_FOLDERS = ("/tmp", "/var/tmp", "/dev/shm")
"""Where a student process without the view (another user, no mount namespace) can leave
files for the next one: the view gives it a private /tmp and /dev/shm instead."""


def remove_leftovers(uid: int, since: float) -> list[str]:
    """Removes what user ``uid`` created in the shared temporary folders since ``since``
    (a time.time(); the sandbox user's other files stay: ``nobody`` may be shared); returns
    the paths removed. For the modes without the view, where that user is not the grader."""
    removed = []
    for folder in SHARED_TEMP_FOLDERS:
        try:
            entries = list(os.scandir(folder))
        except OSError:
            continue
        for entry in entries:
            try:
                st = entry.stat(follow_symlinks=False)
            except OSError:
                continue
            if st.st_uid != uid or st.st_ctime < since - 1.0:
                continue
            if stat.S_ISDIR(st.st_mode):
                shutil.rmtree(entry.path, ignore_errors=True)
            else:
                try:
                    os.unlink(entry.path)
                except OSError:
                    continue
            removed.append(entry.path)
    return removed


SYSV_IPC = {"shm": ("shmid", "shmctl"), "sem": ("semid", "semctl"), "msg": ("msqid", "msgctl")}
"""System V IPC objects (``/proc/sysvipc/<kind>``): their id column and the call removing one."""
POSIX_QUEUES = "/dev/mqueue"
"""Where POSIX message queues are listed (when that file system is mounted)."""
IPC_RMID = 0


def remove_ipc_leftovers(uid: int, since: float) -> list[str]:
    """Removes the System V shared memory, semaphores and message queues, and the POSIX
    message queues, that user ``uid`` created since ``since`` (a time.time()); returns what
    it removed. For the separate-user fallback where the machine refuses it an IPC namespace
    of its own (:data:`doorlab.pset.isolation.choice.OWN_NAMESPACES`)."""
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    removed = []
    for kind, (id_column, call) in SYSV_IPC.items():
        try:
            header, *lines = Path(f"/proc/sysvipc/{kind}").read_text().splitlines()
        except (OSError, ValueError):
            continue
        names = header.split()
        for line in lines:
            row = dict(zip(names, line.split(), strict=False))
            try:
                mine = int(row["cuid"]) == uid and int(row["ctime"]) >= since - 1.0
                number = int(row[id_column])
            except (KeyError, ValueError):
                continue
            if not mine:
                continue
            remove = getattr(libc, call)
            result = (
                remove(number, 0, IPC_RMID) if kind == "sem" else remove(number, IPC_RMID, None)
            )
            if result == 0:
                removed.append(f"System V {kind} {number}")
    try:
        queues = list(os.scandir(POSIX_QUEUES))
    except OSError:
        queues = []
    for entry in queues:
        try:
            st = entry.stat(follow_symlinks=False)
            if st.st_uid == uid and st.st_ctime >= since - 1.0:
                os.unlink(entry.path)
                removed.append(entry.path)
        except OSError:
            continue
    return removed


_NO_MODULE = re.compile(r"ModuleNotFoundError: No module named '([A-Za-z_][\w.]*)'")


def _import_failure(output: str) -> str | None:
    """Why a student process that died before its greeting did, when it could not import the
    grader's own packages (the student's code is not loaded yet): the user it runs as cannot
    read the grader's Python environment. None for anything else."""
    found = _NO_MODULE.search(output)
    if found is None or found.group(1).split(".")[0] not in ("doorlab", "numpy", "pydrake"):
        return None
    return (
        f"it could not import {found.group(1)}: the user it runs as cannot read the grader's "
        "Python environment; install doorlab where that user can read it (not in a private "
        "folder such as /root)"
    )


def _signal_message(signum: int, limits: sandbox.Limits) -> str:
    if signum == signal.SIGXCPU:
        return f"your code used more than {limits.cpu_seconds:.0f} s of CPU time (the CPU limit)"
    if signum == signal.SIGXFSZ:
        return (
            f"your code wrote a file larger than {limits.file_size_bytes >> 20} MiB "
            "(the file-size limit)"
        )
    if signum == signal.SIGSEGV:
        return "your code crashed its process (SIGSEGV, a segmentation fault)"
    try:
        name = signal.Signals(signum).name
    except ValueError:
        name = f"signal {signum}"
    return f"your code's process was killed by {name}"


def student_environment(home: str, tmp: str) -> dict[str, str]:
    """The student process's whole environment (nothing of the grader's): ``home`` its
    working directory, ``tmp`` its temporary folder (both as its process names them)."""
    return {
        "PATH": "/usr/local/bin:/usr/bin:/bin",
        "HOME": home,
        "TMPDIR": tmp,
        "LANG": "C.UTF-8",
        "MPLBACKEND": "Agg",
        "MPLCONFIGDIR": os.path.join(tmp, ".matplotlib"),
        "OPENBLAS_NUM_THREADS": "1",
        "OMP_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
    }


class StudentProcess:
    """The worker for one test, running the submission's code in a scratch copy.

    Use as a context manager; :meth:`close` (on exit) kills the process and every
    descendant of the calling process: the caller is a trusted job process (a child
    subreaper, see :mod:`doorlab.pset.isolation.sandbox`) whose only child is this one. Every call
    raises :class:`StudentFailure` when the student's side fails.

    Args:
        folder: The submission. workdir: The grading's private folder (scratch copies go
            in it). name: The test's job name (the scratch folder's name).
        time_limit: The whole test's time (:class:`doorlab.pset.rules.clock.Clock`: wall time
            less the grader's wait for a CPU) and the student's CPU time [s].
        isolation: How the grading isolates the student's code.
        group: The cgroup its processes go in (:mod:`doorlab.pset.isolation.cgroups`; None: none).
    """

    def __init__(
        self,
        folder: Path,
        workdir: Path,
        name: str,
        time_limit: float,
        isolation: Isolation,
        group=None,
    ):
        self.limits = sandbox.Limits(cpu_seconds=time_limit, oom_score_adj=STUDENT_OOM_SCORE_ADJ)
        self.deadline = Clock(time_limit)
        self.group = group
        self._oom_kills = group.oom_kills() if group is not None else 0
        self.started = time.time()
        self.facts: dict = {}
        self.isolation = isolation
        self._private: list[Path] = []
        self._closed = False
        self._start(folder, workdir, name.replace(":", "_"))
        self.output = sandbox.OutputCollector(
            self._output_stream, limit=self.limits.output_bytes, on_overflow=self._stop
        )
        try:
            hello = self.channel.receive_json(self.deadline)
        except ProtocolError as e:
            self.close()
            output = self.output.text()
            why = _import_failure(output) or self._death(e)
            raise SandboxError(
                f"the student's process did not start ({why}): " + clean_text(output[-500:])
            ) from None
        facts = hello.get("hello")
        self.facts = facts if isinstance(facts, dict) else {}
        self._started()

    def _start(self, folder: Path, workdir: Path, stem: str) -> None:
        """Copies the submission and starts the process: sets ``channel``, ``_output_stream``
        (its stdout and stderr, binary) and ``proc``."""
        identity = self.isolation.user()
        plan = self.isolation.plan()
        self.scratch = workdir / ("scratch_" + stem)
        self._private.append(self.scratch)
        try:
            copy_submission(folder, self.scratch, identity)
            tmp_dirs = None
            if plan is not None:
                drop = None if identity is None else (identity.uid, identity.gid)
                tmp_dirs = bwrap_root.job_tmp_dirs(plan, workdir / ("tmp_" + stem), drop)
                if tmp_dirs is not None:
                    self._private.append(workdir / ("tmp_" + stem))
        except OSError as e:
            raise SandboxError(f"cannot copy the submission: {e}") from None
        request_r, self._request_w = os.pipe()
        self._answer_r, answer_w = os.pipe()
        os.set_blocking(self._request_w, False)
        channel_args = [str(request_r), str(answer_w), json.dumps(self.isolation.guard)]
        passed, seccomp = [request_r, answer_w], None
        if plan is None:
            argv = [
                sys.executable,
                "-I",
                "-B",
                "-m",
                "doorlab.pset.isolation.worker",
                *channel_args,
            ]
            env = student_environment(str(self.scratch), str(self.scratch))
        else:
            drop = None if identity is None else (identity.uid, identity.gid)
            try:
                seccomp = filter_descriptor()
            except FilterError as e:
                raise SandboxError(f"cannot start the student's process: {e}") from None
            passed.append(seccomp)
            argv = bwrap_root.bwrap_argv(
                plan, self.scratch, tmp_dirs, as_root=identity is not None, seccomp_fd=seccomp
            )
            argv += [plan.python, "-I", "-S", "-B", "-c", bwrap_root.worker_code(plan, drop)]
            argv += channel_args
            env = student_environment(bwrap_root.SCRATCH_MOUNT, "/tmp")
        groups = []
        try:
            groups = self.group.join_descriptors() if self.group is not None else []
            self.proc = sandbox.spawn(
                argv,
                cwd=self.scratch,
                env=env,
                limits=self.limits,
                identity=identity,
                switch_user=plan is None,
                pass_fds=tuple(passed),
                cgroup_fds=groups,
                new_namespaces=self.isolation.namespaces if plan is None else 0,
            )
        except (OSError, subprocess.SubprocessError, CgroupError) as e:  # a limit refused
            raise SandboxError(f"cannot start the student's process: {e}") from None
        finally:
            for fd in [*passed, *groups]:
                os.close(fd)
        self.channel = Channel(self._answer_r, self._request_w)
        self._output_stream = self.proc.stdout
        cpu = self.group.cpu_seconds if self.group is not None else None
        self.deadline.watch_student(self.proc.pid, cpu)

    def _started(self) -> None:
        """After the hello, before any request (the student's code has not run yet)."""

    def _stop(self) -> None:
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass

    def __enter__(self) -> StudentProcess:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Kills the process and every descendant, then collects the output."""
        if self._closed:
            return
        self._closed = True
        self._end()
        self.output.join(timeout=5)
        for fd in (self._answer_r, self._request_w):
            try:
                os.close(fd)
            except OSError:
                pass
        for folder in self._private:
            shutil.rmtree(folder, ignore_errors=True)
        user = self.isolation.user()
        if self.isolation.mode == "uid" and user is not None:
            remove_leftovers(user.uid, self.started)
            if not self.isolation.namespaces & sandbox.CLONE_NEWIPC:  # no IPC namespace
                remove_ipc_leftovers(user.uid, self.started)

    def _end(self) -> None:
        """Kills the process and every process it started; waits for them."""
        self._stop()
        sandbox.kill_descendants(unreaped=[self.proc.pid])
        try:
            self.proc.wait(timeout=10)
        except Exception:  # noqa: BLE001 - nothing more can be done
            pass
        sandbox.kill_descendants()

    def _exit_code(self, timeout: float) -> int | None:
        """The process's exit code (negative: killed by that signal), or None while it runs
        after ``timeout`` [s]."""
        try:
            code = self.proc.wait(timeout=timeout)
        except Exception:  # noqa: BLE001 - still running
            return None
        if self.isolation.mode == "bwrap" and 128 < code < 128 + 65:
            # bwrap reports a death by signal N as exit code 128 + N (as a shell does).
            return 128 - code
        return code

    def _running(self) -> bool:
        return self.proc.poll() is None

    # What went wrong --------------------------------------------------------------------

    def _death(self, error: ProtocolError) -> str:
        """The cause of a broken exchange, in a student's words."""
        if self.output.overflowed:
            return (
                f"your code printed more than {self.output.limit >> 20} MiB "
                "(the output limit); the test was stopped"
            )
        if isinstance(error, ChannelTimeout):
            starved = self.deadline.starved()
            if starved is not None:  # not the student's: no verdict
                raise SandboxError(starved)
            return (
                f"time limit: your code did not answer within {self.limits.cpu_seconds:.0f} s "
                "(an endless loop? a long sleep?)"
            )
        code = self._exit_code(timeout=2.0)
        if (code is None or code == -signal.SIGKILL) and self._out_of_memory():
            # The kernel ended a process of the view for want of memory: the test's own
            # process, one of its children holding the memory, or the view's first process
            # (then the whole view, whose processes held it).
            return verdict(self.group.memory_limit)
        if code is None:
            if isinstance(error, ChannelClosed):
                return "your code closed the grader's channel"
            return f"your code's process sent something that is not an answer ({error})"
        if code < 0:
            return _signal_message(-code, self.limits)
        return (
            f"your code ended its process (exit code {code}) before answering "
            "(sys.exit, os._exit or os.kill in your code?)"
        )

    def _out_of_memory(self) -> bool:
        """Whether the kernel killed a process of the test's group for want of memory."""
        if self.group is None or self.group.memory_limit is None:
            return False
        return self.group.oom_kills() > self._oom_kills

    def _detail(self, traceback: str = "") -> str:
        parts = []
        if traceback:
            parts.append(traceback)
        self.output.join(timeout=0.05 if self._running() else 1.0)
        self.output.drain()  # what it printed before its answer, whether the thread ran or not
        printed = self.output.text().strip()
        if printed:
            parts.append(f"your code printed ({self.output.total} bytes):\n{printed}")
        text = "\n".join(parts)
        if len(text) > MAX_DETAIL_CHARS:
            text = text[:MAX_DETAIL_CHARS] + " [...]"
        return text

    def _failure(self, error: ProtocolError) -> StudentFailure:
        message = self._death(error)
        self._stop()
        return StudentFailure(message, self._detail())

    def _check_answer(self, answer: dict) -> dict:
        if "honesty" in answer:
            raise StudentFailure(as_text(answer["honesty"], 500), self._detail())
        if "invalid" in answer:
            raise StudentFailure(as_text(answer["invalid"], 500), self._detail())
        if "error" in answer:
            error = answer["error"] if isinstance(answer["error"], dict) else {}
            kind = as_text(error.get("type"), 100) or "Error"
            text = as_text(error.get("message"), 500)
            message = f"{kind}: {text}" if text else kind
            if "MemoryError" in kind:
                message = (
                    f"your code ran out of memory (the limit is "
                    f"{self.limits.memory_bytes >> 30} GiB of address space): {message}"
                )
            elif "[Errno 27]" in text:  # EFBIG: Python ignores SIGXFSZ, the write fails
                message = f"{_signal_message(signal.SIGXFSZ, self.limits)}: {message}"
            raise StudentFailure(message, self._detail(as_text(error.get("traceback"))))
        if self.output.overflowed:
            raise self._failure(ProtocolError("output"))
        return answer

    # Requests ---------------------------------------------------------------------------

    def call(self, op: str, **args) -> dict:
        """Sends request ``op`` and returns the answer (a JSON object, not yet validated)."""
        try:
            self.channel.send_json({"op": op, **args}, self.deadline)
            return self._check_answer(self.channel.receive_json(self.deadline))
        except ProtocolError as e:
            raise self._failure(e) from None

    def tick(self, values: np.ndarray) -> np.ndarray:
        """One control tick: (q, q_cmd, v, tau_ext, t_plan, control_period) in, the 14
        floats (q_ref, tau_ff) of the student's plan out (not yet checked for finiteness)."""
        try:
            self.channel.send_array(values, self.deadline)
            kind, body = self.channel.receive(self.deadline)
            if kind == KIND_ARRAY:
                return parse_array(body, ANSWER_SIZE)
            self._check_answer(parse_json(body))
            raise ProtocolError("an object where a tick's answer was expected")
        except ProtocolError as e:
            raise self._failure(e) from None
