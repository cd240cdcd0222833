"""The first process of a student's view: imports once, forks a fresh student process per test.

Started by :class:`doorlab.pset.isolation.student_view.StudentView` as the view's PID 1
(bubblewrap's ``--as-pid-1``) with ``CONTROL_FD CONFIG_JSON``, after
:func:`doorlab.pset.isolation.bwrap_root.boot_code` switched it to the sandbox user for good. Before
it reads a request it imports what the problem set's files need
(:func:`doorlab.pset.isolation.worker._preload`: numpy, pydrake's modules, doorlab's student side)
and makes itself undumpable (no ``ptrace`` and no ``/proc/PID/mem`` for the processes it forks,
which run as the same user). It runs none of the student's code: it never puts the submission on
``sys.path``, and each request forks a child that is the student process of one test:

- the child keeps only that test's descriptors (its end of the channel's two pipes, its
  output pipe as stdout and stderr; ``/dev/null`` as stdin) and closes every other one,
  the control socket included;
- it starts its own session, gets ``SIGKILL`` when this process dies, lowers its CPU limit to
  the test's (``RLIMIT_CPU`` counts from zero in a new process; the other limits were set on
  this process by :func:`doorlab.pset.isolation.sandbox.spawn` and are inherited), enters the test's
  own scratch copy (``/pset/<test>``);
- then it runs :func:`doorlab.pset.isolation.worker.serve`: it notes what it sees, installs the
  honesty guard, says hello, and only then puts its folder on ``sys.path``; it never returns here.

The grader runs one test at a time in a view. Before each fork this process makes the view as
fresh as a new one: it kills every other process of the view (what an earlier test left
running, detached or not) and reaps them, empties ``/tmp`` and ``/dev/shm`` (and ``/pset``
but the test's own folder, where it may write), removes the System V shared memory,
semaphores and message queues of the view's IPC namespace, and clears the sandbox user's
kernel keyrings (which are the user's, not the view's: what a test of an earlier grading put
there is gone too); so a test sees no process, file or note of the tests before it, only
this process. (POSIX message queues cannot be listed without mounting their file system,
which this process may not do: a test that knows a queue's name could read what an earlier
test of the same grading left in it.)

As the namespace's init, this process receives from inside the view only the signals it
handles (``SIGCHLD``): the student's processes cannot kill it. It reaps every process of the
view (its children and the orphans the kernel hands to an init) and tells the grader how each
test's process ended (on that test's status socket: ``{"pid"}`` at the fork, then
``{"exit"}`` or ``{"signal"}``); the grader uses that for its message only. When the
grader closes the control socket it exits, and the kernel kills every process left in the
view.
"""

from __future__ import annotations

import ctypes
import json
import os
import re
import resource
import select
import shutil
import signal
import socket
import sys
import time

CONTROL_MESSAGE_BYTES = 4096
"""Largest request on the control socket [bytes]."""
REQUEST_FDS = 4
"""Descriptors a fork request carries: the channel's read and write ends, the output pipe's
write end, the test's status socket."""
SCRATCH_ROOT = "/pset"
"""Where the scratch copies of the tests are in the view (each in a folder of its own)."""
SUBMISSION_ROOT = "/doorlab-submission"
"""Where the grader's copies of the submission are, read-only, when :data:`SCRATCH_ROOT` is a
tmpfs (:data:`doorlab.pset.isolation.bwrap_root.SUBMISSION_MOUNT`): each test's folder is
copied from there, by this process, into the tmpfs (its pages the view's)."""
PROCESS_NAME = b"doorlab-view"
"""This process's name (``/proc/1/comm`` in the view: the worker checks it)."""
PRIVATE_FOLDERS = ("/tmp", "/dev/shm")
"""The view's private temporary folders, emptied before each test."""
SYSV_IPC = {"shm": "shmctl", "sem": "semctl", "msg": "msgctl"}
"""System V IPC objects (``/proc/sysvipc/<kind>``) and the call that removes one."""
IPC_RMID = 0
KEYCTL_CLEAR = 7
KEY_SPEC_USER_KEYRING = -4
KEY_SPEC_USER_SESSION_KEYRING = -5
KEYCTL_SYSCALL = {"x86_64": 250, "aarch64": 219, "ppc64le": 271, "s390x": 250}
"""keyctl's system call number by machine (Python has no binding)."""
STUDENT_OOM_SCORE_ADJ = 1000
"""Each test's process's ``oom_score_adj``: the first process the kernel's OOM killer ends
(:mod:`doorlab.pset.isolation.memory`; raising it needs no privilege)."""
CLEAN_TIMEOUT_S = 10.0
"""How long killing an earlier test's processes may take [s] (a fork bomb within the
process limit dies in milliseconds)."""

PR_SET_PDEATHSIG = 1
PR_SET_DUMPABLE = 4
PR_SET_NAME = 15
_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,100}$")

_libc = ctypes.CDLL(None, use_errno=True)


def _prctl(option: int, value) -> None:
    if _libc.prctl(option, value, 0, 0, 0) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"prctl({option}): {os.strerror(err)}")


def _send(sock: socket.socket, message: dict) -> None:
    try:
        sock.send(json.dumps(message).encode())
    except OSError:
        pass  # the grader closed its end: nobody to tell


def _status(code: int) -> dict:
    if os.WIFSIGNALED(code):
        return {"signal": os.WTERMSIG(code)}
    return {"exit": os.WEXITSTATUS(code) if os.WIFEXITED(code) else -1}


def _close_all_but(keep: set[int]) -> None:
    try:
        fds = [int(fd) for fd in os.listdir("/proc/self/fd")]
    except OSError:
        fds = list(range(3, resource.getrlimit(resource.RLIMIT_NOFILE)[0]))
    for fd in fds:
        if fd not in keep:
            try:
                os.close(fd)
            except OSError:
                pass


def _child(request: dict, fds: list[int], config: dict) -> None:
    """The student process of one test (in the forked child; never returns)."""
    code = 70
    try:
        signal.set_wakeup_fd(-1)
        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        request_r, answer_w, output_w, _status_fd = fds
        null = os.open("/dev/null", os.O_RDONLY)
        os.dup2(null, 0)
        os.dup2(output_w, 1)
        os.dup2(output_w, 2)
        _close_all_but({0, 1, 2, request_r, answer_w})
        os.setsid()
        _prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
        try:
            with open("/proc/self/oom_score_adj", "w") as f:
                f.write(str(STUDENT_OOM_SCORE_ADJ))
        except OSError:
            pass  # the view's floor (the grader's VIEW_OOM_SCORE_ADJ) holds
        cpu = max(1, int(request["cpu_seconds"]))
        resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu + 2))
        os.chdir(os.path.join(SCRATCH_ROOT, request["scratch"]))
        from doorlab.pset.isolation.worker import serve

        code = serve(request_r, answer_w, config)
    except BaseException:  # noqa: BLE001 - nothing of the child may return into the loop
        code = 71
    finally:
        os._exit(code)


def _others() -> list[int]:
    """Every process of the view but this one (its PID namespace: all of them below it)."""
    me = os.getpid()
    return [int(p) for p in os.listdir("/proc") if p.isdigit() and int(p) != me]


def _empty(folder: str, keep: str = "") -> None:
    def retry(function, path, _):
        # A folder made unwritable (its owner may change that) or a file in it.
        try:
            os.chmod(os.path.dirname(path) or folder, 0o700)
            os.chmod(path, 0o700)
            function(path)
        except OSError:
            pass

    try:
        names = os.listdir(folder)
    except OSError:
        return
    for name in names:
        if name == keep:
            continue
        path = os.path.join(folder, name)
        if os.path.isdir(path) and not os.path.islink(path):
            shutil.rmtree(path, onerror=retry)
        else:
            try:
                os.unlink(path)
            except OSError:
                pass


def _remove_ipc() -> None:
    """Removes every System V IPC object of the view's IPC namespace (the student's)."""
    for kind, call in SYSV_IPC.items():
        try:
            with open(f"/proc/sysvipc/{kind}") as f:
                lines = f.read().splitlines()[1:]
        except OSError:
            continue
        remove = getattr(_libc, call)
        for line in lines:
            fields = line.split()
            if len(fields) < 2 or not fields[1].isdigit():
                continue
            if kind == "sem":
                remove(int(fields[1]), 0, IPC_RMID)
            else:
                remove(int(fields[1]), IPC_RMID, None)


def _clear_keyrings() -> None:
    """Clears the sandbox user's keyrings (kept by the kernel per user, across processes)."""
    number = KEYCTL_SYSCALL.get(os.uname().machine)
    if number is None:
        return
    for keyring in (KEY_SPEC_USER_KEYRING, KEY_SPEC_USER_SESSION_KEYRING):
        _libc.syscall(number, KEYCTL_CLEAR, keyring)


def clean_view(children: dict, keep: str = "") -> bool:
    """Kills and reaps every other process of the view, empties its temporary folders and
    its scratch root but ``keep`` (the next test's folder), removes its IPC objects and
    clears the user's keyrings; False if a process outlived :data:`CLEAN_TIMEOUT_S`."""
    deadline = time.monotonic() + CLEAN_TIMEOUT_S
    while True:
        others = _others()
        for pid in others:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
        _reap(children)
        if not others:
            break
        if time.monotonic() > deadline:
            return False
        time.sleep(0.001)
    for folder in PRIVATE_FOLDERS:
        _empty(folder)
    _empty(SCRATCH_ROOT, keep=keep)
    _remove_ipc()
    _clear_keyrings()
    return True


def _refuse(status: socket.socket, fds: list[int], why: str) -> None:
    """Tells the grader this test cannot start (``why``) and closes its descriptors."""
    _send(status, {"refused": why})
    status.close()
    for fd in fds[:3]:
        os.close(fd)


def _fork(request: dict, fds: list[int], config: dict, children: dict) -> None:
    """Starts the student process of one test, in a view made fresh."""
    status = socket.socket(fileno=fds[3])
    if not (
        isinstance(request.get("scratch"), str)
        and _NAME.match(request["scratch"])
        and request["scratch"] not in (".", "..")
        and isinstance(request.get("cpu_seconds"), (int, float))
    ):
        _send(status, {"refused": "a request this process does not understand"})
        status.close()
        for fd in fds[:3]:
            os.close(fd)
        return
    tmpfs = os.path.isdir(SUBMISSION_ROOT)  # else the grader's copy is in SCRATCH_ROOT
    if not clean_view(children, keep="" if tmpfs else request["scratch"]):
        _refuse(status, fds, "a process of an earlier test could not be killed")
        return
    if tmpfs:
        try:
            source = os.path.join(SUBMISSION_ROOT, request["scratch"])
            shutil.copytree(source, os.path.join(SCRATCH_ROOT, request["scratch"]), symlinks=True)
        except (OSError, shutil.Error) as e:
            _refuse(status, fds, f"it could not copy the submission into the view ({e})")
            return
    sys.stdout.flush()
    sys.stderr.flush()
    try:
        pid = os.fork()
    except OSError as e:  # EAGAIN (a process limit), ENOMEM: this test only, said so
        _send(status, {"refused": f"it could not fork the test's process ({e.strerror or e})"})
        status.close()
        for fd in fds[:3]:
            os.close(fd)
        return
    if pid == 0:
        _child(request, fds, config)
    for fd in fds[:3]:
        os.close(fd)
    children[pid] = status
    _send(status, {"pid": pid})


def _reap(children: dict) -> None:
    while True:
        try:
            pid, code = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return
        status = children.pop(pid, None)
        if status is not None:  # a test's process (else an orphan handed to this init)
            _send(status, _status(code))
            status.close()


def main(argv: list[str]) -> int:
    """``CONTROL_FD CONFIG_JSON``: serves fork requests until the control socket closes."""
    _prctl(PR_SET_PDEATHSIG, signal.SIGKILL)  # the switch of user cleared bwrap's
    # As PID 1 a signal it handles reaches it from inside the view: only SIGCHLD does.
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    control = socket.socket(fileno=int(argv[0]))
    config = json.loads(argv[1]) if len(argv) > 1 else {}
    from doorlab.pset.isolation.worker import _preload

    _preload()
    _prctl(PR_SET_DUMPABLE, 0)
    _prctl(PR_SET_NAME, ctypes.c_char_p(PROCESS_NAME))
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_r, False)
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w)
    signal.signal(signal.SIGCHLD, lambda signum, frame: None)
    children: dict[int, socket.socket] = {}
    _send(control, {"ready": os.getpid()})
    poller = select.poll()
    poller.register(control.fileno(), select.POLLIN)
    poller.register(wake_r, select.POLLIN)
    while True:
        ready = {fd for fd, _ in poller.poll()}
        if wake_r in ready:
            try:
                while os.read(wake_r, 512):
                    pass
            except BlockingIOError:
                pass
        _reap(children)
        if control.fileno() not in ready:
            continue
        try:
            message, fds, _, _ = socket.recv_fds(control, CONTROL_MESSAGE_BYTES, REQUEST_FDS)
        except OSError:
            return 0
        if not message:
            return 0  # the grader is done with this view
        try:
            request = json.loads(message.decode())
        except (UnicodeDecodeError, ValueError):
            request = None
        if len(fds) != REQUEST_FDS or not isinstance(request, dict):
            for fd in fds:
                os.close(fd)
            continue
        _fork(request, fds, config, children)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
