"""Controllers from outside doorlab: a file, a module or an installed package (plug-ins).

Where a command takes a controller (``--controller``, ``controller:`` in a scenario or
``controllers:`` in a SPEC) it takes, besides a built-in's name:

- ``FILE.py:NAME``: NAME in a Python file (a relative FILE is relative to the working
  directory on the command line, to the YAML file's folder in a scenario or SPEC);
- ``MODULE:NAME``: NAME in an importable module (the working directory is on the path, as
  for ``python -m``);
- ``NAME`` of an installed plug-in: an entry point of the group ``doorlab.controllers``
  (``[project.entry-points."doorlab.controllers"]`` in its ``pyproject.toml``).

NAME is a :class:`~doorlab.episode.contract.Controller` or a function ``(scenario, geometry,
plant) -> ArcPlan`` (:mod:`doorlab.episode.contract`). A plug-in is loaded once per process
(each worker of a sweep loads it itself, from the same spec). What can go wrong is a
:class:`~doorlab.errors.PluginError`, one line naming the plug-in: it does not import (the
message has the exception and the plug-in's line), NAME is missing or of the wrong kind or
signature, its name is a built-in's, its build raised or returned no ArcPlan. Its plan is
watched at every tick (:class:`GuardedPlan`): an exception or a malformed command stops the
run with status ``controller_error`` (:class:`~doorlab.errors.ControllerError`), the logs kept.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import math
import os
import sys
import traceback
from dataclasses import replace
from pathlib import Path

import numpy as np

from doorlab.config import CONTROLLERS
from doorlab.config_checks import ENTRY_POINT_GROUP, ControllerSpec, controller_spec
from doorlab.constants import NUM_JOINTS
from doorlab.control.plan_base import JointSpacePlan
from doorlab.episode.contract import ArcPlan, Command, Controller
from doorlab.errors import ConfigError, ControllerError, IkError, PluginError

_loaded: dict[str, tuple[Controller, Path | None]] = {}
"""Plug-ins loaded in this process, by spec: the controller and the file of its code."""


def load_plugin(spec_text: str, builtins: tuple[str, ...] = CONTROLLERS) -> Controller:
    """The plug-in a controller spec names, loaded (once per process) and checked.

    Args:
        spec_text: ``FILE.py:NAME``, ``MODULE:NAME`` or an installed plug-in's name.
        builtins: The built-ins' names (a plug-in may not take one; default
            :data:`doorlab.config.CONTROLLERS`).

    Returns:
        Its :class:`Controller`, named: a Controller's own name, else the function's NAME (an
        installed plug-in: its entry point's name).

    Raises:
        PluginError: It cannot be loaded or used (one line naming it).
    """
    known = _loaded.get(spec_text)
    if known is not None:
        return known[0]
    spec = controller_spec(spec_text, builtins)
    shown = f"controller {spec_text!r}"
    if spec.kind == "builtin":
        raise PluginError(f"{shown} is a built-in, not a plug-in")
    obj, file = _load_object(spec, shown)
    controller = _as_controller(obj, spec, shown)
    if controller.name in builtins:
        raise PluginError(
            f"{shown} is named {controller.name!r}, a built-in controller's name; give it "
            f"another (the built-ins: {', '.join(builtins)})"
        )
    _loaded[spec_text] = (controller, file)
    return controller


def display_name(spec_text: str, builtins: tuple[str, ...] = CONTROLLERS) -> str:
    """What tables, metrics and folders call a controller: a built-in's name, a plug-in's own
    (loaded to read it; a plug-in that no longer loads, say the logs of a run whose file has
    moved, or no controller at all, a failed run's: NAME of its spec, or the text)."""
    if spec_text in builtins:
        return spec_text
    try:
        return load_plugin(spec_text, builtins).name
    except ConfigError:  # not a controller at all (a failed run's), or a plug-in gone
        return spec_text.rpartition(":")[2].split(".")[-1] or spec_text


def plugin_file(spec_text: str) -> Path | None:
    """The file a loaded plug-in's code is in (for messages), or None."""
    known = _loaded.get(spec_text)
    return None if known is None else known[1]


def _load_object(spec: ControllerSpec, shown: str) -> tuple[object, Path | None]:
    """The object NAME of the spec's file, module or entry point, and its file."""
    if spec.kind == "file":
        path = Path(spec.target)
        if not path.is_file():
            raise PluginError(f"{shown}: no file {str(path)!r}")
        module = _import_file(path, shown)
        return _attribute(module, spec, shown, path), path
    if spec.kind == "module":
        module = _import_module(spec.target, shown)
        file = getattr(module, "__file__", None)
        return _attribute(module, spec, shown, None), Path(file) if file else None
    entry = installed_plugins().get(spec.target)
    if entry is None:
        raise PluginError(f"{shown}: no installed plug-in of that name")
    try:
        obj = entry.load()
    except Exception as e:
        raise PluginError(
            f"{shown} (the entry point {entry.value!r} of the group {ENTRY_POINT_GROUP}) "
            f"failed to import: {describe_exception(e)}"
        ) from None
    return obj, _module_file(getattr(obj, "__module__", None))


def _module_file(name: str | None) -> Path | None:
    module = sys.modules.get(name or "")
    file = getattr(module, "__file__", None)
    return Path(file) if file else None


def _import_file(path: Path, shown: str):
    """Executes a plug-in file as a module of its own (kept in ``sys.modules`` under a name
    derived from its path, so its dataclasses and pickles work)."""
    digest = hashlib.sha256(str(path).encode()).hexdigest()[:12]
    name = f"doorlab_plugin_{path.stem if path.stem.isidentifier() else 'file'}_{digest}"
    if name in sys.modules:
        return sys.modules[name]
    module_spec = importlib.util.spec_from_file_location(name, path)
    if module_spec is None or module_spec.loader is None:
        raise PluginError(f"{shown}: {str(path)!r} cannot be imported as Python")
    module = importlib.util.module_from_spec(module_spec)
    sys.modules[name] = module
    try:
        module_spec.loader.exec_module(module)
    except BaseException as e:
        sys.modules.pop(name, None)
        if not isinstance(e, Exception):
            raise  # Ctrl-C, SystemExit
        raise PluginError(f"{shown} failed to import: {describe_exception(e, path)}") from None
    return module


def _import_module(name: str, shown: str):
    cwd = os.getcwd()
    if cwd not in sys.path and "" not in sys.path:
        sys.path.append(cwd)  # as python -m does (appended: it shadows nothing installed)
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as e:
        if e.name and (name == e.name or name.startswith(e.name + ".")):
            raise PluginError(
                f"{shown}: no module named {e.name!r} (install it, or run from the folder "
                "that holds it, or put that folder on PYTHONPATH)"
            ) from None
        raise PluginError(f"{shown} failed to import: {describe_exception(e)}") from None
    except Exception as e:
        raise PluginError(f"{shown} failed to import: {describe_exception(e)}") from None


def _attribute(module, spec: ControllerSpec, shown: str, path: Path | None) -> object:
    obj = module
    for part in spec.name.split("."):
        if not hasattr(obj, part):
            where = str(path) if path is not None else spec.target
            found = sorted(n for n, v in vars(module).items() if _offered(n, v, module))
            hint = f"; it defines {', '.join(found)}" if found else ""
            raise PluginError(f"{shown}: {where} has no {spec.name!r}{hint}")
        obj = getattr(obj, part)
    return obj


def _offered(name: str, value: object, module) -> bool:
    """Whether a module's attribute could be a plug-in: a Controller, or a public function
    defined there."""
    if name.startswith("_"):
        return False
    if isinstance(value, Controller):
        return True
    return inspect.isfunction(value) and value.__module__ == module.__name__


def _as_controller(obj: object, spec: ControllerSpec, shown: str) -> Controller:
    """``obj`` as a named Controller, its build function's signature checked."""
    wanted = "a doorlab.Controller or a function (scenario, geometry, plant) -> doorlab.ArcPlan"
    if isinstance(obj, Controller):
        controller = obj
    elif inspect.isclass(obj):
        raise PluginError(f"{shown} is a class; it must be {wanted}")
    elif callable(obj):
        name = spec.target if spec.kind == "entry_point" else spec.name.split(".")[-1]
        doc = inspect.getdoc(obj) or ""
        summary = doc.strip().splitlines()[0] if doc.strip() else ""
        try:
            controller = Controller(name, None, name, summary, obj)
        except Exception as e:  # a name that cannot name a folder
            raise PluginError(f"{shown}: {e}") from None
    else:
        raise PluginError(f"{shown} is a {type(obj).__name__}; it must be {wanted}")
    if spec.kind == "entry_point" and controller.name != spec.target:
        controller = replace(controller, name=spec.target)  # what the user typed
    _check_signature(controller.build, shown)
    return controller


def _check_signature(build, shown: str) -> None:
    try:
        signature = inspect.signature(build)
    except (TypeError, ValueError):
        return  # a builtin or C function: its call will tell
    try:
        signature.bind(None, None, None)
    except TypeError:
        raise PluginError(
            f"{shown}: its build function takes {signature}; it must take (scenario, "
            "geometry, plant) and return a doorlab.ArcPlan"
        ) from None


def installed_plugins() -> dict:
    """The installed plug-ins: entry point name -> entry point (group ``doorlab.controllers``)."""
    from importlib.metadata import entry_points

    return {entry.name: entry for entry in entry_points(group=ENTRY_POINT_GROUP)}


def describe_exception(error: BaseException, file: Path | None = None) -> str:
    """``Type: message`` on one line, with where it was raised: the last line of the
    traceback in ``file`` if given, else the last one at all (``at NAME.py, line N``)."""
    message = " ".join(str(error).split())
    text = f"{type(error).__name__}: {message}" if message else type(error).__name__
    if len(text) > 300:
        text = text[:297] + "..."
    frames = traceback.extract_tb(error.__traceback__)
    if isinstance(error, SyntaxError) and error.filename:
        return f"{text} ({Path(error.filename).name}, line {error.lineno})"
    if file is not None:
        frames = [f for f in frames if Path(f.filename) == file] or frames
    if frames:
        frame = frames[-1]
        return f"{text} ({Path(frame.filename).name}, line {frame.lineno})"
    return text


def build_arc(controller: Controller, spec_text: str, scenario, geometry, plant) -> ArcPlan:
    """A plug-in's build, watched: its ArcPlan with the plan wrapped in a :class:`GuardedPlan`.

    Raises:
        IkError: The build's IK failed (a result, as for a built-in).
        PluginError: The build raised anything else, or returned no valid ArcPlan.
    """
    shown = f"controller {controller.name!r} ({spec_text})"
    file = plugin_file(spec_text)
    try:
        arc = controller.build(scenario, geometry, plant)
    except IkError:
        raise
    except Exception as e:
        raise PluginError(f"{shown}: its build raised {describe_exception(e, file)}") from None
    if not isinstance(arc, ArcPlan):
        raise PluginError(f"{shown}: its build returned a {type(arc).__name__}, not an ArcPlan")
    q_start = np.asarray(arc.q_start, dtype=float) if _numeric(arc.q_start) else None
    if q_start is None or q_start.shape != (NUM_JOINTS,) or not np.all(np.isfinite(q_start)):
        raise PluginError(f"{shown}: its ArcPlan's q_start must be 7 finite numbers [rad]")
    plan = arc.plan
    duration = getattr(plan, "duration", None)
    if not callable(getattr(plan, "command", None)) or not isinstance(
        getattr(plan, "name", None), str
    ):
        raise PluginError(
            f"{shown}: its ArcPlan's plan is a {type(plan).__name__}: a plan needs a name (str), "
            "a duration [s] and command(t, state) -> Command"
        )
    if (
        not isinstance(duration, (int, float))
        or isinstance(duration, bool)
        or not math.isfinite(duration)
        or duration <= 0
    ):
        raise PluginError(f"{shown}: its plan's duration must be a number of seconds > 0")
    if type(plan) is not JointSpacePlan:  # doorlab's own replays run in C++, unwatched
        plan = GuardedPlan(plan, shown, file)
    return ArcPlan(plan, q_start, arc.ik)


def _numeric(value: object) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


class GuardedPlan:
    """A plug-in's plan, watched at every tick: an exception, or a command that is not 7 + 7
    finite numbers, raises :class:`~doorlab.errors.ControllerError` (the run stops there with
    status ``controller_error``). Every other attribute is the plan's (``log_table``...)."""

    def __init__(self, plan, shown: str, file: Path | None = None) -> None:
        self._plan = plan
        self._shown = shown
        self._file = file
        self.name = plan.name
        self.duration = float(plan.duration)

    def command(self, t: float, state) -> Command:
        """The plan's command at t [s] since it started, checked."""
        try:
            command = self._plan.command(t, state)
        except Exception as e:
            raise ControllerError(
                f"{self._shown} raised at t = {t:.3f} s of its plan: "
                f"{describe_exception(e, self._file)}"
            ) from None
        try:
            q_ref, tau_ff = command
            q_ref = np.asarray(q_ref, dtype=float)
            tau_ff = np.asarray(tau_ff, dtype=float)
        except (TypeError, ValueError):
            raise ControllerError(
                f"{self._shown} returned a {type(command).__name__} at t = {t:.3f} s of its "
                "plan, not a Command(q_ref, tau_ff)"
            ) from None
        for what, value, unit in (("q_ref", q_ref, "rad"), ("tau_ff", tau_ff, "N m")):
            if value.shape != (NUM_JOINTS,) or not np.all(np.isfinite(value)):
                shape = "x".join(map(str, value.shape)) or "a scalar"
                raise ControllerError(
                    f"{self._shown} returned a {what} of shape {shape} with "
                    f"{int(np.size(value) - np.isfinite(value).sum())} non-finite values at "
                    f"t = {t:.3f} s of its plan; a Command holds 7 finite numbers each "
                    f"({what} [{unit}])"
                )
        return Command(q_ref, tau_ff)

    def __getattr__(self, name: str):
        return getattr(self._plan, name)
