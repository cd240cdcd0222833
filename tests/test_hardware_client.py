"""doorlab run --hardware's client against an in-process stand-in driver (tests/fake_driver.py,
memq://, a virtual clock): the protocol's rules and every safety stop, deterministically.

The fake arm is ideal (its measured q is the last command, one status late), so these tests
check what the client sends and when, not physics; the closed loop on doorlab's simulated cell
is in test_hardware_wiring.py (memq, one process) and test_hardware_two_process.py.
"""

from __future__ import annotations

import json
import signal

import numpy as np
import pytest
from fake_driver import FakeDriver

from doorlab.cell.safety import SafetyLimits, check_command
from doorlab.config import Scenario, validate
from doorlab.constants import Q_HOME
from doorlab.episode.result import EpisodeResult
from doorlab.errors import Interrupted, NoDriver
from doorlab.hardware.episode import FIRST_COMMAND_DELAY, WATCHDOG_TIMEOUT
from doorlab.hardware.link import DriverLink
from doorlab.hardware.run import run_hardware_to_folder

Q0 = Q_HOME + np.array([0.1, 0.1, 0.0, 0.2, 0.0, 0.0, 0.0])  # joint 4 off its limit


def short(controller: str = "velocity") -> Scenario:
    scenario = Scenario(controller=controller, doors="closed")
    t = scenario.timeline
    t.hold_duration, t.approach_duration, t.grasp_duration = 0.2, 1.0, 0.2
    t.arc_duration, t.extra_time = 3.0, 0.2  # a shorter arc asks for more than 0.5 x 98 deg/s
    return validate(scenario)


def run(driver: FakeDriver, tmp_path, scenario=None, **kwargs):
    link = DriverLink(driver.lcm, clock=driver.clock, pump=driver.pump)
    return run_hardware_to_folder(
        scenario or short(),
        tmp_path / "run",
        link=link,
        wait=1.0,
        confirm=lambda plan: True,
        **kwargs,
    )


@pytest.mark.slow
def test_a_completed_run_writes_the_simulated_runs_folder(tmp_path):
    """Same files and channels as a simulated run; the hinge angles absent, the estimate there."""
    driver = FakeDriver(Q0)
    outcome = run(driver, tmp_path)
    assert (outcome.status, outcome.exit_code) == ("ok", 0)
    out = tmp_path / "run"
    files = {p.name for p in out.iterdir()}
    assert {"log.npz", "metrics.json", "scenario.yaml", "replay.html", "radial_error.png"} <= files
    log = EpisodeResult.load(out / "log.npz")
    assert log.cell == "hardware" and log.door_angles is None
    assert log.door_angle_estimated.shape == log.t.shape
    np.testing.assert_allclose(log.q_measured[0], Q0)  # it starts where the arm is
    assert log.t[-1] == pytest.approx(0.2 + 1.0 + 1.0 + 1.0 + 0.2 + 1.0 + 3.0 + 1.0 + 0.2)
    metrics = json.loads((out / "metrics.json").read_text())
    assert "door_opening_arc_end_rad" not in metrics and "handle_held" not in metrics
    assert "door_opening_arc_end_estimated_rad" in metrics
    assert metrics["link"]["commands"] == len(driver.commands)


@pytest.mark.slow
def test_every_command_answers_a_status_and_none_comes_early(tmp_path):
    """One command per valid status after the start, each with that status's utime, each with
    7 joints and 7 torques; the first no sooner than 0.3 s after the first status; statuses
    with utime -1 (the real driver's first 200) are never echoed."""
    driver = FakeDriver(Q0, negative_first=200)
    run(driver, tmp_path)
    utimes = {s.utime for s in driver.statuses}
    assert all(c.utime in utimes and c.utime >= 0 for c in driver.commands)
    assert all(c.num_joints == 7 and c.num_torques == 7 for c in driver.commands)
    assert len({c.utime for c in driver.commands}) == len(driver.commands)
    assert driver.command_times[0] >= FIRST_COMMAND_DELAY  # the first status came at t = 0
    assert driver.commands[0].utime >= driver.utime0 + 1e6  # after the 200 at -1 (1 s)
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["link"]["skipped_statuses"] == 0  # the start waited them out


@pytest.mark.slow
def test_runs_are_deterministic_on_the_fake_driver(tmp_path):
    """The same driver, the same commands, bit for bit."""
    a, b = FakeDriver(Q0), FakeDriver(Q0)
    run(a, tmp_path / "a")
    run(b, tmp_path / "b")
    assert [c.joint_position for c in a.commands] == [c.joint_position for c in b.commands]
    assert [c.joint_torque for c in a.commands] == [c.joint_torque for c in b.commands]


class DyingDriver(FakeDriver):
    def __init__(self, q0, die_at: float):
        super().__init__(q0)
        self.die_at = die_at

    def pump(self, timeout):
        if self.t >= self.die_at:
            self.alive = False
        super().pump(timeout)


def test_the_watchdog_stops_commanding_50_ms_after_the_last_status(tmp_path):
    """The driver dies mid-arc: no command after its last status, driver_lost, exit 7, the
    folder written with the logs up to then."""
    driver = DyingDriver(Q0, die_at=6.0)  # episode time ~5.7 s: the arc is 4.4-7.4 s
    outcome = run(driver, tmp_path)
    assert (outcome.status, outcome.exit_code) == ("driver_lost", 7)
    last_status = driver.statuses[-1]
    assert all(c.utime <= last_status.utime for c in driver.commands)
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["status"] == "driver_lost"
    stop = metrics["stop"]
    assert WATCHDOG_TIMEOUT - 1e-9 <= stop["last_status_to_stop_s"] <= WATCHDOG_TIMEOUT + 0.006
    log = EpisodeResult.load(tmp_path / "run" / "log.npz")
    assert 5.0 < log.t[-1] <= 6.0
    assert not (tmp_path / "run" / "replay.html").exists()  # a stopped run ends at once


def test_no_driver_is_exit_7_and_writes_nothing(tmp_path):
    driver = FakeDriver(Q0)
    driver.alive = False
    with pytest.raises(NoDriver, match=r"no IIWA_STATUS on memq:// within 1 s.*ip route add"):
        run(driver, tmp_path)
    assert not any(tmp_path.iterdir())


def test_a_command_over_a_limit_is_not_sent(tmp_path):
    """A torque bound the velocity plan's zero tau_ff meets but a position-gap bound its first
    move breaks: safety_stop, exit 8, the limit, joint and time in metrics.json, and the driver
    never received a command that breaks it."""
    scenario = short()
    scenario.station.safety.gap_time = 1e-5  # 17-31 urad: the move's first step breaks it
    driver = FakeDriver(Q0)
    outcome = run(driver, tmp_path, scenario=scenario)
    assert (outcome.status, outcome.exit_code) == ("safety_stop", 8)
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    violation = metrics["stop"]["violation"]
    assert violation["limit"] == "position_gap"
    assert violation["joint"].startswith("iiwa_joint_")
    assert 1.2 <= violation["t"] < 1.3  # the move starts after the 1.2 s hold
    limits = SafetyLimits.from_config(scenario.station.safety, Q0)
    q_previous = Q0
    for status, command in zip(driver.statuses[60:], driver.commands, strict=False):
        q_ref = np.array(command.joint_position)
        assert not check_command(
            limits,
            t=0.0,
            q_ref=q_ref,
            tau_ff=np.array(command.joint_torque),
            q_measured=np.array(status.joint_position_measured),
            q_ref_previous=q_previous,
            dt=0.005,
        )
        q_previous = q_ref


class InterruptedDriver(FakeDriver):
    def __init__(self, q0, at: float, signum: int | None):
        super().__init__(q0)
        self.at, self.signum = at, signum

    def pump(self, timeout):
        super().pump(timeout)
        if self.t >= self.at:
            self.at = float("inf")
            raise KeyboardInterrupt if self.signum is None else Interrupted(self.signum)


@pytest.mark.parametrize("signum, code", [(None, 130), (signal.SIGTERM, 143)])
def test_ctrl_c_and_sigterm_stop_commanding_and_write_the_folder(tmp_path, signum, code):
    driver = InterruptedDriver(Q0, at=2.0, signum=signum)
    outcome = run(driver, tmp_path)
    assert (outcome.status, outcome.exit_code) == ("interrupted", code)
    assert max(driver.command_times) <= 2.0
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["status"] == "interrupted"
    assert EpisodeResult.load(tmp_path / "run" / "log.npz").t[-1] <= 2.0


@pytest.mark.slow
def test_a_command_ready_too_late_is_dropped(tmp_path):
    """A client descheduled between a status and its answer (here: its clock jumps 8 ms while
    it computes the 500th answer) does not send that stale command; the next status gets one."""
    from doorlab.hardware import episode

    driver = FakeDriver(Q0)
    link = DriverLink(driver.lcm, clock=driver.clock, pump=driver.pump)
    original = episode.check_command
    calls = []

    def slow_check(*args, **kwargs):
        calls.append(1)
        if len(calls) == 500:
            driver.t += 0.008  # the answer's clock passes the next status's time
        return original(*args, **kwargs)

    episode.check_command = slow_check
    try:
        outcome = run_hardware_to_folder(
            short(), tmp_path / "run", link=link, wait=1.0, confirm=lambda plan: True
        )
    finally:
        episode.check_command = original
    assert outcome.status == "ok"
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["link"]["stale_commands_dropped"] == 1
    assert metrics["link"]["commands"] == len(calls) - 1 == len(driver.commands)
