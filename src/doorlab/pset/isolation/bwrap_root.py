"""The student process's view of the machine: a minimal root built with bubblewrap (``bwrap``).

The student's code sees nothing it was not given. :func:`plan_view` lists what its root holds,
all read-only but three places:

- the system's ``/usr`` (libraries, no user data) and the top-level links into it (``/lib``,
  ``/bin``...), the dynamic loader's cache; the interpreter, its shared library and its
  standard library where they live elsewhere (pyenv's ``/root/.pyenv/...``), each alone;
- every ``site-packages`` or ``dist-packages`` folder inside those made empty, then only the
  distributions the student's code needs bound back at their own paths: drake, numpy,
  matplotlib and what they require (:data:`STUDENT_DISTRIBUTIONS`);
- doorlab's *student side*, a copy of just :data:`STUDENT_MODULES` and the models made for
  this grading (:func:`build_site`), at :data:`SITE_MOUNT`: none of the reference solutions,
  the templates or the grader's own modules exist in the view (:mod:`doorlab.pset.rules.verdicts`
  lists them);
- writable: the submission's scratch copy at :data:`SCRATCH_MOUNT` (its working directory;
  in a view, a tmpfs of :data:`SCRATCH_TMPFS_BYTES`), and a private ``/tmp`` and ``/dev/shm``
  of :data:`TMPFS_BYTES` each (tmpfs, gone with the process: their pages are charged to the
  memory of the view that writes them, so no student fills a disk that others share; bwrap
  older than 0.7 has no ``--size``: then three folders of the job's scratch, on its disk);
- a fresh ``/proc`` of its own PID namespace (it sees its own processes only) and ``/dev``.

Not there: ``/home``, ``/root``, ``/srv``, ``/autograder``, the clone and its ``.git``, the
grader's working folders, other submissions, the grader's venv beyond those distributions.
The process also gets its own IPC, UTS, network (loopback only) and PID namespaces, a new
session, a system-call filter (:mod:`doorlab.pset.isolation.seccomp`: no namespace, mount, keyring
or BPF of its own), and dies with its parent. As root, bwrap runs without a user namespace (no
capability but CAP_SETUID and CAP_SETGID) and the worker's first statement switches to the
sandbox user (:func:`doorlab.pset.isolation.sandbox.sandbox_identity`) for good; as an ordinary
user, bwrap maps that user into a user namespace in which no further one can be made.

Where bwrap cannot build the view (not installed; no unprivileged user namespaces; a
container that refuses namespaces), :func:`probe` says why, before any student code runs.
"""

from __future__ import annotations

import compileall
import importlib.metadata as metadata
import json
import os
import re
import shutil
import site
import subprocess
import sys
import sysconfig
from dataclasses import asdict, dataclass
from functools import cache
from pathlib import Path

BWRAP_ENV = "DOORLAB_BWRAP"
"""Environment variable naming the bwrap program (default: ``bwrap`` on PATH, else
``/usr/bin/bwrap``)."""
SITE_MOUNT = "/doorlab-site"
"""Where doorlab's student side appears in the view."""
SCRATCH_MOUNT = "/pset"
"""Where the submission's scratch copy appears in the view (the working directory)."""
SUBMISSION_MOUNT = "/doorlab-submission"
"""Where a view (:mod:`doorlab.pset.isolation.student_view`) sees the grader's copies of the
submission, read-only: its first process copies a test's into :data:`SCRATCH_MOUNT`, a sized
tmpfs, before it forks the test's process."""
SCRATCH_TMPFS_BYTES = 64 << 20
"""Size of a view's :data:`SCRATCH_MOUNT` tmpfs [bytes] (a problem-set folder is ~70 kB; what
the student's code writes there is bounded by it, in the view's memory, never on a disk)."""
TMPFS_BYTES = 64 << 20
"""Size of the view's ``/tmp`` and of its ``/dev/shm`` [bytes] each (RAM the address-space
limit does not count: bounded here)."""
PROBE_TIMEOUT_S = 30.0
"""How long the probe of the view may take [s] (it starts one interpreter)."""

STUDENT_MODULES = (
    "doorlab",
    "doorlab.cell",
    "doorlab.cell.door_model",
    "doorlab.cell.frames",
    "doorlab.cell.models",
    "doorlab.cell.station",
    "doorlab.config",
    "doorlab.config_checks",
    "doorlab.constants",
    "doorlab.control",
    "doorlab.control.ik",
    "doorlab.errors",
    "doorlab.kuka",
    "doorlab.pset",
    "doorlab.pset.handout",
    "doorlab.pset.handout.station_api",
    "doorlab.pset.handout.task_helpers",
    "doorlab.pset.isolation",
    "doorlab.pset.isolation.channel",
    "doorlab.pset.isolation.guard",
    "doorlab.pset.isolation.worker",
    "doorlab.pset.isolation.zygote",
    "doorlab.runtime",
    "doorlab.runtime.drake_compat",
    "doorlab.runtime.inputs",
)
"""doorlab's modules in the student's view: what the folder's files and the worker import, and
the packages that hold them (their ``__init__``, docstrings only). Nothing else of doorlab is
there (a test checks that none is a reference solution)."""
STUDENT_DATA = ("doorlab/cell/models",)
"""Package folders copied whole (the SDF models)."""
STUDENT_DISTRIBUTIONS = ("drake", "numpy", "matplotlib")
"""Distributions in the view, with everything they require."""
SYSTEM_TREES = ("/usr",)
"""System folders bound whole (read-only)."""
TOP_LINKS = ("/bin", "/sbin", "/lib", "/lib32", "/lib64", "/libx32")
"""Top-level folders, links into /usr on merged-/usr systems."""
ETC_FILES = ("/etc/ld.so.cache", "/etc/ld.so.conf", "/etc/ld.so.conf.d", "/etc/localtime")
"""What the dynamic loader and the C library read from /etc."""


# doorlab's student side -----------------------------------------------------------------


def _package_dir() -> Path:
    import doorlab

    return Path(doorlab.__file__).resolve().parent


def student_files(package_dir: Path | None = None) -> list[str]:
    """The student side's files, relative to the package's parent (``doorlab/...``)."""
    package_dir = package_dir or _package_dir()
    out = []
    for name in STUDENT_MODULES:
        rel = Path(*name.split("."))
        if (package_dir.parent / rel).is_dir():
            out.append(str(rel / "__init__.py"))
        else:
            out.append(str(rel) + ".py")
    for folder in STUDENT_DATA:
        for path in sorted((package_dir.parent / folder).rglob("*")):
            if path.is_file() and "__pycache__" not in path.parts and path.suffix != ".pyc":
                out.append(str(path.relative_to(package_dir.parent)))
    return sorted(set(out))


def build_site(dest: Path) -> Path:
    """Copies doorlab's student side into ``dest`` (new; folders 0755, files 0644) and
    compiles it (the student's process writes no bytecode); returns ``dest``."""
    package_dir = _package_dir()
    dest.mkdir(mode=0o755)
    os.chmod(dest, 0o755)
    for rel in student_files(package_dir):
        target = dest / rel
        for parent in reversed(target.relative_to(dest).parents[:-1]):
            folder = dest / parent
            if not folder.is_dir():
                folder.mkdir(mode=0o755)
                os.chmod(folder, 0o755)
        shutil.copyfile(package_dir.parent / rel, target)
        os.chmod(target, 0o644)
    compileall.compile_dir(dest, quiet=2, workers=1)
    for path in dest.rglob("*"):
        os.chmod(path, 0o755 if path.is_dir() else 0o644)
    return dest


# The distributions ------------------------------------------------------------------------

_NAME = re.compile(r"^\s*([A-Za-z0-9][A-Za-z0-9._-]*)")


def _required(dist: metadata.Distribution) -> list[str]:
    names = []
    for req in dist.requires or []:
        if "extra ==" in req.replace(" ", "").replace("extra==", "extra =="):
            continue
        match = _NAME.match(req)
        if match:
            names.append(match.group(1))
    return names


def distribution_entries(names=STUDENT_DISTRIBUTIONS) -> list[str]:
    """Real paths of the top-level files and folders (packages, their ``.libs`` and
    ``.dist-info``) of the distributions ``names`` and of everything they require (those
    installed)."""
    seen: set[str] = set()
    todo = list(names)
    entries: set[str] = set()
    while todo:
        name = todo.pop()
        key = re.sub(r"[-_.]+", "-", name).lower()
        if key in seen:
            continue
        seen.add(key)
        try:
            dist = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            continue
        todo.extend(_required(dist))
        tops = {line.split(",", 1)[0].split("/", 1)[0] for line in _record(dist).splitlines()}
        for top in tops:
            if top in ("..", "", "__pycache__"):
                continue
            path = Path(dist.locate_file(top))
            if path.exists():
                entries.add(os.path.realpath(path))
    return sorted(entries)


def _record(dist: metadata.Distribution) -> str:
    """The distribution's file list (RECORD; an egg's SOURCES.txt), as text."""
    return dist.read_text("RECORD") or dist.read_text("SOURCES.txt") or ""


# The plan ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class View:
    """How to build the view (JSON-ready: the supervisor plans once, each job reads it).

    Attributes:
        bwrap: The bwrap program. python: The interpreter (a real file, same path inside).
        mounts: ``["dir", dest]``, ``["ro", src, dest]``, ``["tmpfs", dest]`` and
            ``["symlink", target, dest]`` operations in order.
        sys_path: The student process's ``sys.path`` after the standard library.
        site: The student side's folder (outside).
        sized_tmpfs: bwrap has ``--size``.
    """

    bwrap: str
    python: str
    mounts: tuple
    sys_path: tuple
    site: str
    sized_tmpfs: bool

    @property
    def private_tops(self) -> list[str]:
        """The folders right under the private ``/tmp`` and ``/dev/shm`` on the way to a
        distribution bound from there (a venv made under /tmp): each a read-only tmpfs of its
        own, so nothing on the way is made in those writable places. Usually none."""
        private = ("/tmp", "/dev/shm")
        return sorted(
            {
                "/".join(op[1].split("/")[: p.count("/") + 2])
                for op in self.mounts
                if op[0] == "dir"
                for p in private
                if op[1].startswith(p + "/")
            }
        )

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> View:
        data = json.loads(text)
        data["mounts"] = tuple(tuple(m) for m in data["mounts"])
        data["sys_path"] = tuple(data["sys_path"])
        return cls(**data)


def find_bwrap() -> str | None:
    """The bwrap program to use, or None (``$DOORLAB_BWRAP``, else PATH, else /usr/bin)."""
    wanted = os.environ.get(BWRAP_ENV, "").strip()
    if wanted:
        return wanted if os.access(wanted, os.X_OK) and os.path.isfile(wanted) else None
    return shutil.which("bwrap") or (
        "/usr/bin/bwrap" if os.access("/usr/bin/bwrap", os.X_OK) else None
    )


@cache
def _has_size_option(bwrap: str) -> bool:
    try:
        text = subprocess.run(
            [bwrap, "--help"], capture_output=True, text=True, timeout=10, check=False
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return False
    return "--size" in text


def _inside(path: str, roots) -> bool:
    return any(path == r or path.startswith(r.rstrip("/") + "/") for r in roots)


def _site_folders() -> list[str]:
    """Every site-packages / dist-packages folder of this interpreter, of its base, and of
    the system's Pythons (where ``sudo pip`` installs), and doorlab's own package folder."""
    folders = set(site.getsitepackages([sys.base_prefix, sys.base_exec_prefix]))
    folders.update(site.getsitepackages())
    folders.update(p for p in sys.path if p.endswith(("site-packages", "dist-packages")))
    for tree in SYSTEM_TREES:
        for pattern in ("lib*/python3*/*-packages", "local/lib*/python3*/*-packages"):
            folders.update(str(p) for p in Path(tree).glob(pattern))
    folders.add(str(_package_dir()))
    return sorted({os.path.realpath(f) for f in folders if os.path.isdir(f)})


def plan_view(site_dir: Path, bwrap: str) -> View:
    """The view of a student process (see the module's docstring)."""
    python = os.path.realpath(sys.executable)
    ro: list[tuple[str, str]] = []
    mounts: list[list[str]] = []
    for tree in SYSTEM_TREES:
        if os.path.isdir(tree):
            ro.append((tree, tree))
    for top in TOP_LINKS:
        if os.path.islink(top):
            mounts.append(["symlink", os.readlink(top), top])
        elif os.path.isdir(top):
            ro.append((top, top))
    ro.extend((f, f) for f in ETC_FILES if os.path.exists(f))
    bound = [dest for _, dest in ro]
    # The interpreter's own library folder whole where it is not the system's (pyenv's,
    # conda's: libpython and the libraries its modules link to; its site-packages is
    # emptied below), then the standard library if it lives elsewhere still.
    libdir = sysconfig.get_config_var("LIBDIR") or ""
    extra = [python]
    if libdir and os.path.isdir(libdir):
        extra.append(os.path.realpath(libdir))
    extra += [os.path.realpath(sysconfig.get_paths()["stdlib"]), os.path.dirname(os.__file__)]
    for path in extra:
        if not _inside(path, bound):
            ro.append((path, path))
            bound.append(path)
    covers = [f for f in _site_folders() if _inside(f, bound)]
    entries = distribution_entries()
    sys_path = sorted({os.path.dirname(e) for e in entries if not e.endswith(".dist-info")})
    later = [(e, e) for e in entries]
    dests = [d for _, d in ro] + covers + [d for _, d in later] + [SITE_MOUNT, SCRATCH_MOUNT]
    dirs = sorted(
        {
            str(parent)
            for dest in dests
            for parent in Path(dest).parents
            if str(parent) != "/" and not _inside(str(parent), bound + covers)
        },
        key=lambda p: (p.count("/"), p),
    )
    ops = [["dir", d] for d in dirs] + mounts
    ops += [["ro", src, dest] for src, dest in ro]
    ops += [["tmpfs", c] for c in sorted(covers, key=lambda p: (p.count("/"), p))]
    ops += [["ro", src, dest] for src, dest in later]
    ops.append(["ro", str(site_dir), SITE_MOUNT])
    return View(
        bwrap=bwrap,
        python=python,
        mounts=tuple(tuple(op) for op in ops),
        sys_path=tuple(sys_path),
        site=str(site_dir),
        sized_tmpfs=_has_size_option(bwrap),
    )


# The command ------------------------------------------------------------------------------


def boot_code(view: View, drop: tuple[int, int] | None) -> str:
    """The student interpreter's first statements (``python -I -S -c``): switch to the
    sandbox user for good (``drop``: uid, gid, when bwrap runs as root), enter the scratch
    copy, then set ``sys.path``: the student side first, the standard library, the
    distributions."""
    lines = ["import os, sys"]
    if drop is not None:
        uid, gid = drop
        lines += [
            "os.setgroups([])",
            f"os.setresgid({gid}, {gid}, {gid})",
            f"os.setresuid({uid}, {uid}, {uid})",
        ]
    lines += [
        # After the switch: the scratch copy is its user's alone (bwrap, root without
        # CAP_DAC_OVERRIDE, could not enter it).
        f"os.chdir({SCRATCH_MOUNT!r})",
        f"sys.path[:0] = [{SITE_MOUNT!r}]",
        f"sys.path += {list(view.sys_path)!r}",
    ]
    return "\n".join(lines)


def worker_code(view: View, drop: tuple[int, int] | None) -> str:
    """:func:`boot_code`, then :func:`doorlab.pset.isolation.worker.main` on the arguments."""
    run = "from doorlab.pset.isolation.worker import main\nsys.exit(main(sys.argv[1:]))"
    return boot_code(view, drop) + "\n" + run


def zygote_code(view: View, drop: tuple[int, int] | None) -> str:
    """:func:`boot_code`, then :func:`doorlab.pset.isolation.zygote.main` on the arguments."""
    run = "from doorlab.pset.isolation.zygote import main\nsys.exit(main(sys.argv[1:]))"
    return boot_code(view, drop) + "\n" + run


def bwrap_argv(
    view: View,
    scratch: Path,
    tmp_dirs: tuple[Path, Path] | None,
    *,
    as_root: bool,
    as_pid_1: bool = False,
    seccomp_fd: int | None = None,
    scratch_tmpfs: bool = False,
) -> list[str]:
    """bwrap and its options up to (not including) the command.

    Args:
        view: The plan. scratch: The submission's scratch copy (bound writable).
        tmp_dirs: Folders for /tmp and /dev/shm when bwrap cannot size a tmpfs (else None).
        as_root: bwrap runs as root (no user namespace; the command drops to the sandbox
            user itself).
        as_pid_1: The command is the PID namespace's init (no reaper of bwrap's; the
            command reaps, and signals from inside reach it only where it handles them).
        seccomp_fd: A descriptor holding the system-call filter
            (:func:`doorlab.pset.isolation.seccomp.filter_descriptor`), passed to the command: bwrap
            applies it to the command and everything it starts.
        scratch_tmpfs: :data:`SCRATCH_MOUNT` is a tmpfs of :data:`SCRATCH_TMPFS_BYTES` and
            ``scratch`` is bound read-only at :data:`SUBMISSION_MOUNT` (a view: its first process
            copies each test's folder over), where bwrap can size a tmpfs; else ``scratch`` is
            bound writable at :data:`SCRATCH_MOUNT`.
    """
    argv = [view.bwrap, "--die-with-parent", "--new-session"]
    if seccomp_fd is not None:
        argv += ["--seccomp", str(seccomp_fd)]
    if as_pid_1:
        argv.append("--as-pid-1")
    if as_root:
        argv += ["--unshare-ipc", "--unshare-pid", "--unshare-net", "--unshare-uts"]
        argv += ["--unshare-cgroup-try", "--cap-drop", "ALL"]
        argv += ["--cap-add", "CAP_SETUID", "--cap-add", "CAP_SETGID"]
    else:
        argv += ["--unshare-all", "--unshare-user", "--disable-userns"]
    argv += ["--hostname", "sandbox"]
    # /proc, /dev and the private /tmp and /dev/shm first, so that a distribution bound from
    # under /tmp (a venv made there) lands on top of the private /tmp, not under it.
    argv += ["--proc", "/proc", "--dev", "/dev"]
    for dest, folder in zip(("/tmp", "/dev/shm"), tmp_dirs or (None, None), strict=True):
        if folder is None:
            argv += ["--size", str(TMPFS_BYTES), "--perms", "1777", "--tmpfs", dest]
        else:
            argv += ["--bind", str(folder), dest]
    # Folders on the way to a distribution bound from under /tmp or /dev/shm would be made in
    # those writable places: each such top folder is a tmpfs of its own, read-only at the end.
    tops = view.private_tops
    for top in tops:
        argv += ["--tmpfs", top]
    for op in view.mounts:
        kind = op[0]
        if kind == "dir":
            argv += ["--dir", op[1]]
        elif kind == "ro":
            argv += ["--ro-bind", op[1], op[2]]
        elif kind == "tmpfs":
            argv += ["--tmpfs", op[1]]
        elif kind == "symlink":
            argv += ["--symlink", op[1], op[2]]
    if scratch_tmpfs and tmp_dirs is None:
        argv += ["--size", str(SCRATCH_TMPFS_BYTES), "--perms", "1777", "--tmpfs", SCRATCH_MOUNT]
        argv += ["--ro-bind", str(scratch), SUBMISSION_MOUNT, "--chdir", "/"]
    else:
        argv += ["--bind", str(scratch), SCRATCH_MOUNT, "--chdir", "/"]
    # The root itself (a tmpfs holding the mount points, the user's own in a user
    # namespace) read-only too: not recursive, so the three writable places stay writable.
    argv += ["--remount-ro", "/"]
    for top in tops:
        argv += ["--remount-ro", top]
    return [*argv, "--"]


PROBE = """
import ctypes, json
facts = {"uid": os.getuid(), "visible": [p for p in sys.argv[1:] if os.path.exists(p)]}
pid = os.fork()
if pid == 0:  # a user namespace of its own: the filter (or --disable-userns) refuses it
    os._exit(0 if ctypes.CDLL(None).unshare(0x10000000) == 0 else 1)
facts["userns"] = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]) == 0
print("PROBE " + json.dumps(facts))
"""


def probe(view: View, drop: tuple[int, int] | None, work: Path, forbidden=()) -> str | None:
    """Starts the view once with a tiny program, as a student process would start; returns
    None when it ran as planned, else why not (bwrap's own words, first line).

    Args:
        view: The plan. drop: See :func:`boot_code`. work: A private folder for the
            probe's scratch. forbidden: Paths that must not exist in the view (checked).
    """
    scratch = work / "probe_scratch"
    scratch.mkdir(exist_ok=True)
    if drop is not None:
        os.chown(scratch, drop[0], drop[1])
    tmp_dirs = None if view.sized_tmpfs else _tmp_dirs(work / "probe_tmp", drop)
    from doorlab.pset.isolation.seccomp import FilterError, filter_descriptor

    try:
        seccomp = filter_descriptor()
    except FilterError as e:
        return str(e)
    argv = bwrap_argv(view, scratch, tmp_dirs, as_root=drop is not None, seccomp_fd=seccomp)
    argv += [view.python, "-I", "-S", "-B", "-c", boot_code(view, drop) + "\n" + PROBE]
    argv += [str(p) for p in forbidden]
    try:
        proc = subprocess.run(
            argv,
            capture_output=True,
            text=True,
            timeout=PROBE_TIMEOUT_S,
            stdin=subprocess.DEVNULL,
            env={"PATH": "/usr/bin:/bin", "LANG": "C.UTF-8"},
            pass_fds=(seccomp,),
            check=False,
        )
    except (OSError, subprocess.SubprocessError) as e:
        return f"{view.bwrap}: {e}"
    finally:
        os.close(seccomp)
        shutil.rmtree(scratch, ignore_errors=True)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("PROBE ")]
    if proc.returncode != 0 or not lines:
        said = (proc.stderr.strip() or proc.stdout.strip()).splitlines()
        first = said[0] if said else f"exit code {proc.returncode}"
        return first[:300]
    facts = json.loads(lines[-1][len("PROBE ") :])
    if drop is not None and facts.get("uid") != drop[0]:
        return f"the probe ran as uid {facts.get('uid')}, not {drop[0]}"
    if facts.get("visible"):
        return f"the view shows what it must not: {facts['visible'][:3]}"
    if facts.get("userns"):
        return "the view lets the student's code make a user namespace (no filter held)"
    return None


def _tmp_dirs(base: Path, drop: tuple[int, int] | None) -> tuple[Path, Path]:
    """Two folders standing in for /tmp and /dev/shm (bwrap without ``--size``)."""
    out = []
    for name in ("tmp", "shm"):
        folder = base / name
        folder.mkdir(parents=True, exist_ok=True)
        os.chmod(folder, 0o1777)
        if drop is not None:
            os.chown(folder, drop[0], drop[1])
        out.append(folder)
    return out[0], out[1]


def job_tmp_dirs(view: View, base: Path, drop: tuple[int, int] | None):
    """The /tmp and /dev/shm folders of one job when bwrap cannot size a tmpfs, else None."""
    return None if view.sized_tmpfs else _tmp_dirs(base, drop)
