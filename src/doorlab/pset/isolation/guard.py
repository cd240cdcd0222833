"""The honesty guard: a second line, in the student's process, against doorlab's reference
solutions.

The first line is the student's view (:mod:`doorlab.pset.isolation.bwrap_root`): the modules that
hold the reference solutions, the templates and the grader's own modules do not exist there. The
grader's table of them (:func:`doorlab.pset.rules.verdicts.hidden_modules`) also reaches the
student's process, where this guard, installed before any of the student's code runs:

- refuses importing one of those modules (by ``import``, ``importlib`` or ``__import__``):
  :class:`HonestyError`, recorded, so the test fails with a message that names what was
  imported even if the student's code catches the error;
- refuses opening one of their files (the paths the grader lists: sources, compiled files,
  the templates), also relative to any open directory (``os.open(name, dir_fd=fd)``), by an
  audit hook, which Python cannot remove.

Where the view cannot be built (``--insecure``; Gradescope's fallback to a separate user) this
is what catches an ``import doorlab.control.laws``, so the grader's results say which line held
(``extra_data.sandbox``). No grader can catch a student who copies the published solutions
by hand.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Mapping


class HonestyError(ImportError):
    """Graded code reached for doorlab's reference solution."""


def _message(what: str, description: str) -> str:
    return (
        f"your code used {what}, {description}: graded code must not use doorlab's "
        "reference solutions (see the problem set's README)"
    )


class Guard:
    """Installed once in the student's process, before any of its code runs.

    Args:
        modules: Module name -> what it holds (the grader's table).
        paths: Files and folders of those modules (absolute; folders end their subtree).

    Attributes:
        violation: The first violation's message (None: none so far).
    """

    def __init__(self, modules: Mapping[str, str], paths: Iterable[str]):
        self.violation: str | None = None
        self._busy = False
        self.modules = dict(modules)
        paths = [os.path.realpath(p) for p in paths]
        self._files = {p for p in paths if not os.path.isdir(p)}
        self._folders = tuple(p.rstrip(os.sep) + os.sep for p in paths if os.path.isdir(p))
        self._names = {os.path.basename(p) for p in paths}

    def _record(self, message: str) -> HonestyError:
        if self.violation is None:
            self.violation = message
        return HonestyError(message)

    def check_module(self, name: str) -> None:
        """Raises HonestyError if ``name`` is (in) a hidden module."""
        for module, description in self.modules.items():
            if name == module or name.startswith(module + "."):
                raise self._record(_message(module, description))

    def _hidden(self, real: str) -> bool:
        return (
            real in self._files
            or real.startswith(self._folders)
            or real + os.sep in (self._folders)
        )

    def check_path(self, path) -> None:
        """Raises HonestyError if ``path`` is a hidden file or in a hidden folder: as given
        (absolute, or relative to the working directory) and, for a relative path, relative
        to every directory this process has open (``dir_fd`` opens)."""
        if isinstance(path, int):
            return
        try:
            text = os.fsdecode(path)
        except (TypeError, ValueError):
            return
        candidates = [os.path.realpath(text)]
        if not os.path.isabs(text) and self._names.intersection(text.split(os.sep)):
            candidates += [os.path.realpath(os.path.join(d, text)) for d in _open_folders()]
        for real in candidates:
            if self._hidden(real):
                raise self._record(_message(real, "a file of doorlab's reference solutions"))

    def _audit(self, event: str, args: tuple) -> None:
        if self._busy:  # the checks' own listdir and readlink
            return
        self._busy = True
        try:
            if event == "import":
                self.check_module(str(args[0]))
            elif event in ("open", "os.listdir", "os.scandir") and args:
                self.check_path(args[0])
        finally:
            self._busy = False

    def find_spec(self, name, path=None, target=None):
        """A meta-path finder (for ``importlib.import_module``, which raises no audit event
        for the module itself): refuses hidden modules, finds nothing else."""
        self.check_module(name)
        return None

    def install(self) -> None:
        """The meta-path finder (first) and the audit hook."""
        loaded = [m for m in self.modules if m in sys.modules]
        if loaded:
            raise RuntimeError(f"hidden modules loaded before the guard: {loaded}")
        sys.meta_path.insert(0, self)
        sys.addaudithook(self._audit)


def _open_folders() -> list[str]:
    """The directories this process has open (what a ``dir_fd`` can name)."""
    out = []
    try:
        fds = os.listdir("/proc/self/fd")
    except OSError:
        return out
    for fd in fds:
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith("/") and os.path.isdir(target):
            out.append(target)
    return out
