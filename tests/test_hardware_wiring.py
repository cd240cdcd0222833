"""The wiring on memq:// in one process, deterministic: ``doorlab run --hardware``'s client and
``doorlab sim-driver`` (its library, stepped by the client's waits) on one in-process bus, with
the arm preset (``examples/kuka_arm.yaml``) on both sides.

Both plans' commands and statuses round-trip (every status after the start answered by one
command carrying its utime; kuka_driver's cycle applies it at the next cycle, and the status
after that reports it), every command is applied at the cycle after the status it answers
(the driver counts none late), and the episode is the one-process run's with the same preset
bit for bit: every cycle's measured and commanded joint positions, velocity estimate and
external torques, from the client's first status to the end. kuka_driver's external-torque
freeze fires on none of the four plans (their peak |external torque| against its limits).
Nothing waits for a wall clock here; over loopback multicast in real time,
test_hardware_two_process.py.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from stepped_driver import SteppedDriver

from doorlab.config import Scenario, load_scenario, validate
from doorlab.episode.controllers import episode_plans, run_controller
from doorlab.hardware.episode import HardwareOutcome, run_hardware_episode
from doorlab.hardware.link import DriverLink
from doorlab.hardware.protocol import IIWA_STATUS_PERIOD
from doorlab.kuka import clamp_command, external_torque_limits

PRESET = Path(__file__).resolve().parents[1] / "examples" / "kuka_arm.yaml"


def preset(controller: str, arc: float = 10.0) -> Scenario:
    """The arm preset, doors closed, the timeline before the arc shortened (the arc whole)."""
    scenario = load_scenario(PRESET)
    scenario.controller, scenario.doors = controller, "closed"
    scenario.timeline.hold_duration, scenario.timeline.approach_duration = 0.5, 4.0
    scenario.timeline.arc_duration = arc
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
    return {c: run_on_memq(preset(c)) for c in ("velocity", "impedance")}


@pytest.mark.slow
@pytest.mark.parametrize("controller", ["velocity", "impedance"])
def test_commands_and_statuses_round_trip(memq_runs, controller):
    """One command per status from the start on, echoing its utime, 7 joints and 7 torques;
    kuka_driver applies it at the next cycle, clamped to its limits less 1 deg (q_home's
    joint 4 needs it in the hold), and the status after that reports it as commanded."""
    outcome, stepped = memq_runs[controller]
    assert outcome.status == "ok", outcome.message
    record = outcome.record
    assert record.command_utime == record.status_utime  # every status answered, in order
    assert len(record.command_utime) == round(outcome.result.t[-1] / IIWA_STATUS_PERIOD)
    commanded = clamp_command(np.asarray(record.command_q))
    echoed = np.asarray(record.status_q_commanded)
    np.testing.assert_array_equal(echoed[2:], commanded[:-2])
    assert stepped.driver.systems.iiwa_commands_received() == len(record.command_q)
    assert np.all(np.diff(record.command_utime) == 5000)  # no status missed


@pytest.mark.slow
@pytest.mark.parametrize("controller", ["velocity", "impedance"])
def test_two_processes_and_one_are_the_same_episode_bit_for_bit(memq_runs, controller):
    """Every command applied at the cycle after its status (none late); each cycle's status
    (measured and commanded joint positions, filtered velocity, external torques, the
    gripper's command) equal, bit for bit, to the one-process run's with the same preset from
    the client's first status (t = 0) to the end; the door opens the same."""
    outcome, stepped = memq_runs[controller]
    context = stepped.simulator.get_context()
    delays = stepped.driver.systems.command_delays(context)
    # (the last answer is for the last status: the driver stops before the next cycle)
    assert len(delays) == len(outcome.record.command_q) - 1 and np.all(delays == 0)
    reference, _ = run_controller(preset(controller))
    one = reference.cycle_log
    two = stepped.driver.systems.cycle_log(context)
    k0 = round(outcome.record.status_utime[0] * 1e-6 / IIWA_STATUS_PERIOD)
    n = len(one["t"])
    assert len(two["t"]) >= k0 + n - 1 and n > 0.95 * outcome.result.t[-1] / IIWA_STATUS_PERIOD
    for name in ("q_measured", "q_commanded", "v_estimated", "tau_external", "wsg_commanded"):
        np.testing.assert_array_equal(two[name][k0 : k0 + n], one[name][: len(two["t"]) - k0])
    # The client's statuses are the driver's, and so the one-process run's.
    statuses = np.asarray(outcome.record.status_q_measured)
    m = min(len(statuses), n)
    np.testing.assert_array_equal(statuses[:m], one["q_measured"][:m])
    # kuka_driver's external-torque freeze does not fire on the shipped plans.
    ratio = np.abs(two["tau_external"]) / external_torque_limits()
    print(f"{controller}: peak |tau_external| {100 * ratio.max():.1f} % of the freeze limit")
    assert ratio.max() < 1.0


@pytest.mark.slow
def test_the_run_repeats_bit_for_bit():
    """Two runs on memq:// send the same commands and log the same channels."""
    scenario = preset("velocity", arc=2.0)
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


@pytest.mark.slow
@pytest.mark.parametrize("controller", ["ik", "adaptive"])
def test_every_controller_runs_on_the_real_cells_path(controller):
    """The other two controllers of the registry (velocity and impedance above) run through
    the same path to their end, on the arm preset, and open the door (the driver's truth),
    the handle held."""
    scenario = preset(controller)
    outcome, stepped = run_on_memq(scenario)
    assert outcome.status == "ok", outcome.message
    truth = stepped.driver.ground_truth()
    opening = truth.door_angles[0, 0] - truth.door_angles[-1, 0]
    assert math.degrees(opening) > 35.0  # the problem set's sweep is 41.2 deg
    cycles = stepped.driver.systems.cycle_log(stepped.simulator.get_context())
    assert np.max(np.abs(cycles["tau_external"]) / external_torque_limits()) < 1.0
    assert truth.wsg_width[-1] > 0.0075
    assert outcome.result.plan_names[-1] == controller
