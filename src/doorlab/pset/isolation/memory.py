"""How much memory a student's view may hold, and whom the kernel ends when memory runs out.

Every byte a student's code can hold is charged to its view's cgroup
(:mod:`doorlab.pset.isolation.cgroups`): its processes' pages, its memfds and System V
segments (shared memory, charged to the group of the process that touches it first), its
``/tmp``, ``/dev/shm`` and ``/pset`` (sized tmpfs, :mod:`doorlab.pset.isolation.bwrap_root`: the
pages of a tmpfs are charged to the group of the process that writes them), the pipe
buffers it fills (kernel memory, charged to the writer's group), and it writes to no disk.
Two rules then decide who the kernel ends:

- **the views' limits fit in the room there is**: :func:`plan` divides the memory the grader
  finds (:func:`room`: the machine's available memory, or less where a cgroup above the
  grader, a container's or a service's, has a limit) between the views that run at once
  (``--jobs``), after :data:`GRADER_BYTES` for the grading command itself and
  :data:`GRADING_BYTES` per grading at once for its trusted side (its worker, supervisor and
  trusted processes: about 0.1 GiB each, measured). A view that reaches its limit is the
  only group out of memory: the kernel ends one of its processes, never another grading's,
  and the test is that submission's verdict ("your code's processes used more than N MiB
  together").
- **the student's processes go first anyway**: where the machine runs out for other
  reasons (another program; no cgroup to limit a view), the kernel's OOM killer ranks
  processes by their resident memory plus ``oom_score_adj``, and memory held in a memfd or a
  tmpfs is in no process's resident set. A view's processes get :data:`VIEW_OOM_SCORE_ADJ`
  (the view's first process) and :data:`STUDENT_OOM_SCORE_ADJ` (each test's process: the
  highest there is), set before their first instruction by the grader's root-owned code, so a
  student's code cannot lower them below the view's; the grader's own processes get
  :data:`TRUSTED_OOM_SCORE_ADJ` where it may lower it (root): a supervisor is never ranked
  before a student's process.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from doorlab.errors import ConfigError
from doorlab.pset.isolation.zygote import STUDENT_OOM_SCORE_ADJ

__all__ = ["STUDENT_OOM_SCORE_ADJ"]  # each test's student process's: the first the kernel ends

VIEW_MEMORY_MAX_BYTES = 3 << 30
"""The most a view's processes may hold together [bytes] (one student process may map 2 GiB,
its address-space limit; the view's first process holds pydrake's modules)."""
VIEW_MEMORY_MIN_BYTES = 384 << 20
"""The least a view is given [bytes]: an honest view holds about 60 MiB of its own (pydrake's
libraries are the page cache the grader loaded), its three tmpfs up to 192 MiB more."""
GRADER_BYTES = 256 << 20
"""Kept for the grading command's own process (``grade-all``'s, ``pset grade``'s) [bytes]."""
GRADING_BYTES = 384 << 20
"""Kept per grading at once for its trusted side: its worker, supervisor and trusted
processes [bytes] (two gradings and ``grade-all`` held about 0.2 GiB together, measured)."""
TRUSTED_OOM_SCORE_ADJ = -500
"""The grader's processes' ``oom_score_adj`` (-1000 to 1000; root only: a lower value needs
``CAP_SYS_RESOURCE``)."""
VIEW_OOM_SCORE_ADJ = 800
"""bubblewrap's and the view's first process's ``oom_score_adj`` (set as root, so the floor of
every process in the view)."""
UNLIMITED = 1 << 62
"""A cgroup limit at least this large is no limit (v1 writes 2^63 - 4096)."""


def verdict(limit: int) -> str:
    """A test's message when the kernel ended a process of its view for want of memory."""
    return (
        f"your code's processes used more than {limit >> 20} MiB {VERDICT_MARK}: its "
        "processes, its /tmp, /dev/shm and folder, its memfds and pipes): the kernel ended one"
    )


VERDICT_MARK = "of memory together (the limit of its view"
"""What :func:`verdict` says whatever the limit (the class's summary counts it)."""


def ended_for_memory(results: dict) -> list[str]:
    """The tests of a grading's results whose view the kernel ended for want of memory."""
    return [
        str(t.get("name"))
        for t in results.get("tests") or []
        if isinstance(t, dict) and VERDICT_MARK in str(t.get("output") or "")
    ]


class MemoryRoomError(ConfigError):
    """Too little memory for the views ``--jobs`` asks for (the message says how much)."""


def mib(value: int) -> str:
    """``value`` bytes as MiB, or as GiB (one decimal) from 1 GiB."""
    if value >= 1 << 30:
        return f"{value / (1 << 30):.1f} GiB"
    return f"{value >> 20} MiB"


# The room ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Room:
    """Memory the grader may use.

    Attributes:
        bytes: How much [bytes].
        where: Where that bound comes from (for the summary).
    """

    bytes: int
    where: str


def _read_int(path: Path) -> int | None:
    try:
        text = path.read_text().strip()
    except OSError:
        return None
    if text == "max":
        return UNLIMITED
    return int(text) if text.isdigit() else None


def _stat(path: Path) -> dict[str, int]:
    out = {}
    try:
        lines = path.read_text().splitlines()
    except OSError:
        return out
    for line in lines:
        key, _, value = line.partition(" ")
        if value.strip().isdigit():
            out[key] = int(value)
    return out


def _meminfo() -> dict[str, int]:
    """/proc/meminfo's fields [bytes]."""
    out = {}
    try:
        lines = Path("/proc/meminfo").read_text().splitlines()
    except OSError:
        return out
    for line in lines:
        key, _, rest = line.partition(":")
        parts = rest.split()
        if parts and parts[0].isdigit():
            out[key] = int(parts[0]) * (1024 if parts[1:] == ["kB"] else 1)
    return out


def _cgroup_rooms() -> list[Room]:
    """Each cgroup above this process (its own included) that has a memory limit: the limit
    less what the group holds but its reclaimable page cache."""
    from doorlab.pset.isolation.cgroups import _join, _mounts, _own_paths

    rooms = []
    own, mounts = _own_paths(), _mounts()
    v1 = next((m for m in mounts if m[1] == "cgroup" and "memory" in m[2]), None)
    v2 = next((m for m in mounts if m[1] == "cgroup2"), None)
    if v1 is not None and "memory" in own:
        folder, top = _join(v1[0], own["memory"]), Path(v1[0])
        names = ("memory.limit_in_bytes", "memory.usage_in_bytes", "total_inactive_file")
    elif v2 is not None and "" in own:
        folder, top = _join(v2[0], own[""]), Path(v2[0])
        names = ("memory.max", "memory.current", "inactive_file")
    else:
        return rooms
    while True:
        limit = _read_int(folder / names[0])
        if limit is not None and limit < UNLIMITED:
            used = _read_int(folder / names[1]) or 0
            used -= _stat(folder / "memory.stat").get(names[2], 0)
            where = "/" + str(folder.relative_to(top)).lstrip(".")
            rooms.append(Room(max(0, limit - max(0, used)), f"the cgroup {where}'s limit"))
        if folder == top or top not in folder.parents:
            return rooms
        folder = folder.parent


def room() -> Room:
    """The memory this grader may use: the machine's available memory (``MemAvailable``),
    or less where a cgroup above it has a limit (a container, a service, a test's group)."""
    info = _meminfo()
    available = info.get("MemAvailable", info.get("MemTotal", 0))
    rooms = [Room(available, "this machine's available memory"), *_cgroup_rooms()]
    return min(rooms, key=lambda r: r.bytes)


def dask_worker_room() -> Room | None:
    """Inside a Dask worker: its memory limit (Dask's share of its machine for it), when set."""
    try:
        from distributed import get_worker

        worker = get_worker()
    except (ImportError, ValueError):
        return None
    limit = getattr(getattr(worker, "memory_manager", None), "memory_limit", None)
    if not limit:
        return None
    return Room(int(limit), "this Dask worker's memory limit")


# The plan ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class MemoryPlan:
    """Each view's memory limit, and why.

    Attributes:
        view_bytes: Each view's limit (its cgroup's ``memory.max``) [bytes].
        views: Views at once. gradings: Gradings at once.
        room: The room found. kept: Kept for the grader's own processes [bytes].
        short: The room was too small for ``views`` views of :data:`VIEW_MEMORY_MIN_BYTES`.
    """

    view_bytes: int
    views: int
    gradings: int
    room: Room
    kept: int
    short: bool = False

    def line(self) -> str:
        """The summary's line."""
        text = (
            f"memory: each student's view at most {mib(self.view_bytes)} ({self.views} at "
            f"once; {mib(self.room.bytes)} free by {self.room.where}, {mib(self.kept)} of it "
            "kept for the grader's own processes)"
        )
        if self.short:
            text += "; less than the views need, so the kernel may end a view early"
        return text

    def to_dict(self) -> dict:
        return {
            "view_bytes": self.view_bytes,
            "views": self.views,
            "room_bytes": self.room.bytes,
            "room": self.room.where,
        }


def plan(
    views: int,
    gradings: int,
    *,
    own_bytes: int = GRADER_BYTES,
    found: Room | None = None,
    strict: bool = True,
    jobs_option: str = "--jobs",
) -> MemoryPlan:
    """Each view's memory limit when ``views`` views and ``gradings`` gradings run at once:
    what :func:`room` finds (or ``found``), less ``own_bytes`` and :data:`GRADING_BYTES` per
    grading, divided between the views, at most :data:`VIEW_MEMORY_MAX_BYTES`.

    Raises:
        MemoryRoomError: With ``strict``, less than :data:`VIEW_MEMORY_MIN_BYTES` per view
            (the message names how many views fit); without, the views get that least and
            the plan says so (``short``).
    """
    found = found or room()
    views, gradings = max(1, int(views)), max(1, int(gradings))
    kept = own_bytes + GRADING_BYTES * gradings
    each = (found.bytes - kept) // views
    if each >= VIEW_MEMORY_MIN_BYTES:
        view = min(VIEW_MEMORY_MAX_BYTES, each) >> 20 << 20
        return MemoryPlan(view, views, gradings, found, kept)
    if strict:
        per = GRADING_BYTES + VIEW_MEMORY_MIN_BYTES
        fits = max(0, (found.bytes - own_bytes) // per)
        advice = f"use {jobs_option} {fits}" if fits else "free some memory first"
        raise MemoryRoomError(
            f"{jobs_option} {views}: {views} student views of at least "
            f"{mib(VIEW_MEMORY_MIN_BYTES)} each and the grader's own processes need "
            f"{mib(kept + views * VIEW_MEMORY_MIN_BYTES)}, and {mib(found.bytes)} is free by "
            f"{found.where}; {advice}"
        )
    return MemoryPlan(VIEW_MEMORY_MIN_BYTES, views, gradings, found, kept, short=True)


# Who goes first -----------------------------------------------------------------------------


def set_oom_score_adj(value: int) -> bool:
    """Writes this process's ``oom_score_adj`` (inherited by what it starts); False where
    the kernel refuses (a value below the floor without ``CAP_SYS_RESOURCE``). Safe between
    fork and exec (no allocation beyond the value's text)."""
    try:
        fd = os.open("/proc/self/oom_score_adj", os.O_WRONLY)
    except OSError:
        return False
    try:
        os.write(fd, str(int(value)).encode())
        return True
    except OSError:
        return False
    finally:
        os.close(fd)


def protect_trusted() -> bool:
    """The grader's processes last in line for the OOM killer (:data:`TRUSTED_OOM_SCORE_ADJ`,
    where this user may lower it; every process it starts inherits it)."""
    try:
        current = int(Path("/proc/self/oom_score_adj").read_text())
    except (OSError, ValueError):
        return False
    if current <= TRUSTED_OOM_SCORE_ADJ:
        return True
    return set_oom_score_adj(TRUSTED_OOM_SCORE_ADJ)
