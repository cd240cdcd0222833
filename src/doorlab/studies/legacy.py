"""The episode design before issue 9 (commit 353b732), kept to measure the current one against.

Same physics, older machinery: the arm's inner loop through the plant's PD actuators
(``station.inner_loop.kind: implicit_pd``, one SAP constraint per joint), every geometry of the
cupboard and the table with a proximity role (``station.scene_collision``), the Python plan
runner ticking from t = 0 (the joint-space phases too) and nine loggers, one per channel.
(Not reproduced: the models parsed from files, which costs time before the simulation
only.) The benchmarks time it side by side with the current design, and a test checks that
both give the same metrics.
"""

from __future__ import annotations

import contextlib
import copy
from collections.abc import Iterator

from doorlab.config import Scenario, validate
from doorlab.episode import simulation, wiring


def legacy_scenario(scenario: Scenario) -> Scenario:
    """A copy of ``scenario`` on the old station: PD actuators, the whole scene colliding."""
    old = copy.deepcopy(scenario)
    old.station.inner_loop.kind = "implicit_pd"
    old.station.scene_collision = True
    return validate(old)


@contextlib.contextmanager
def python_joint_space_plans() -> Iterator[None]:
    """Within the block, episodes run every plan in the Python plan runner from t = 0 and log
    every channel with its own logger."""
    original = wiring.joint_space_prefix
    wiring.joint_space_prefix = lambda schedule: 0
    simulation._SEPARATE_LOGGERS = True
    try:
        yield
    finally:
        wiring.joint_space_prefix = original
        simulation._SEPARATE_LOGGERS = False


def run_legacy_controller(scenario: Scenario):
    """:func:`doorlab.episode.controllers.run_controller` with the 353b732 design (same
    arguments)."""
    from doorlab.episode.controllers import run_controller

    with python_joint_space_plans():
        return run_controller(legacy_scenario(scenario))
