"""One cgroup per grading: what a grading's processes may use together, whatever runs beside it.

Per-process limits (:mod:`doorlab.pset.isolation.sandbox`'s ``setrlimit``) bound each process, and
``RLIMIT_NPROC`` counts every task of the sandbox user on the machine, so two gradings at once
(``grade-all --jobs 2``) shared it, and nothing divided the CPU between them. A cgroup holds a
set of processes and everything they start: the kernel counts and limits them together. Each
grading gets its own (:class:`GradingGroups`):

- ``G`` (``doorlab-<supervisor pid>-<n>``), with the default CPU weight: gradings running at
  once share the CPU equally, however many processes each starts;
- ``G/trusted``: the grading's trusted processes (the jobs forked by the supervisor), with
  :data:`TRUSTED_WEIGHT` (four times the student's): the student's code cannot take the CPU
  the grader needs to answer it;
- ``G/view<k>``: a student's view (bubblewrap and every process in it), or ``G/student-<job>``
  (a student process without the view): ``pids.max`` (:data:`VIEW_TASKS`: the view's own
  process limit, which no other grading's processes count against), ``memory.max`` (the
  view's processes, its tmpfs, its memfds and pipe buffers together:
  :mod:`doorlab.pset.isolation.memory` derives it from the room there is and the views at once,
  at most :data:`VIEW_MEMORY_BYTES`), the default CPU weight, and its CPU time counted (the
  test's clock, :mod:`doorlab.pset.rules.clock`).

Where: below the cgroup the grader runs in, so the limits of whatever started it (a
container, a session, a service) still hold. With cgroup v1 (a hierarchy per controller:
``cpu``, ``cpuacct``, ``memory``, ``pids``) that is a folder below its own in each; with cgroup
v2 (one hierarchy, ``cgroup2``) the cgroup it runs in when that is the hierarchy's root (a
container with its own cgroup namespace; a machine without systemd), else the cgroup above
it when that one delegates ``cpu``, ``memory`` and ``pids`` to its children and may be
written (a delegated subtree: systemd's ``Delegate=yes``, as root or as the user it is
delegated to). Which one is used is decided by what is mounted (:func:`probe`). Where neither
serves (an ordinary user without a delegated subtree; a read-only ``/sys/fs/cgroup``), the
grading runs on the per-process limits alone and its results say why
(``extra_data.sandbox.cgroup``).
"""

from __future__ import annotations

import itertools
import json
import os
import signal
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

NEEDED = ("cpu", "memory", "pids")
"""The controllers a grading's groups need (v1 also ``cpuacct``, for the CPU time)."""
V1_CONTROLLERS = ("cpu", "cpuacct", "memory", "pids")
"""cgroup v1 hierarchies used."""
VIEW_TASKS = 72
"""Processes and threads of one view together (``pids.max``): the student's
:data:`doorlab.pset.isolation.sandbox.PROCESS_LIMIT` (64), the view's first process and its threads,
bubblewrap."""
VIEW_MEMORY_BYTES = 3 << 30
"""The most one view's processes may hold together, its tmpfs included (``memory.max``)
[bytes]: one student process may map 2 GiB (its address-space limit); the view's first
process holds pydrake. Each grading's is :mod:`doorlab.pset.isolation.memory`'s plan, at most
this."""
TRUSTED_MEMORY_FLOOR = 256 << 20
"""cgroup v2: memory of a grading's trusted processes never reclaimed for others
(``memory.min``) [bytes]."""
TRUSTED_WEIGHT = 400
"""CPU weight of a grading's trusted processes (cgroup v2's scale, 100 the default; v1's
``cpu.shares`` is 10.24 times it)."""
DEFAULT_WEIGHT = 100
"""CPU weight of a grading, and of a view in it."""
PREFIX = "doorlab-"
"""Name of a grading's group: ``doorlab-<supervisor pid>-<n>``."""
KILL_TIMEOUT_S = 10.0
"""How long emptying a group may take [s]."""

_counter = itertools.count()


class CgroupError(Exception):
    """A cgroup could not be made or set (the message says which file and why)."""


@dataclass(frozen=True)
class Cgroups:
    """Where a grader may make its groups (JSON-ready: decided once, in the supervisor).

    Attributes:
        version: 1 or 2; None: no cgroup.
        bases: The folders below which groups are made: one per controller (v1: ``cpu``,
            ``cpuacct``, ``memory``, ``pids``), or ``{"unified": folder}`` (v2).
        reason: Why there is none (empty when there is).
    """

    version: int | None
    bases: dict = field(default_factory=dict)
    reason: str = ""

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> Cgroups:
        return cls(**json.loads(text))

    def describe(self, view_memory_bytes: int = VIEW_MEMORY_BYTES) -> dict:
        """What the results say (``extra_data.sandbox.cgroup``)."""
        if self.version is None:
            return {"version": None, "why_none": self.reason}
        return {
            "version": self.version,
            "view_tasks": VIEW_TASKS,
            "view_memory_bytes": int(view_memory_bytes),
            "trusted_cpu_weight": TRUSTED_WEIGHT,
        }


# What is mounted ---------------------------------------------------------------------------


def _mounts() -> list[tuple[str, str, set[str]]]:
    """(mount point, file system type, its super options) of every cgroup mount."""
    out = []
    try:
        lines = Path("/proc/self/mountinfo").read_text().splitlines()
    except OSError:
        return out
    for line in lines:
        left, _, right = line.partition(" - ")
        fields, tail = left.split(), right.split()
        if len(fields) < 5 or len(tail) < 3 or tail[0] not in ("cgroup", "cgroup2"):
            continue
        point = fields[4].replace("\\040", " ")
        out.append((point, tail[0], set(tail[2].split(","))))
    return out


def _own_paths() -> dict[str, str]:
    """This process's cgroup path per v1 controller, and ``""`` for v2 (``/proc/self/cgroup``)."""
    out = {}
    try:
        lines = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        return out
    for line in lines:
        number, _, rest = line.partition(":")
        names, _, path = rest.partition(":")
        if number == "0" and names == "":
            out[""] = path
        for name in names.split(","):
            if name:
                out[name] = path
    return out


def _join(point: str, path: str) -> Path:
    return Path(point) / path.lstrip("/")


def _read(path: Path) -> str:
    try:
        return path.read_text()
    except OSError:
        return ""


def _writable(folder: Path) -> bool:
    return folder.is_dir() and os.access(folder, os.W_OK | os.X_OK)


def probe() -> Cgroups:
    """Where this process may make a grading's groups (see the module), or why nowhere."""
    mounts, own = _mounts(), _own_paths()
    unified = next((m for m in mounts if m[1] == "cgroup2"), None)
    v1 = {c: m for m in mounts if m[1] == "cgroup" for c in V1_CONTROLLERS if c in m[2]}
    if unified is not None and "" in own:
        base = _join(unified[0], own[""])
        available = set(_read(base / "cgroup.controllers").split())
        if set(NEEDED) <= available or not v1:
            return _probe_v2(unified[0], own[""])
    if not v1:
        return Cgroups(None, reason="no cgroup file system is mounted (/sys/fs/cgroup)")
    missing = [c for c in V1_CONTROLLERS if c not in v1]
    if missing:
        return Cgroups(None, reason=f"cgroup v1 without the {', '.join(missing)} controller")
    bases = {c: str(_join(v1[c][0], own.get(c, "/"))) for c in V1_CONTROLLERS}
    closed = [b for b in bases.values() if not _writable(Path(b))]
    if closed:
        return Cgroups(None, reason=f"cgroup v1: {closed[0]} may not be written by this user")
    return Cgroups(1, bases)


def _probe_v2(point: str, path: str) -> Cgroups:
    own = _join(point, path)
    if path in ("", "/"):
        candidates = [own]  # the hierarchy's (or the namespace's) root
    else:
        candidates = [own.parent]  # a delegated parent: our groups beside our own
    for base in candidates:
        if not _writable(base):
            continue
        control = set(_read(base / "cgroup.subtree_control").split())
        missing = [c for c in NEEDED if c not in control]
        if missing:
            try:
                (base / "cgroup.subtree_control").write_text(" ".join(f"+{c}" for c in missing))
            except OSError:
                continue
        return Cgroups(2, {"unified": str(base)})
    return Cgroups(
        None,
        reason=(
            f"cgroup v2: neither {own} (the grader's own) nor the cgroup above it delegates "
            f"{', '.join(NEEDED)} to a cgroup this user may create"
        ),
    )


# A group ------------------------------------------------------------------------------------


class Group:
    """One cgroup: a folder per controller hierarchy (v1) or one folder (v2)."""

    def __init__(self, cgroups: Cgroups, folders: dict[str, Path]):
        self.cgroups = cgroups
        self.folders = folders
        self.version = cgroups.version
        self.memory_limit: int | None = None  # what set_memory set [bytes]

    @property
    def name(self) -> str:
        return next(iter(self.folders.values())).name

    def _folder(self, controller: str) -> Path:
        return self.folders["unified" if self.version == 2 else controller]

    def _write(self, controller: str, name: str, value: str) -> None:
        path = self._folder(controller) / name
        try:
            path.write_text(value)
        except OSError as e:
            raise CgroupError(f"cannot write {value!r} to {path}: {e.strerror or e}") from None

    def child(self, name: str, *, holds_groups: bool = False) -> Group:
        """A new group below this one (made now). ``holds_groups``: it will hold groups, not
        processes (v2: its children get the controllers; a v2 group cannot have both)."""
        folders = {k: v / name for k, v in self.folders.items()}
        for folder in dict.fromkeys(folders.values()):
            try:
                folder.mkdir()
            except OSError as e:
                raise CgroupError(f"cannot make {folder}: {e.strerror or e}") from None
        group = Group(self.cgroups, folders)
        if self.version == 2 and holds_groups:
            control = " ".join(f"+{c}" for c in NEEDED)
            try:
                (folders["unified"] / "cgroup.subtree_control").write_text(control)
            except OSError as e:
                group.remove()
                raise CgroupError(f"cannot delegate {control} below {group.name}: {e}") from None
        return group

    # Limits -------------------------------------------------------------------------------

    def set_cpu_weight(self, weight: int) -> None:
        """The group's share of the CPU against its siblings (v2's scale: 100 the default)."""
        if self.version == 2:
            self._write("cpu", "cpu.weight", str(int(weight)))
        else:
            self._write("cpu", "cpu.shares", str(max(2, round(weight * 1024 / 100))))

    def set_tasks(self, count: int) -> None:
        """At most ``count`` processes and threads in the group at once (``pids.max``)."""
        self._write("pids", "pids.max", str(int(count)))

    def set_memory(self, limit: int) -> None:
        """At most ``limit`` bytes of memory (pages, tmpfs included) and no swap."""
        if self.version == 2:
            self._write("memory", "memory.max", str(int(limit)))
            if (self._folder("memory") / "memory.swap.max").exists():
                self._write("memory", "memory.swap.max", "0")
            if (self._folder("memory") / "memory.oom.group").exists():
                # Out of memory, the kernel ends the group's processes together: whichever
                # holds the memory (a memfd's holder is in no resident set) goes too.
                self._write("memory", "memory.oom.group", "1")
        else:
            self._write("memory", "memory.limit_in_bytes", str(int(limit)))
            if (self._folder("memory") / "memory.memsw.limit_in_bytes").exists():
                self._write("memory", "memory.memsw.limit_in_bytes", str(int(limit)))
        self.memory_limit = int(limit)

    def protect_memory(self, floor: int) -> None:
        """cgroup v2: the group's first ``floor`` bytes are not reclaimed for others
        (``memory.min``; best effort: v1 has no such protection)."""
        if self.version == 2 and (self._folder("memory") / "memory.min").exists():
            try:
                self._write("memory", "memory.min", str(int(floor)))
            except CgroupError:
                pass

    # What it used --------------------------------------------------------------------------

    def cpu_seconds(self) -> float | None:
        """CPU time used by the group's processes since it was made [s] (those gone too)."""
        if self.version == 2:
            for line in _read(self._folder("cpu") / "cpu.stat").splitlines():
                key, _, value = line.partition(" ")
                if key == "usage_usec":
                    return int(value) * 1e-6
            return None
        text = _read(self._folder("cpuacct") / "cpuacct.usage").strip()
        return int(text) * 1e-9 if text.isdigit() else None

    def oom_kills(self) -> int:
        """Processes of the group the kernel killed for want of memory."""
        if self.version == 2:
            name = "memory.events"
        else:
            name = "memory.oom_control"
        for line in _read(self._folder("memory") / name).splitlines():
            key, _, value = line.partition(" ")
            if key == "oom_kill" and value.strip().isdigit():
                return int(value)
        return 0

    def pids(self) -> set[int]:
        """Every process in the group (and, v1, in none of its children)."""
        out: set[int] = set()
        for folder in dict.fromkeys(self.folders.values()):
            out |= {int(p) for p in _read(folder / "cgroup.procs").split() if p.isdigit()}
        return out

    # Joining ------------------------------------------------------------------------------

    def join(self, pid: int | None = None) -> None:
        """Moves process ``pid`` (default: this one) into the group."""
        value = str(os.getpid() if pid is None else pid)
        for folder in dict.fromkeys(self.folders.values()):
            try:
                (folder / "cgroup.procs").write_text(value)
            except OSError as e:
                raise CgroupError(f"cannot move {value} into {folder}: {e.strerror or e}") from None

    def join_descriptors(self) -> list[int]:
        """Its ``cgroup.procs`` files opened for writing (close-on-exec): a child between
        fork and exec writes its pid to each (:func:`join_by_descriptors`), so everything it
        starts is in the group from its first instruction."""
        fds = []
        try:
            for folder in dict.fromkeys(self.folders.values()):
                fds.append(os.open(folder / "cgroup.procs", os.O_WRONLY | os.O_CLOEXEC))
        except OSError as e:
            for fd in fds:
                os.close(fd)
            raise CgroupError(f"cannot open {folder / 'cgroup.procs'}: {e.strerror}") from None
        return fds

    # Ending -------------------------------------------------------------------------------

    def kill(self, timeout: float = KILL_TIMEOUT_S) -> None:
        """SIGKILLs every process in the group and below, until none is left."""
        deadline = time.monotonic() + timeout
        while True:
            pids = set().union(*(g.pids() for g in self._tree()))
            if not pids or time.monotonic() > deadline:
                return
            for pid in pids:
                try:
                    os.kill(pid, signal.SIGKILL)
                except OSError:
                    pass
            time.sleep(0.005)

    def _tree(self) -> list[Group]:
        """This group and every group below it, deepest first."""
        out = []
        for folder in dict.fromkeys(self.folders.values()):
            for path in sorted(folder.rglob("*"), key=lambda p: -len(p.parts)):
                if path.is_dir():
                    out.append(Group(self.cgroups, {"_": path}))
        return [*out, self]

    def remove(self) -> None:
        """Kills what is left in the group, then removes it and every group below it."""
        self.kill()
        for group in self._tree():
            for folder in dict.fromkeys(group.folders.values()):
                try:
                    folder.rmdir()
                except OSError:
                    pass


def join_by_descriptors(fds: list[int]) -> None:
    """Between fork and exec: writes this process's pid to each of ``fds``
    (:meth:`Group.join_descriptors`; no allocation beyond the pid's text)."""
    value = str(os.getpid()).encode()
    for fd in fds:
        os.write(fd, value)


# A grading's groups ---------------------------------------------------------------------------


class GradingGroups:
    """A grading's group ``G`` and its ``trusted`` group (see the module); the views' groups
    are made as the views start (:meth:`view`).

    Raises:
        CgroupError: A group could not be made or set.
    """

    def __init__(self, cgroups: Cgroups, view_memory_bytes: int = VIEW_MEMORY_BYTES):
        self.cgroups = cgroups
        self.view_memory_bytes = int(view_memory_bytes)
        _remove_stale(cgroups)
        name = f"{PREFIX}{os.getpid()}-{next(_counter)}"
        base = Group(cgroups, {k: Path(v) for k, v in cgroups.bases.items()})
        self.grading = base.child(name, holds_groups=True)
        try:
            self.grading.set_cpu_weight(DEFAULT_WEIGHT)
            self.trusted = self.grading.child("trusted")
            self.trusted.set_cpu_weight(TRUSTED_WEIGHT)
            self.trusted.protect_memory(TRUSTED_MEMORY_FLOOR)
        except CgroupError:
            self.grading.remove()
            raise
        self.views: dict[str, Group] = {}

    def student(self, key: str) -> Group:
        """A new group for a student's view or process: its tasks, memory and CPU weight."""
        group = self.grading.child(key)
        group.set_cpu_weight(DEFAULT_WEIGHT)
        group.set_tasks(VIEW_TASKS)
        group.set_memory(self.view_memory_bytes)
        self.views[key] = group
        return group

    def close(self) -> None:
        """Kills whatever is left in the grading's groups and removes them."""
        self.grading.remove()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove_stale(cgroups: Cgroups) -> None:
    """Removes the groups of gradings whose supervisor is gone (killed before it could)."""
    for base in dict.fromkeys(cgroups.bases.values()):
        try:
            names = [p for p in Path(base).iterdir() if p.name.startswith(PREFIX)]
        except OSError:
            continue
        for folder in names:
            pid = folder.name[len(PREFIX) :].split("-", 1)[0]
            if pid.isdigit() and not _alive(int(pid)):
                group = Group(cgroups, {"_": folder})
                group.version = cgroups.version
                group.remove()
