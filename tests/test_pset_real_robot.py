"""The problem set's ``ManipulationStationSimulator.RunRealRobot`` (the 2019 API) over the path
of ``doorlab run --hardware``, against the in-process stand-in driver (tests/fake_driver.py)."""

from __future__ import annotations

import importlib.util
import inspect
from pathlib import Path

import numpy as np
import pytest
from fake_driver import FakeDriver
from pydrake.trajectories import PiecewisePolynomial

import doorlab.pset.handout
from doorlab.config import Scenario
from doorlab.constants import Q_HOME
from doorlab.errors import ConfigError, SafetyStop
from doorlab.hardware.link import DriverLink
from doorlab.pset.handout.station_api import ProblemSetJointSpacePlan, StationRun

Q0 = Q_HOME + np.array([0.1, 0.1, 0.0, 0.2, 0.0, 0.0, 0.0])
Q_START = Q0 + 0.1


def plans():
    knots = np.column_stack([Q_START, Q_START + 0.05])
    return [ProblemSetJointSpacePlan(PiecewisePolynomial.FirstOrderHold([0.0, 1.0], knots))]


def station() -> StationRun:
    scenario = Scenario()
    scenario.timeline.hold_duration, scenario.timeline.approach_duration = 0.2, 1.0
    return StationRun(scenario)


def real(run: StationRun, driver: FakeDriver):
    link = DriverLink(driver.lcm, clock=driver.clock, pump=driver.pump)
    return run.run_real_robot(plans(), [0.02], extra_time=0.5, yes=True, link=link)


def test_run_real_robot_returns_the_2019_logs_of_the_same_episode():
    """(command, measured, velocity, external torque, t_plan), as in 2019; the same timeline
    (t_plan) and log period as RunSimulation's, and the channels of its EpisodeResult."""
    driver = FakeDriver(Q0)
    run = station()
    q_cmd, q_meas, v, tau_ext, t_plan = real(run, driver)
    sim = station()
    sim_logs = sim.run(
        Q0,
        (-0.001, 0.001),
        plans(),
        [0.02],
        extra_time=0.5,
        real_time_rate=0.0,
        meshcat=None,
        gripper_setpoint_initial=0.025,
    )
    np.testing.assert_allclose(t_plan, sim_logs[-1])
    assert q_cmd.data().shape == sim_logs[0].data().shape
    np.testing.assert_allclose(q_cmd.sample_times(), sim_logs[0].sample_times())
    result = run.result
    assert result.cell == "hardware"
    for log, channel in zip(
        (q_cmd, q_meas, v, tau_ext),
        (result.q_commanded, result.q_measured, result.v_measured, result.tau_external),
        strict=True,
    ):
        np.testing.assert_array_equal(log.data(), channel.T)
    np.testing.assert_allclose(q_meas.data()[:, 0], Q0)  # from where the arm stood
    np.testing.assert_allclose(q_cmd.data()[:, -1], Q_START + 0.05, atol=1e-12)  # the plan's end


def test_run_real_robot_stops_on_a_broken_limit_and_keeps_the_logs():
    driver = FakeDriver(Q0)
    run = station()
    run.scenario.station.safety.gap_time = 1e-5
    with pytest.raises(SafetyStop, match="position_gap"):
        real(run, driver)
    assert run.result is not None and len(run.result.t) > 0


def test_the_problem_sets_simulator_has_run_real_robot_with_the_2019_signature():
    path = (
        Path(doorlab.pset.handout.__file__).parent
        / "templates/manip_station_sim/manipulation_station_simulator.py"
    )
    spec = importlib.util.spec_from_file_location("manipulation_station_simulator", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    parameters = inspect.signature(module.ManipulationStationSimulator.RunRealRobot).parameters
    assert list(parameters)[:4] == ["self", "plan_list", "gripper_setpoint_list", "extra_time"]
    assert parameters["extra_time"].default == 2.0
    with pytest.raises(ConfigError, match="JointSpacePlan"):
        module.ManipulationStationSimulator().RunRealRobot([object()], [0.02])
