"""The split episode (schedule, plan runner, shared wiring and logger, simulation) gives the
logs of main's one-function ``run_episode`` bit for bit.

The reference is a frozen copy of main's ``doorlab/simulation.py`` (2f990e7,
``main_simulation_2f990e7.py``), run here in the same process on the same station, so the
comparison is exact: every channel of :class:`~doorlab.episode.result.EpisodeResult`, the plan's
own log included, must be equal (``array_equal``, no tolerance). A shortened timeline keeps
each episode under a second; every phase still runs (hold, move, grasp, arc, extra time) and
every controller of the registry takes part (the IK plan runs all in C++ sources, the others
hand over to the Python runner).
"""

from __future__ import annotations

import dataclasses

import main_simulation_2f990e7 as main_simulation
import numpy as np
import pytest

from doorlab.cell.geometry import scenario_door_geometry
from doorlab.cell.station import make_controller_plant
from doorlab.config import Scenario, validate
from doorlab.control.plans import JointSpacePlan
from doorlab.episode.controllers import REGISTRY, get_controller
from doorlab.episode.simulation import run_episode


def short_scenario(controller: str, doors: str) -> Scenario:
    scenario = Scenario(controller=controller, doors=doors)
    timeline = scenario.timeline
    timeline.hold_duration, timeline.approach_duration = 0.2, 2.0
    timeline.grasp_duration, timeline.arc_duration, timeline.extra_time = 0.5, 3.0, 0.3
    return validate(scenario)


def episode(run, scenario: Scenario):
    """One episode through ``run`` (either run_episode) with a freshly built arc plan."""
    arc = get_controller(scenario.controller).build(
        scenario, scenario_door_geometry(scenario), make_controller_plant()
    )
    grasp = JointSpacePlan.hold(arc.q_start, scenario.timeline.grasp_duration, name="grasp")
    width = scenario.station.gripper.grasp_width
    return run(scenario, [grasp, arc.plan], [width, width], q_start=arc.q_start)


CASES = [(name, "closed") for name in REGISTRY] + [("velocity", "open"), ("impedance", "open")]
"""Every controller with the doors closed; the two feedback plans in free space too."""


@pytest.mark.slow
@pytest.mark.parametrize("controller, doors", CASES)
def test_split_episode_is_bit_identical_to_mains(controller, doors):
    """Every logged channel equals main's, exactly."""
    scenario = short_scenario(controller, doors)
    new = episode(run_episode, scenario)
    old = episode(main_simulation.run_episode, scenario)
    for field in dataclasses.fields(old):  # main's channels (the new result adds the real cell's)
        if field.name == "wall_time_s":
            continue
        a, b = getattr(new, field.name), getattr(old, field.name)
        if field.name == "plan_log":
            assert a.keys() == b.keys()
            for key in a:
                np.testing.assert_array_equal(a[key], b[key], err_msg=f"plan_log.{key}")
        elif isinstance(a, np.ndarray):
            assert a.shape == b.shape, field.name
            np.testing.assert_array_equal(a, b, err_msg=field.name)
        else:
            assert a == b, field.name
    assert len(new.t) > 500
    assert (new.cell, new.door_angle_estimated, new.status_time) == ("simulation", None, None)
