"""The wiring on memq:// in one process, deterministic: ``doorlab run --hardware``'s client and
``doorlab sim-driver`` (its library, stepped by the client's waits) on one in-process bus.

Both plans' commands and statuses round-trip (every status after the start answered by one
command carrying its utime, every command reported by the next status), the run repeats bit
for bit, and it opens the door as the one-process episode does. Here nothing waits for a wall
clock, so every command reaches the driver before its next plant step and acts from the step
it acts from in one process (the driver's count of late commands says so); the two paths then
differ only by what the driver does that one process does not (the clamp of q_home's joint 4
to the limits less 1 deg in the hold, the measured start), far below the tolerances: the
door within 0.05 deg, Q's radial error within 2 um.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from doorlab.config import Scenario, validate
from doorlab.controllers import episode_plans, run_controller
from doorlab.geometry import true_door_geometry
from doorlab.hardware.episode import HardwareOutcome, run_hardware_episode
from doorlab.hardware.link import DriverLink
from doorlab.hardware.protocol import DRIVER_JOINT_LIMITS, IIWA_STATUS_PERIOD, JOINT_LIMIT_MARGIN
from doorlab.hardware.sim_cell import STATUS_DELAY
from doorlab.hardware.sim_driver import SimDriver
from doorlab.metrics import compute_metrics


class SteppedDriver:
    """``doorlab sim-driver``'s library on memq://, advanced one status at a time by the
    client's waits (:class:`~doorlab.hardware.link.DriverLink`'s pump) on its own clock."""

    def __init__(self, scenario: Scenario):
        self.driver = SimDriver(scenario, lcm_url="memq://", record=True)
        self.lcm = self.driver.lcm
        self.simulator = self.driver.simulator
        self.simulator.set_target_realtime_rate(0.0)
        self.simulator.Initialize()

    def clock(self) -> float:
        return self.driver.time

    def pump(self, timeout: float) -> None:
        t = self.driver.time
        slot = (math.floor(t / IIWA_STATUS_PERIOD + 1e-9) + 1) * IIWA_STATUS_PERIOD
        t_next = slot + STATUS_DELAY  # when the driver publishes the status of that slot
        self.simulator.AdvanceTo(t_next if t_next <= t + timeout + 1e-9 else t + timeout)
        self.lcm.HandleSubscriptions(0)  # deliver it


def pre_arc_short(controller: str) -> Scenario:
    scenario = Scenario(controller=controller, doors="closed")
    scenario.timeline.hold_duration, scenario.timeline.approach_duration = 0.5, 3.0
    return validate(scenario)


def run_on_memq(scenario: Scenario) -> tuple[HardwareOutcome, SteppedDriver]:
    stepped = SteppedDriver(scenario)
    link = DriverLink(stepped.lcm, clock=stepped.clock, pump=stepped.pump)
    link.wait_first_status(1.0)
    plans, widths, arc = episode_plans(scenario)
    outcome = run_hardware_episode(scenario, plans, widths, q_start=arc.q_start, link=link, wait=1)
    return outcome, stepped


@pytest.fixture(scope="module")
def memq_runs():
    return {c: run_on_memq(pre_arc_short(c)) for c in ("velocity", "impedance")}


@pytest.mark.parametrize("controller", ["velocity", "impedance"])
def test_commands_and_statuses_round_trip(memq_runs, controller):
    """One command per status from the start on, echoing its utime, 7 joints and 7 torques;
    the next status reports it as commanded (the driver's clamp to its limits less 1 deg
    applied, which q_home's joint 4 needs in the hold)."""
    outcome, stepped = memq_runs[controller]
    assert outcome.status == "ok"
    record = outcome.record
    assert record.command_utime == record.status_utime  # every status answered, in order
    assert len(record.command_utime) == round(outcome.result.t[-1] / IIWA_STATUS_PERIOD)
    limit = DRIVER_JOINT_LIMITS - JOINT_LIMIT_MARGIN
    commanded = np.clip(np.asarray(record.command_q), -limit, limit)
    echoed = np.asarray(record.status_q_commanded)
    np.testing.assert_array_equal(echoed[1:], commanded[:-1])
    assert stepped.driver.systems.iiwa_commands_received() == len(record.command_q)
    assert np.all(np.diff(record.command_utime) == 5000)  # no status missed


def test_the_run_repeats_bit_for_bit():
    """Two runs on memq:// send the same commands and log the same channels."""
    scenario = pre_arc_short("velocity")
    scenario.timeline.arc_duration = 2.0  # enough for the runner's ticks to matter
    (a, _), (b, _) = run_on_memq(scenario), run_on_memq(scenario)
    np.testing.assert_array_equal(np.asarray(a.record.command_q), np.asarray(b.record.command_q))
    for name in (
        "q_measured",
        "q_commanded",
        "tau_feedforward",
        "wsg_width",
        "door_angle_estimated",
    ):
        np.testing.assert_array_equal(getattr(a.result, name), getattr(b.result, name))


@pytest.mark.parametrize("controller", ["velocity", "impedance"])
def test_the_door_opens_as_in_one_process(memq_runs, controller):
    """Every command acts from the plant step it acts from in one process; the driver's true
    door at the arc's end and Q's radial error match the one-process episode's (module
    docstring)."""
    outcome, stepped = memq_runs[controller]
    delays = stepped.driver.systems.command_delays(stepped.simulator.get_context())
    assert len(delays) > 0.9 * len(outcome.record.command_q) and np.all(delays == 0)
    scenario = pre_arc_short(controller)
    reference, _ = run_controller(scenario)
    ref = compute_metrics(reference, scenario, true_door_geometry(scenario))

    truth = stepped.driver.ground_truth()
    log = outcome.result
    t_end = log.status_time[0] + log.arc_window[1]
    i = int(np.argmin(np.abs(truth.t - t_end)))
    j = int(np.argmin(np.abs(reference.t - reference.arc_window[1])))
    door = truth.door_angles[i, 0] - reference.door_angles[j, 0]
    print(f"{controller}: door {math.degrees(door):+.5f} deg")
    assert abs(door) <= math.radians(0.05), math.degrees(door)

    from doorlab.hardware.metrics import compute_hardware_metrics

    metrics = compute_hardware_metrics(outcome, scenario, lcm_url="memq://")
    for key in ("max_radial_error_m", "rms_radial_error_m"):
        difference = abs(getattr(metrics, key) - getattr(ref, key))
        print(f"  {key}: {1e6 * difference:.3f} um")
        assert difference <= 2e-6, key
    assert metrics.fingers_on_handle and truth.wsg_width[-1] > 0.0075


@pytest.mark.parametrize("controller", ["ik", "adaptive"])
def test_every_controller_runs_on_the_real_cells_path(controller):
    """The other two controllers of the registry (velocity and impedance above) run through
    the same path to their end and open the door (the driver's truth), the handle held."""
    scenario = pre_arc_short(controller)
    outcome, stepped = run_on_memq(scenario)
    assert outcome.status == "ok", outcome.message
    truth = stepped.driver.ground_truth()
    opening = truth.door_angles[0, 0] - truth.door_angles[-1, 0]
    assert math.degrees(opening) > 35.0  # the problem set's sweep is 41.2 deg
    assert truth.wsg_width[-1] > 0.0075
    assert outcome.result.plan_names[-1] == controller
