"""doorlab: three ways of commanding a simulated KUKA iiwa 7 to open a cupboard door, and a
fourth (``adaptive``) that opens one whose hinge it does not know.

Public API (the site's Python API reference shows it all): :class:`Scenario` and
:func:`load_scenario` (configuration), :func:`run_controller` (one episode of a registered
controller), :func:`run_episode` (your own plans), :class:`EpisodeResult` (named logs),
:func:`compute_metrics`; the contract of a controller of your own (a plug-in every command
runs: :mod:`doorlab.episode.contract`): :class:`Controller`, :class:`ArcPlan`, :class:`Plan`,
:class:`ArmState`, :class:`Command`, and :func:`grasp_configuration`; sweeps in
:mod:`doorlab.sweep` (``run_sweep(spec) -> pandas.DataFrame``), the report in
:mod:`doorlab.report`.

The names below are imported on first use (PEP 562), so importing one submodule (say
``doorlab.constants``) does not load the controllers: the problem set's graded process
must not load doorlab's reference solutions (:mod:`doorlab.pset.isolation.guard`).
"""

from doorlab.errors import (
    ConfigError,
    ControllerError,
    DoorlabError,
    IkError,
    OutputError,
    PluginError,
    SimulationError,
)

__version__ = "0.1.0"

_LAZY = {
    "ArcPlan": "doorlab.episode.contract",
    "ArmState": "doorlab.control.plan_base",
    "Command": "doorlab.control.plan_base",
    "Controller": "doorlab.episode.contract",
    "Plan": "doorlab.control.plan_base",
    "grasp_configuration": "doorlab.episode.controllers",
    "Scenario": "doorlab.config",
    "load_scenario": "doorlab.config",
    "validate": "doorlab.config",
    "REGISTRY": "doorlab.episode.controllers",
    "get_controller": "doorlab.episode.controllers",
    "run_controller": "doorlab.episode.controllers",
    "EpisodeResult": "doorlab.episode.result",
    "run_episode": "doorlab.episode.simulation",
}
"""The API that needs pydrake, imported on first use: ``import doorlab`` stays light, so the
``doorlab`` command handles signals before its imports (:mod:`doorlab.cli.entry`)."""


__all__ = [
    "REGISTRY",
    "ArcPlan",
    "ArmState",
    "Command",
    "ConfigError",
    "Controller",
    "ControllerError",
    "DoorlabError",
    "EpisodeResult",
    "IkError",
    "OutputError",
    "Plan",
    "PluginError",
    "Scenario",
    "SimulationError",
    "get_controller",
    "grasp_configuration",
    "load_scenario",
    "run_controller",
    "run_episode",
    "validate",
]


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'doorlab' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
