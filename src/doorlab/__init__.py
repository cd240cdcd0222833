"""doorlab: three ways of commanding a simulated KUKA iiwa 7 to open a cupboard door.

Public API (see the README): :class:`Scenario` and :func:`load_scenario` (configuration),
:func:`run_controller` (one episode of a registered controller), :func:`run_episode`
(your own plans), :class:`EpisodeResult` (named logs), :func:`compute_metrics`; sweeps in
:mod:`doorlab.sweep` (``run_sweep(spec) -> pandas.DataFrame``), the report in
:mod:`doorlab.report`.
"""

from doorlab.config import Scenario, load_scenario, validate
from doorlab.controllers import REGISTRY, get_controller, run_controller
from doorlab.errors import ConfigError, DoorlabError, IkError, OutputError, SimulationError
from doorlab.simulation import EpisodeResult, run_episode

__version__ = "0.1.0"

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
