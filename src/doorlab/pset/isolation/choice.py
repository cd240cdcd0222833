"""How a grading isolates the student's code, decided once before any of it runs.

:func:`prepare` (in the supervisor, :mod:`doorlab.pset.grading.jobs`) tries the student's view
(:mod:`doorlab.pset.isolation.bwrap_root`: bubblewrap, a minimal read-only root) and returns the
:class:`Isolation` every job then uses. Where the view cannot be built, the *policy* decides:

- ``"require"`` (``doorlab pset grade``): no isolation, no grade: :class:`IsolationError`
  with one line saying what is missing and how to get it;
- ``"insecure"`` (``--insecure``): grade anyway, every result marked. As root, student code
  runs as the sandbox user (mode ``"uid"``) in network and IPC namespaces of its own
  (:data:`OWN_NAMESPACES`, where the machine allows them): it cannot write the grader's files
  nor reach the network, but can read whatever that user may; as an ordinary user it runs
  as that user (mode ``"none"``), which is refused when that user could change doorlab's
  installation (a student's code could then change the grader: :func:`writable_installation`);
- ``"autograder"`` (``run_autograder`` on Gradescope, whose containers may refuse
  namespaces): as root only, the separate user, after :func:`harden` made doorlab's
  reference and grader files, the autograder's source (its wheel) and the other given paths
  unreadable to that user; the results list what held;
- ``"self-check"`` (the folder's ``test_pset_5a.py``: a student grading their own work,
  with nobody to protect from it): as ``"insecure"``, without refusing.
"""

from __future__ import annotations

import json
import os
import pwd
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

from doorlab.pset.isolation import bwrap_root, cgroups, sandbox
from doorlab.pset.rules.verdicts import TEMPLATES, hidden_modules

POLICIES = ("require", "insecure", "autograder", "self-check")
"""What a grading does where the student's view cannot be built (see the module)."""
HOW_TO_ISOLATE = (
    "install bubblewrap (apt-get install bubblewrap) and grade as root or as a user allowed "
    "unprivileged user namespaces (or in a container that allows them)"
)


class IsolationError(Exception):
    """The student's code cannot be isolated as the policy requires (one line)."""


@dataclass(frozen=True)
class Isolation:
    """How every student process of a grading runs.

    Attributes:
        mode: ``"bwrap"`` (the view), ``"uid"`` (another user, no view), ``"none"`` (the
            grader's own user, no view).
        policy: The grading's policy (:data:`POLICIES`).
        identity: (name, uid, gid) of the user student code runs as (None: the grader's).
        view: The view's plan (:meth:`doorlab.pset.isolation.bwrap_root.View.to_json`), mode
            ``"bwrap"``.
        guard: What the worker's honesty guard refuses: ``{"modules": {...}, "paths": [...]}``.
        reason: Why there is no view (empty in mode ``"bwrap"``).
        hardened: What :func:`harden` made unreadable (the autograder's fallback).
        namespaces: :func:`~doorlab.pset.isolation.sandbox.unshare` flags each student process gets
            without the view (as root: its own network and IPC namespaces, where the machine
            allows them; else 0).
        cgroups: Where the grading's cgroups go
            (:meth:`doorlab.pset.isolation.cgroups.Cgroups.to_json`).
    """

    mode: str
    policy: str
    identity: tuple | None
    view: str | None
    guard: dict
    reason: str = ""
    hardened: list = field(default_factory=list)
    namespaces: int = 0
    cgroups: str | None = None

    @property
    def network_isolated(self) -> bool:
        """The student's code gets a network namespace of its own (loopback only): the view,
        or the separate user's own namespace; else it reaches the network (a cluster too)."""
        return self.mode == "bwrap" or bool(self.namespaces & sandbox.CLONE_NEWNET)

    def cgroup_setup(self):
        from doorlab.pset.isolation.cgroups import Cgroups

        return None if self.cgroups is None else Cgroups.from_json(self.cgroups)

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> Isolation:
        return cls(**json.loads(text))

    def user(self) -> sandbox.Identity | None:
        return None if self.identity is None else sandbox.Identity(*self.identity)

    def plan(self) -> bwrap_root.View | None:
        return None if self.view is None else bwrap_root.View.from_json(self.view)


def _module_file(name: str) -> Path | None:
    import importlib.util

    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None
    return Path(spec.origin).resolve() if spec is not None and spec.origin else None


def reference_paths() -> list[Path]:
    """The files and folders of :func:`~doorlab.pset.rules.verdicts.hidden_modules` (sources and
    their compiled files) and the templates folder (those that exist)."""
    out = []
    for name in hidden_modules():
        source = _module_file(name)
        if source is None:
            continue
        out.append(source)
        cache = source.parent / "__pycache__"
        if cache.is_dir():
            out.extend(sorted(cache.glob(f"{source.stem}.*.pyc")))
    package = _module_file(TEMPLATES[0])
    if package is not None:
        out.append(package.parent / TEMPLATES[1])
    return [p for p in out if p.exists()]


def guard_config() -> dict:
    """The worker's honesty guard's table (see :class:`doorlab.pset.isolation.guard.Guard`)."""
    return {"modules": hidden_modules(), "paths": [str(p) for p in reference_paths()]}


def prepare(workdir: Path, policy: str = "require", harden_paths: Sequence[str] = ()) -> Isolation:
    """The grading's isolation (builds the student side in ``workdir / "site"``).

    Raises:
        IsolationError: The policy refuses (see the module). OSError: No sandbox user.
    """
    if policy not in POLICIES:
        raise ValueError(f"policy must be one of {POLICIES}, got {policy!r}")
    identity = sandbox.sandbox_identity()
    user = None if identity is None else (identity.name, identity.uid, identity.gid)
    drop = None if identity is None else (identity.uid, identity.gid)
    guard = guard_config()
    groups = cgroups.probe().to_json()
    bwrap = bwrap_root.find_bwrap()
    if bwrap is None:
        reason = "bubblewrap (bwrap) is not installed"
    else:
        plan = bwrap_root.plan_view(bwrap_root.build_site(workdir / "site"), bwrap)
        forbidden = [*guard["paths"], str(Path(bwrap_root.__file__).resolve().parents[2])]
        reason = bwrap_root.probe(plan, drop, workdir, forbidden) or ""
        if not reason:
            return Isolation("bwrap", policy, user, plan.to_json(), guard, cgroups=groups)
    if policy == "require":
        raise IsolationError(
            f"cannot isolate the student's code: {reason}. To grade, {HOW_TO_ISOLATE}; "
            "--insecure grades without that isolation and marks the results so"
        )
    if identity is None:
        if policy == "autograder":
            raise IsolationError(
                f"cannot isolate the student's code ({reason}) and the autograder does not "
                "run as root, so it cannot fall back to another user"
            )
        writable = [] if policy == "self-check" else writable_installation()
        if writable:
            raise IsolationError(
                f"cannot isolate the student's code ({reason}), and --insecure would run it "
                f"as {_user_name()}, who can change doorlab's installation ({writable[0]} "
                f"is writable): {HOW_TO_ISOLATE}, or install doorlab where you cannot write"
            )
        return Isolation("none", policy, None, None, guard, reason, cgroups=groups)
    hardened = harden(harden_paths) if policy == "autograder" else []
    flags = own_namespaces()
    return Isolation("uid", policy, user, None, guard, reason, hardened, flags, groups)


OWN_NAMESPACES = sandbox.CLONE_NEWNET | sandbox.CLONE_NEWIPC
"""What the separate-user fallback (root, no view) gives each student process: a network
namespace (loopback only, down: no cluster, no grader's port reachable) and an IPC namespace
(its System V objects and POSIX message queues are gone with it)."""


def own_namespaces() -> int:
    """:data:`OWN_NAMESPACES` where a child of this (root) process may make them (a
    container's seccomp profile may refuse ``unshare``: then 0, and the results say so)."""
    pid = os.fork()
    if pid == 0:  # a throwaway child: the namespaces are its own
        code = 1
        try:
            sandbox.unshare(OWN_NAMESPACES)
            code = 0
        finally:
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    return OWN_NAMESPACES if os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0 else 0


def _user_name() -> str:
    try:
        return pwd.getpwuid(os.getuid()).pw_name
    except KeyError:
        return f"uid {os.getuid()}"


def writable_installation() -> list[str]:
    """doorlab's files and folders, and the folders on this interpreter's path, that this
    process's user may change (a ``.pth`` file in a site folder runs in every later Python)."""
    package = Path(bwrap_root.__file__).resolve().parents[2]
    candidates = [package, *sorted(package.rglob("*"))]
    candidates += [Path(p) for p in __import__("sys").path if p and os.path.isdir(p)]
    return [str(p) for p in candidates if os.access(p, os.W_OK)]


def harden(extra: Sequence[str]) -> list[str]:
    """The autograder's fallback without a view (root only; Gradescope's container is thrown
    away after the grading): every file of the installed doorlab that is not on the student
    side (:data:`doorlab.pset.isolation.bwrap_root.STUDENT_MODULES`) becomes root's alone (0600,
    folders holding no student file 0700; compiled files follow their source's mode), and so do the
    ``extra`` paths (the autograder's source with its wheel, the results, the submission's
    metadata). Returns what it made unreadable."""
    package = Path(bwrap_root.__file__).resolve().parents[2]
    student = set(bwrap_root.student_files(package))
    keep_dirs = {str(Path(rel).parent) for rel in student}
    keep_dirs |= {str(p) for rel in student for p in Path(rel).parents}
    hidden = 0
    for path in sorted(package.rglob("*"), key=lambda p: -len(p.parts)):
        rel = path.relative_to(package.parent)
        if path.is_symlink():
            continue
        if path.is_dir():
            if path.name == "__pycache__" or str(rel) in keep_dirs:
                continue
            os.chmod(path, 0o700)
        elif str(_source_of(rel)) not in student:
            os.chmod(path, 0o600)
            hidden += 1
    out = [f"{hidden} files of doorlab's reference solutions and grader ({package})"]
    for name in extra:
        path = Path(name)
        if path.exists() and not path.is_symlink():
            os.chmod(path, 0o700 if path.is_dir() else 0o600)
            out.append(str(path))
    return out


def _source_of(rel: Path) -> Path:
    """The source a compiled file in ``__pycache__`` belongs to (else ``rel`` itself)."""
    if rel.parent.name == "__pycache__" and rel.suffix == ".pyc":
        return rel.parent.parent / (rel.name.split(".", 1)[0] + ".py")
    return rel
