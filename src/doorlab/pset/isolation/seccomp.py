"""The student's view's system-call filter: what no student process may ask of the kernel.

Namespaces, mounts and a few other kernel interfaces are a large attack surface and nothing
the problem set needs: inside the view (:mod:`doorlab.pset.isolation.bwrap_root`) the student's code
could otherwise make a user namespace of its own and, with the capabilities it holds there, reach
kernel code an ordinary process never does. bubblewrap applies a seccomp filter to the view's
first process and everything it starts (``--seccomp FD``, before the command runs, so bwrap's
own set-up is not filtered); :func:`filter_bytes` compiles it with libseccomp (through the
``pyseccomp`` binding: never hand-written BPF). The filter allows everything but:

- ``unshare``, ``setns`` and ``clone`` with any of the namespace flags (``CLONE_NEWUSER``,
  ``CLONE_NEWNS``, ``CLONE_NEWPID``, ``CLONE_NEWNET``, ``CLONE_NEWIPC``, ``CLONE_NEWUTS``,
  ``CLONE_NEWCGROUP``): EPERM; ``clone3``, whose flags are behind a pointer a filter cannot
  read: ENOSYS, so the C library falls back to ``clone`` (as Docker's and Flatpak's filters do);
- the mount family (``mount``, ``umount2``, ``pivot_root``, the new mount API);
- the kernel's keyrings (``add_key``, ``request_key``, ``keyctl``): kept per user across
  processes, so two gradings at once could pass a note there;
- ``bpf``, ``perf_event_open``, ``userfaultfd``, ``io_uring_*``, ``ptrace``,
  ``process_vm_writev``, ``open_by_handle_at``, module and kexec loading, ``syslog``,
  ``acct``, ``quotactl``, ``swapon``/``swapoff``, ``reboot``;
- every system call of another architecture (the 32-bit calls of an x86-64 process): the
  process is killed (libseccomp's default for a foreign architecture).
"""

from __future__ import annotations

import errno
import os
from functools import cache

NAMESPACE_FLAGS = {
    "CLONE_NEWNS": 0x00020000,
    "CLONE_NEWCGROUP": 0x02000000,
    "CLONE_NEWUTS": 0x04000000,
    "CLONE_NEWIPC": 0x08000000,
    "CLONE_NEWUSER": 0x10000000,
    "CLONE_NEWPID": 0x20000000,
    "CLONE_NEWNET": 0x40000000,
}
"""``clone`` flags that make a namespace (linux/sched.h)."""
REFUSED = (
    "unshare",
    "setns",
    "mount",
    "umount2",
    "pivot_root",
    "fsopen",
    "fsmount",
    "fsconfig",
    "fspick",
    "move_mount",
    "open_tree",
    "mount_setattr",
    "add_key",
    "request_key",
    "keyctl",
    "bpf",
    "perf_event_open",
    "userfaultfd",
    "io_uring_setup",
    "io_uring_enter",
    "io_uring_register",
    "ptrace",
    "process_vm_writev",
    "open_by_handle_at",
    "name_to_handle_at",
    "init_module",
    "finit_module",
    "delete_module",
    "kexec_load",
    "kexec_file_load",
    "syslog",
    "acct",
    "quotactl",
    "swapon",
    "swapoff",
    "reboot",
)
"""System calls refused with EPERM whatever their arguments."""
CLONE_FLAGS_ARGUMENT = {"s390x": 1, "s390": 1}
"""Which argument of ``clone`` holds its flags, where it is not the first."""


class FilterError(Exception):
    """The filter cannot be compiled here (no libseccomp: the message says how to get it)."""


@cache
def filter_bytes() -> bytes:
    """The compiled filter (classic BPF, as ``bwrap --seccomp`` reads it), for this machine's
    architecture.

    Raises:
        FilterError: libseccomp or its binding is missing.
    """
    try:
        import pyseccomp as seccomp
    except (ImportError, RuntimeError) as e:  # RuntimeError: the binding found no libseccomp
        raise FilterError(
            f"the system-call filter needs libseccomp (apt-get install libseccomp2) and the "
            f"pyseccomp package ({e})"
        ) from None
    rules = seccomp.SyscallFilter(seccomp.ALLOW)
    refuse = seccomp.ERRNO(errno.EPERM)
    for name in REFUSED:
        try:
            rules.add_rule(refuse, name)
        except (OSError, ValueError, RuntimeError):
            pass  # not a system call of this architecture or kernel: nothing to refuse
    which = CLONE_FLAGS_ARGUMENT.get(os.uname().machine, 0)
    for flag in NAMESPACE_FLAGS.values():
        rules.add_rule(refuse, "clone", seccomp.Arg(which, seccomp.MASKED_EQ, flag, flag))
    try:
        rules.add_rule(seccomp.ERRNO(errno.ENOSYS), "clone3")
    except (OSError, ValueError, RuntimeError):
        pass
    fd = os.memfd_create("doorlab-seccomp", os.MFD_CLOEXEC)
    try:
        with os.fdopen(os.dup(fd), "w+b") as f:
            rules.export_bpf(f)
        os.lseek(fd, 0, os.SEEK_SET)
        chunks = []
        while chunk := os.read(fd, 1 << 16):
            chunks.append(chunk)
    finally:
        os.close(fd)
    return b"".join(chunks)


def filter_descriptor() -> int:
    """A new descriptor (inheritable, at offset 0) holding :func:`filter_bytes`, to pass to
    bwrap as ``--seccomp FD``; the caller closes it once bwrap started.

    Raises:
        FilterError: See :func:`filter_bytes`.
    """
    data = filter_bytes()
    fd = os.memfd_create("doorlab-seccomp", 0)
    os.write(fd, data)
    os.lseek(fd, 0, os.SEEK_SET)
    return fd
