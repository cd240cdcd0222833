"""The honesty boundary: graded code cannot use doorlab's reference solutions.

doorlab ships the solutions of its own problem set: the control laws (:mod:`doorlab.laws`)
and the plans and controllers built on them, the pointwise IK (:func:`doorlab.ik.pointwise_ik`),
the ``--solutions`` files (the templates and :mod:`doorlab.pset.folder`, which renders them)
and the grader's own expected answers. In the student's process:

- importing one of :data:`REFERENCE_MODULES` (by ``import``, ``importlib`` or
  ``__import__``) raises :class:`HonestyError` and is recorded, so the test fails with a
  message that names what was imported, even if the student's code catches the error;
- opening one of their files (:func:`reference_paths`: the sources, their compiled
  ``.pyc`` and the templates) does the same (an audit hook, which Python cannot remove);
- ``doorlab.ik.pointwise_ik`` is replaced by a function that does the same when called
  (:mod:`doorlab.ik` itself stays: the folder's ``SolveOneShotIk`` uses its ``solve_ik``).

Where the kernel allows a mount namespace (see :mod:`doorlab.pset.sandbox`) the same files
are also replaced by empty ones for that process and its children, so a subprocess cannot
read them either. What no grader can catch: the solutions are public, like any published
problem set's, and a student can copy them by hand.
"""

from __future__ import annotations

import importlib.util
import os
import sys
from collections.abc import Callable
from pathlib import Path

REFERENCE_MODULES = {
    "doorlab.laws": "doorlab's control laws (the reference solution of tasks 2 and 3)",
    "doorlab.plans": "doorlab's task-space plans (the reference solution of tasks 2 and 3)",
    "doorlab.controllers": "doorlab's controllers (the reference solutions of tasks 1-3)",
    "doorlab.adaptive": "doorlab's adaptive plan (built on the reference control laws)",
    "doorlab.legacy": "doorlab's former episode design (runs the reference controllers)",
    "doorlab.pset.folder": "the problem set's solution files (doorlab pset init --solutions)",
    "doorlab.pset.grader": "the grader (its expected answers)",
    "doorlab.pset.checks": "the grader (its expected answers)",
    "doorlab.pset.jobs": "the grader (its expected answers)",
}
"""Modules graded code may not import, and what they hold."""
REFERENCE_FUNCTIONS = {"doorlab.ik": {"pointwise_ik": "doorlab's pointwise IK (task 1's solution)"}}
"""Functions of allowed modules that graded code may not call."""
TEMPLATES = ("doorlab.pset", "templates")
"""The folder of the problem set's templates (the solutions' text)."""


class HonestyError(ImportError):
    """Graded code reached for doorlab's reference solution."""


def _module_file(name: str) -> Path | None:
    spec = importlib.util.find_spec(name)
    return Path(spec.origin).resolve() if spec is not None and spec.origin else None


def reference_paths() -> list[Path]:
    """The files and folders that hold the reference solutions: each module's source and
    its compiled files, and the templates folder (those that exist)."""
    out = []
    for name in REFERENCE_MODULES:
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


def _message(what: str, description: str) -> str:
    return (
        f"your code used {what}, {description}: graded code must not use doorlab's "
        "reference solutions (see the problem set's README)"
    )


class Guard:
    """Installed once in the student's process, before any of its code runs.

    Attributes:
        violation: The first violation's message (None: none so far).
    """

    def __init__(self, paths: list[Path]):
        self.violation: str | None = None
        self._files = {str(p) for p in paths if not p.is_dir()}
        self._folders = tuple(str(p) + os.sep for p in paths if p.is_dir())

    def _record(self, message: str) -> HonestyError:
        if self.violation is None:
            self.violation = message
        return HonestyError(message)

    def check_module(self, name: str) -> None:
        """Raises HonestyError if ``name`` is (in) a reference module."""
        for module, description in REFERENCE_MODULES.items():
            if name == module or name.startswith(module + "."):
                raise self._record(_message(module, description))

    def check_path(self, path) -> None:
        """Raises HonestyError if ``path`` is a reference file."""
        if isinstance(path, int):
            return
        try:
            real = os.path.realpath(os.fsdecode(path))
        except (TypeError, ValueError):
            return
        if real in self._files or real.startswith(self._folders):
            raise self._record(_message(real, "a file of doorlab's reference solutions"))

    def _audit(self, event: str, args: tuple) -> None:
        if event == "import":
            self.check_module(str(args[0]))
        elif event == "open":
            self.check_path(args[0])

    def find_spec(self, name, path=None, target=None):
        """A meta-path finder (for ``importlib.import_module``, which raises no audit event
        for the module itself): refuses reference modules, finds nothing else."""
        self.check_module(name)
        return None

    def tripwire(self, module: str, name: str, description: str) -> Callable:
        """A stand-in for a reference function: calling it is a violation."""

        def forbidden(*args, **kwargs):
            raise self._record(_message(f"{module}.{name}", description))

        forbidden.__name__ = name
        return forbidden

    def install(self) -> None:
        """Audit hook, meta-path finder and tripwires (modules in REFERENCE_FUNCTIONS must
        be importable here; they are imported)."""
        for module, functions in REFERENCE_FUNCTIONS.items():
            mod = importlib.import_module(module)
            for name, description in functions.items():
                setattr(mod, name, self.tripwire(module, name, description))
        loaded = [m for m in REFERENCE_MODULES if m in sys.modules]
        if loaded:
            raise RuntimeError(f"reference modules loaded before the guard: {loaded}")
        sys.meta_path.insert(0, self)
        sys.addaudithook(self._audit)
