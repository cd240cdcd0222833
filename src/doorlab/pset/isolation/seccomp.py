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
  ``acct``, ``quotactl``, ``swapon``/``swapoff``, ``reboot``, ``modify_ldt`` (the x86
  local descriptor table, a kernel path nothing here uses) and ``personality`` (execution
  domains that turn off address-space randomisation);
- a socket of any family but those the view needs (:data:`SOCKET_FAMILIES`: Unix sockets, and
  IPv4 and IPv6 on the view's own loopback): EAFNOSUPPORT for ``socket`` and ``socketpair``,
  so no netlink (the kernel's routing and audit interfaces), no packet socket, no ``AF_VSOCK``
  (a virtual machine's host), no ``AF_ALG`` (the kernel's crypto);
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
    "modify_ldt",
    "personality",
)
"""System calls refused with EPERM whatever their arguments."""
SOCKET_FAMILIES = {"AF_UNIX": 1, "AF_INET": 2, "AF_INET6": 10}
"""The socket families a student process may open (linux/socket.h): every other is refused.
The view's network namespace holds only its loopback; Python's ``multiprocessing`` and
``socketpair`` use Unix sockets."""
SOCKET_CALLS = ("socket", "socketpair")
"""The system calls whose first argument is a socket family."""
CLONE_FLAGS_ARGUMENT = {"s390x": 1, "s390": 1}
"""Which argument of ``clone`` holds its flags, where it is not the first."""


class FilterError(Exception):
    """The filter cannot be compiled here (no libseccomp: the message says how to get it)."""


Rule = tuple[str, str, tuple]
"""(action, system call, condition): the action an ``errno`` name; the condition ``()`` or
``(argument, comparison, value)``, the comparison ``"&=="`` (the argument's bits ``value``
all set), ``"=="`` or ``">="``."""


def rule_list() -> list[Rule]:
    """The filter's rules (:data:`Rule`), in the order they are added; everything else is
    allowed. (A test compares this list with a recorded one: a change is deliberate.)"""
    out: list[Rule] = [("EPERM", name, ()) for name in REFUSED]
    which = CLONE_FLAGS_ARGUMENT.get(os.uname().machine, 0)
    out += [("EPERM", "clone", (which, "&==", flag)) for flag in NAMESPACE_FLAGS.values()]
    out.append(("ENOSYS", "clone3", ()))
    allowed = sorted(SOCKET_FAMILIES.values())
    # libseccomp compares an argument once per rule: one rule per refused value, then the rest.
    refused = [(0, "==", n) for n in range(allowed[-1]) if n not in allowed]
    refused.append((0, ">=", allowed[-1] + 1))
    for call in SOCKET_CALLS:
        out += [("EAFNOSUPPORT", call, condition) for condition in refused]
    return out


def _comparison(seccomp, condition: tuple):
    """libseccomp's form of a rule's condition."""
    argument, op, value = condition
    if op == "&==":
        return seccomp.Arg(argument, seccomp.MASKED_EQ, value, value)
    return seccomp.Arg(argument, {"==": seccomp.EQ, ">=": seccomp.GE}[op], value)


@cache
def filter_bytes() -> bytes:
    """The compiled filter (classic BPF, as ``bwrap --seccomp`` reads it) of
    :func:`rule_list`, for this machine's architecture.

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
    for action, name, condition in rule_list():
        compare = [_comparison(seccomp, condition)] if condition else []
        try:
            rules.add_rule(seccomp.ERRNO(getattr(errno, action)), name, *compare)
        except (OSError, ValueError, RuntimeError):
            if condition:  # a rule on arguments always applies: refuse to run without it
                raise FilterError(f"libseccomp refused the rule {name} {condition}") from None
            # else not a system call of this architecture or kernel: nothing to refuse
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
