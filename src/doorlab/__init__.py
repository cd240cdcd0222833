"""doorlab: three ways of commanding a simulated KUKA iiwa 7 to open a cupboard door, and a
fourth (``adaptive``) that opens one whose hinge it does not know.

Public API (see the README): :class:`Scenario` and :func:`load_scenario` (configuration),
:func:`run_controller` (one episode of a registered controller), :func:`run_episode`
(your own plans), :class:`EpisodeResult` (named logs), :func:`compute_metrics`; sweeps in
:mod:`doorlab.sweep` (``run_sweep(spec) -> pandas.DataFrame``), the report in
:mod:`doorlab.report`.
"""

from doorlab.errors import ConfigError, DoorlabError, IkError, OutputError, SimulationError

__version__ = "0.1.0"

_LAZY = {
    "Scenario": "config",
    "load_scenario": "config",
    "validate": "config",
    "REGISTRY": "controllers",
    "get_controller": "controllers",
    "run_controller": "controllers",
    "EpisodeResult": "simulation",
    "run_episode": "simulation",
}
"""The API that needs pydrake, imported on first use: ``import doorlab`` stays light, so the
``doorlab`` command handles signals before its imports (:mod:`doorlab.entry`)."""


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"doorlab.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'doorlab' has no attribute {name!r}")


__all__ = [
    "REGISTRY",
    "ConfigError",
    "DoorlabError",
    "EpisodeResult",
    "IkError",
    "OutputError",
    "Scenario",
    "SimulationError",
    "get_controller",
    "load_scenario",
    "run_controller",
    "run_episode",
    "validate",
]
