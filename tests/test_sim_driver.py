"""The simulated driver in one process on ``memq://`` (deterministic, no real-time pacing):
kuka_driver's cycle (a command acts from the cycle after the status it answers), hold, clamp,
start guard, status contents (the filtered velocity), the external-torque stop, utime; and
its CLI's errors.

The two-process tests on loopback multicast are in ``test_sim_driver_bus.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from drake import (
    lcmt_iiwa_command,
    lcmt_iiwa_status,
    lcmt_schunk_wsg_command,
    lcmt_schunk_wsg_status,
)
from pydrake.lcm import DrakeLcm
from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
from pydrake.systems.framework import DiagramBuilder

from doorlab.cli.parser import main
from doorlab.config import Scenario
from doorlab.constants import DOOR_ANGLES, Q_HOME
from doorlab.hardware import protocol
from doorlab.hardware.protocol import (
    IIWA_COMMAND_CHANNEL,
    IIWA_STATUS_CHANNEL,
    WSG_COMMAND_CHANNEL,
    WSG_STATUS_CHANNEL,
    resolve_lcm_url,
)
from doorlab.hardware.sim_cell import add_sim_driver
from doorlab.hardware.sim_driver import SimDriver
from doorlab.runtime.folders import write_manifest

H = 0.002
"""The plant's time step of the default scenario [s]."""


class InProcessCell:
    """The driver on memq:// in its own diagram, stepped by hand, with a bus listener."""

    def __init__(self, scenario: Scenario | None = None, *, utime_warmup: bool = False):
        self.scenario = scenario or Scenario()
        self.lcm = DrakeLcm("memq://")
        builder = DiagramBuilder()
        self.driver = add_sim_driver(
            builder,
            self.lcm,
            self.scenario,
            record=True,
            utime_warmup=utime_warmup,
            read_bus="every_cycle",  # the listener's handlers are Python
        )
        self.simulator = Simulator(builder.Build())
        ResetIntegratorFromFlags(self.simulator, "explicit_euler", self.scenario.station.time_step)
        self.driver.initialize(self.simulator.get_mutable_context())
        self.statuses: list[lcmt_iiwa_status] = []
        self.wsg_statuses: list[lcmt_schunk_wsg_status] = []
        self.lcm.Subscribe(IIWA_STATUS_CHANNEL, self._keep(self.statuses, lcmt_iiwa_status))
        self.lcm.Subscribe(
            WSG_STATUS_CHANNEL, self._keep(self.wsg_statuses, lcmt_schunk_wsg_status)
        )
        self.simulator.Initialize()

    @staticmethod
    def _keep(messages, lcm_type):
        return lambda data: messages.append(lcm_type.decode(data))

    def advance(self, t: float):
        """Advances to just past t [s] and delivers what the driver published up to then (a
        status at t goes out status_offset later; memq delivers a message at the next poll)."""
        status = self.driver.advance_to(self.simulator, t + self.driver.status_offset)
        self.lcm.HandleSubscriptions(0)
        return status

    def command(self, q, tau=None, utime: int = 0) -> None:
        message = lcmt_iiwa_command()
        message.utime = utime
        message.num_joints = 7
        message.joint_position = list(np.asarray(q, float))
        message.num_torques = 7
        message.joint_torque = list(np.zeros(7) if tau is None else np.asarray(tau, float))
        self.lcm.Publish(IIWA_COMMAND_CHANNEL, message.encode())

    def truth(self):
        return self.driver.ground_truth(self.simulator.get_context())

    def status_at(self, utime: int) -> lcmt_iiwa_status:
        return next(s for s in self.statuses if s.utime == utime)


def fine_log() -> Scenario:
    scenario = Scenario()
    scenario.timeline.log_period = 0.001
    return scenario


def test_a_command_acts_from_the_next_cycle_and_is_held():
    """kuka_driver's cycle: a command that answers status k (read before cycle k + 1) is
    applied from cycle k + 1 on and reported by status k + 2 (a status reports the command the
    arm tracked up to it); the arm stands still, locked, until then; the command is held when
    commands stop; one read after cycle k + 1's events is applied a cycle later, and counted."""
    cell = InProcessCell(fine_log())
    cell.advance(0.3)
    q = Q_HOME.copy()
    q[0] = 0.1
    tau = np.array([0, 0, 0, 0, 0, 0, 0.5])
    cell.command(q, tau, utime=300_000)  # answers the status of 0.3 s
    cell.advance(3.5)
    truth = cell.truth()
    applied = 0.305  # cycle k + 1; the next plant step (2 ms grid) is at 0.306
    before = truth.t < applied + 1e-9
    np.testing.assert_array_equal(truth.q_measured[before], np.tile(Q_HOME, (before.sum(), 1)))
    assert np.all(truth.v_measured[before] == 0)  # locked: exactly at rest
    assert truth.q_measured[np.searchsorted(truth.t, 0.306 - 1e-9), 0] > 1e-6
    # The status of a cycle carries the command tracked up to it.
    assert np.all(truth.q_commanded[truth.t < 0.310 - 1e-9, 0] == 0.0)
    assert np.all(truth.q_commanded[truth.t > 0.310 - 1e-9, 0] == 0.1)
    assert np.all(truth.tau_feedforward[truth.t < 0.310 - 1e-9] == 0)
    assert np.all(truth.tau_feedforward[truth.t > 0.310 - 1e-9] == tau)
    assert cell.status_at(305_000).joint_position_commanded[0] == 0.0
    assert cell.status_at(310_000).joint_position_commanded[0] == 0.1
    assert all(s.joint_position_commanded[0] == 0.1 for s in cell.statuses if s.utime > 305_000)
    # The arm settles on it: the loop's damping ratio is about 0.12 at wn = 20 rad/s, so
    # 3.2 s leave exp(-0.12 * 20 * 3.2) = 5e-4 of the 0.1 rad step (5e-5 rad); 1e-4 allows
    # for the coupling of the other joints.
    assert abs(truth.q_measured[-1, 0] - 0.1) < 1e-4
    # A late answer: the command for the status of 3.5 s read after the cycle of 3.505 s.
    cell.advance(3.505)
    q[0] = 0.2
    cell.command(q, tau, utime=3_500_000)
    cell.advance(3.6)
    assert cell.status_at(3_510_000).joint_position_commanded[0] == 0.1
    assert cell.status_at(3_515_000).joint_position_commanded[0] == 0.2
    delays = cell.driver.command_delays(cell.simulator.get_context())
    np.testing.assert_array_equal(delays, [0, 1])


def test_the_status_velocity_is_kuka_drivers_filter():
    """joint_velocity_estimated matches a reference implementation of kuka_driver's filter
    written here from its published constants (low_pass_filter.h: val = alpha val + (1 -
    alpha) input, alpha = 1 - dt / (dt + RC), RC = 1 / (2 pi 40 Hz); the input the finite
    difference of the measured positions over the 5 ms step), to round-off; it lags the
    plant's exact velocity, which the ground truth keeps."""
    cell = InProcessCell()
    cell.advance(0.3)
    q = Q_HOME.copy()
    q[[0, 2]] = [0.1, -0.05]
    cell.command(q, utime=300_000)
    cell.advance(1.0)
    statuses = cell.statuses
    measured = np.array([s.joint_position_measured for s in statuses])
    reported = np.array([s.joint_velocity_estimated for s in statuses])
    dt, rc = 0.005, 1.0 / (2.0 * math.pi * 40.0)
    alpha = 1.0 - dt / (dt + rc)  # 0.443
    expected = np.zeros_like(measured)
    for k in range(1, len(measured)):
        difference = (measured[k] - measured[k - 1]) / dt
        expected[k] = alpha * expected[k - 1] + (1.0 - alpha) * difference
    assert np.abs(expected).max() > 0.5  # the joints moved
    np.testing.assert_allclose(reported, expected, rtol=0, atol=1e-12)
    truth = cell.truth()
    on_status = np.isin(np.rint(truth.t * 1e6).astype(int), [s.utime for s in statuses])
    exact = truth.v_measured[on_status]
    assert np.abs(exact - reported[: len(exact)]).max() > 0.05  # the filter lags


def test_start_pose_held_unclamped_and_commands_clamped():
    """Before any command the arm holds q_home exactly (joint 4 is within 1 deg of its
    limit); a command is clamped to the limits less 1 deg, as kuka_driver does."""
    cell = InProcessCell()
    cell.advance(0.3)
    truth = cell.truth()
    np.testing.assert_allclose(truth.q_commanded, np.tile(Q_HOME, (len(truth.t), 1)), atol=1e-12)
    assert Q_HOME[3] < -(np.deg2rad(120) - np.deg2rad(1))  # the premise
    q = Q_HOME.copy()
    q[6] = 4.0  # beyond joint 7's 175 deg
    cell.command(q, utime=300_000)
    cell.advance(0.4)
    commanded = cell.truth().q_commanded[-1]
    expected = q.copy()
    expected[3] = -(np.deg2rad(120) - np.deg2rad(1))
    expected[6] = np.deg2rad(175) - np.deg2rad(1)
    np.testing.assert_array_equal(commanded, expected)


def test_start_guard_monitor_stops_before_the_command_acts():
    """A command within 0.25 s of the first status ends the simulation before it acts."""
    cell = InProcessCell()
    cell.simulator.set_monitor(cell.driver.start_guard_monitor())
    cell.advance(0.1)
    q = Q_HOME.copy()
    q[0] = 0.3
    cell.command(q)
    status = cell.advance(1.0)
    assert status.reason() == status.ReturnReason.kReachedTerminationCondition
    assert status.FormatMessage().count("start guard")
    assert cell.simulator.get_context().get_time() < 0.1 + cell.driver.status_offset + H
    truth = cell.truth()
    np.testing.assert_allclose(truth.q_commanded, np.tile(Q_HOME, (len(truth.t), 1)), atol=1e-12)
    assert all(s.joint_position_commanded[0] == 0.0 for s in cell.statuses)


def _answer_at(driver: SimDriver, utime: int) -> None:
    """Makes a client (a handler on the driver's memq bus) send one command when it sees the
    status with this utime."""

    def handle(data: bytes) -> None:
        if lcmt_iiwa_status.decode(data).utime == utime:
            message = lcmt_iiwa_command()
            message.utime = utime
            message.num_joints = 7
            message.joint_position = list(Q_HOME)
            driver.lcm.Publish(IIWA_COMMAND_CHANNEL, message.encode())

    driver.lcm.Subscribe(IIWA_STATUS_CHANNEL, handle)


@pytest.mark.parametrize(("utime", "status"), [(100_000, "aborted"), (300_000, "stopped")])
def test_sim_driver_run_start_guard(utime, status):
    """SimDriver.run aborts (exit 1) on a command answering the status at 0.1 s, not 0.3 s."""
    driver = SimDriver(Scenario(), lcm_url="memq://", record=True)
    _answer_at(driver, utime)
    outcome = driver.run(duration=0.5, realtime_rate=0.0)
    assert outcome.status == status
    if status == "aborted":
        assert outcome.exit_code == 1 and outcome.message.startswith("start guard")
        assert outcome.sim_time_s < 0.1 + 2 * H  # read at the driver's next step
        np.testing.assert_allclose(driver.ground_truth().q_commanded[:, 0], 0.0, atol=1e-12)
    else:
        assert outcome.exit_code == 0 and outcome.sim_time_s == 0.5
        assert driver.summary()["iiwa_commands_received"] == 1


def test_statuses_carry_the_plant_state():
    """Every status field has 7 entries, taken from the plant at the status's time (the
    ground truth at the same instant); utime is the time in us; the WSG status every 50 ms."""
    cell = InProcessCell(fine_log())
    cell.advance(0.3)
    q = Q_HOME.copy()
    q[1] += 0.2
    cell.command(q, [0.0, 2.0, 0, 0, 0, 0, 0], utime=300_000)
    wsg = lcmt_schunk_wsg_command()
    wsg.target_position_mm = 10.0
    wsg.force = 12.0
    cell.lcm.Publish(WSG_COMMAND_CHANNEL, wsg.encode())
    cell.advance(1.0)
    truth = cell.truth()
    assert [s.utime for s in cell.statuses] == [5000 * k for k in range(201)]
    for status in cell.statuses[::7]:
        i = int(np.searchsorted(truth.t, status.utime * 1e-6 - 1e-9))
        assert abs(truth.t[i] - status.utime * 1e-6) < 1e-9
        assert status.num_joints == 7
        fields = {
            "joint_position_measured": truth.q_measured[i],
            "joint_position_commanded": truth.q_commanded[i],
            "joint_velocity_estimated": truth.v_estimated[i],
            "joint_torque_commanded": truth.tau_commanded[i],
            "joint_torque_measured": truth.tau_commanded[i],
            "joint_torque_external": truth.tau_external[i],
        }
        for name, expected in fields.items():
            np.testing.assert_array_equal(getattr(status, name), expected, err_msg=name)
    assert np.all(np.abs(np.array(cell.statuses[-1].joint_torque_commanded)[[1, 3]]) > 1.0)
    assert [s.utime for s in cell.wsg_statuses] == [50000 * k for k in range(21)]
    assert cell.wsg_statuses[0].actual_position_mm == pytest.approx(30.0, abs=1e-6)
    # The fingers closed towards 10 mm at up to 12 N; nothing is in between them.
    assert cell.wsg_statuses[-1].actual_position_mm < 15.0
    assert np.all(truth.wsg_force_limit[truth.t > 0.31] == 12.0)
    np.testing.assert_allclose(truth.door_angles[-1], DOOR_ANGLES["closed"], atol=1e-9)


def test_utime_warmup():
    """With the warm-up the first 200 statuses carry utime -1, then the time in us."""
    cell = InProcessCell(utime_warmup=True)
    cell.advance(1.1)
    utimes = [s.utime for s in cell.statuses]
    assert utimes[:200] == [-1] * 200
    assert utimes[200:] == [5000 * k for k in range(200, 221)]
    assert np.all(cell.truth().utime[:100] == -1) and cell.truth().utime[100] == 1_000_000


def test_lcm_url_checks():
    """Bad URLs are one-line ConfigErrors naming the valid form; the default resolves."""
    from doorlab.errors import ConfigError

    assert resolve_lcm_url("udpm://239.255.76.67:7667?ttl=0")
    for bad in (
        "bogus",
        "udpm://10.0.0.1:7667",
        "udpm://239.255.76.67:0",
        "udpm://239.1.1.1:7?x=1",
    ):
        with pytest.raises(ConfigError, match="udpm|port|option"):
            resolve_lcm_url(bad)
    with pytest.raises(ConfigError, match="one process"):
        resolve_lcm_url("memq://")
    assert resolve_lcm_url("memq://", allow_memq=True) == "memq://"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--lcm-url", "udpm://1.2.3.4:5"], "not a multicast group"),
        (["--lcm-url", "memq://"], "one process"),
        (["--doors", "ajar"], "invalid choice: 'ajar'"),
        (["--duration", "0"], "number of seconds in [0.01, 604800]"),
        (["--set", "station.time_step=-1"], "station.time_step"),
    ],
)
def test_cli_bad_input(args, message, capsys, tmp_path):
    """Bad input: exit 2, one line naming the problem, nothing written."""
    out = tmp_path / "gt"
    assert main(["sim-driver", *args, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err and "Traceback" not in err
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_cli_existing_out_and_dead_bus(capsys, tmp_path, monkeypatch):
    """An existing --out needs --force (exit 2); a bus that delivers nothing is exit 1 with
    the multicast-route hint, and the old folder is left as it was (no staging folder)."""
    out = tmp_path / "gt"
    out.mkdir()
    (out / "ground_truth.npz").write_bytes(b"an earlier run's")
    write_manifest(out)  # a folder doorlab wrote (an empty one is written without --force)
    before = sorted(p.name for p in out.iterdir())
    assert main(["sim-driver", "--out", str(out)]) == 2
    assert "--force" in capsys.readouterr().err
    monkeypatch.setattr(protocol, "lcm_delivers", lambda url, timeout=1.0: False)
    monkeypatch.setattr("doorlab.hardware.serve.lcm_delivers", protocol.lcm_delivers)
    assert main(["sim-driver", "--out", str(out), "--force"]) == 1
    err = capsys.readouterr().err.strip()
    assert "delivers nothing" in err and "ip route add 224.0.0.0/4 dev lo" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gt"]
    assert sorted(p.name for p in out.iterdir()) == before


def _one_process_episode(q_target: np.ndarray, t_final: float):
    """The module docstring's recipe: the driver and a client made of Drake's C++ LCM systems
    (status receiver, command sender publishing every 5 ms from 0.3 s) on one memq bus."""
    from pydrake.manipulation import IiwaCommandSender, IiwaControlMode, IiwaStatusReceiver
    from pydrake.systems.lcm import LcmInterfaceSystem, LcmPublisherSystem, LcmSubscriberSystem
    from pydrake.systems.primitives import ConstantVectorSource

    lcm = DrakeLcm("memq://")
    builder = DiagramBuilder()
    builder.AddSystem(LcmInterfaceSystem(lcm))
    scenario = Scenario()
    scenario.timeline.log_period = 0.005  # a ground-truth sample at every status
    driver = add_sim_driver(builder, lcm, scenario, read_bus="caller", record=True)
    status_sub = builder.AddSystem(
        LcmSubscriberSystem.Make(
            IIWA_STATUS_CHANNEL, lcmt_iiwa_status, lcm, use_cpp_serializer=True
        )
    )
    status = builder.AddSystem(IiwaStatusReceiver(7))
    builder.Connect(status_sub.get_output_port(), status.get_input_port())
    sender = builder.AddSystem(IiwaCommandSender(7, IiwaControlMode.kPositionAndTorque))
    target = builder.AddSystem(ConstantVectorSource(q_target))
    zero = builder.AddSystem(ConstantVectorSource(np.zeros(7)))
    builder.Connect(target.get_output_port(), sender.get_position_input_port())
    builder.Connect(zero.get_output_port(), sender.get_torque_input_port())
    publisher = builder.AddSystem(
        LcmPublisherSystem.Make(
            IIWA_COMMAND_CHANNEL,
            lcmt_iiwa_command,
            lcm,
            publish_period=0.005,
            publish_offset=0.3,
            use_cpp_serializer=True,
        )
    )
    builder.Connect(sender.get_output_port(), publisher.get_input_port())
    simulator = Simulator(builder.Build())
    ResetIntegratorFromFlags(simulator, "explicit_euler", scenario.station.time_step)
    context = simulator.get_mutable_context()
    driver.initialize(context)
    simulator.set_monitor(driver.start_guard_monitor())
    simulator.AdvanceTo(0.3)
    simulator.clear_monitor()
    driver.advance_to(simulator, t_final)
    measured = status.get_position_measured_output_port().Eval(status.GetMyContextFromRoot(context))
    return driver.ground_truth(context), measured


def test_one_process_with_a_drake_client_is_deterministic():
    """Driver and client in one diagram on memq:// repeat bit for bit; the client's commands
    act (after the guard) and its status receiver reads the plant's state."""
    q_target = Q_HOME.copy()
    q_target[[0, 3]] = [0.2, -2.0]
    first, measured = _one_process_episode(q_target, 2.0)
    second, _ = _one_process_episode(q_target, 2.0)
    np.testing.assert_array_equal(first.plant_state, second.plant_state)
    # The command sent at 0.3 s reaches the bus before that cycle's events (a quarter
    # millisecond later): applied from the cycle of 0.3 s, reported from 0.305 s on.
    assert np.abs(first.q_commanded[first.t < 0.305 - 1e-9] - Q_HOME).max() < 1e-12
    assert np.all(first.q_commanded[first.t > 0.305 - 1e-9] == q_target)
    # The client has read the status of 1.995 s (the one of 2.0 s is read at the next step):
    # it carries the plant's state at that instant.
    np.testing.assert_array_equal(measured, first.q_measured[np.isclose(first.t, 1.995)][0])
    assert np.abs(first.q_measured[-1] - q_target).max() < 0.02  # settling (zeta 0.12)


def test_a_malformed_command_ends_the_run():
    """A command with 3 joints stops the driver (status failed, exit 1) with the reason."""
    driver = SimDriver(Scenario(), lcm_url="memq://")

    def handle(data: bytes) -> None:
        if lcmt_iiwa_status.decode(data).utime == 300_000:
            message = lcmt_iiwa_command()
            message.num_joints = 3
            message.joint_position = [0.0, 0.0, 0.0]
            driver.lcm.Publish(IIWA_COMMAND_CHANNEL, message.encode())

    driver.lcm.Subscribe(IIWA_STATUS_CHANNEL, handle)
    outcome = driver.run(duration=0.5, realtime_rate=0.0)
    assert (outcome.status, outcome.exit_code) == ("failed", 1)
    assert "num_joints = 7" in outcome.message and outcome.sim_time_s < 0.31


def test_a_command_with_utime_minus_one_means_no_command():
    """kuka_driver treats a command whose utime is -1 as none: the arm holds its start pose
    with zero feed-forward torque, until a valid command comes again."""
    cell = InProcessCell()
    cell.advance(0.3)
    q = Q_HOME.copy()
    q[[0, 3]] = [0.1, -2.0]
    tau = np.full(7, 0.3)
    cell.command(q, tau, utime=300_000)
    cell.advance(0.4)
    cell.command(q, tau, utime=-1)
    cell.advance(0.5)
    cell.command(q, tau, utime=500_000)
    cell.advance(0.6)
    truth = cell.truth()

    def at(t: float) -> int:
        return int(np.argmin(np.abs(truth.t - t)))

    np.testing.assert_array_equal(truth.q_commanded[at(0.35)], q)
    np.testing.assert_array_equal(truth.tau_feedforward[at(0.35)], tau)
    assert np.abs(truth.q_commanded[at(0.45)] - Q_HOME).max() < 1e-12  # unclamped start pose
    np.testing.assert_array_equal(truth.tau_feedforward[at(0.45)], np.zeros(7))
    np.testing.assert_array_equal(truth.q_commanded[at(0.55)], q)
    np.testing.assert_array_equal(truth.tau_feedforward[at(0.55)], tau)


def test_the_external_torque_stop():
    """kuka_driver's freeze: the gripper closed on the handle of a door whose hinge is damped
    at 1e5 N m s/rad, the arm told to turn joint 1 by 0.1 rad (the spring's 133 N m against a
    door that barely moves): at the first cycle whose |tau_external| exceeds 60 N m x (1, 1,
    1, 0.5, 0.2, 0.2, 0.1) the driver stops (SimDriver.run: aborted, exit 1, one line naming
    the joint, the torque and the limit); that cycle's status is not sent and the torques of
    every status sent are within the limits; the ground truth is written."""
    from doorlab.constants import Q_GRASP
    from doorlab.hardware.protocol import EXTERNAL_TORQUE_LIMITS

    scenario = Scenario()
    scenario.station.hinge_damping = 1e5
    driver = SimDriver(scenario, lcm_url="memq://", record=True, q_initial=Q_GRASP)
    statuses = []

    def handle(data: bytes) -> None:
        status = lcmt_iiwa_status.decode(data)
        statuses.append(status)
        if status.utime >= 300_000:  # after the start guard: hold, grip, then turn
            q = Q_GRASP.copy()
            q[0] += 0.1 if status.utime >= 800_000 else 0.0
            message = lcmt_iiwa_command()
            message.utime = status.utime
            message.num_joints = 7
            message.joint_position = list(q)
            driver.lcm.Publish(IIWA_COMMAND_CHANNEL, message.encode())
            wsg = lcmt_schunk_wsg_command()
            wsg.target_position_mm, wsg.force = 5.0, 15.0
            driver.lcm.Publish(WSG_COMMAND_CHANNEL, wsg.encode())

    driver.lcm.Subscribe(IIWA_STATUS_CHANNEL, handle)
    outcome = driver.run(duration=3.0, realtime_rate=0.0)
    assert (outcome.status, outcome.exit_code) == ("aborted", 1), outcome.message
    message = outcome.message
    assert "\n" not in message and message.startswith("external torque")
    assert "iiwa_joint_" in message and "kuka_driver's limit" in message
    assert 0.8 < outcome.sim_time_s < 3.0
    sent = np.array([s.joint_torque_external for s in statuses])
    assert np.all(np.abs(sent) <= EXTERNAL_TORQUE_LIMITS)
    assert statuses[-1].utime * 1e-6 < outcome.sim_time_s  # the stopping cycle's is not sent
    truth = driver.ground_truth()
    assert truth.t[-1] > 0.8 and np.abs(truth.tau_external).max() > 1.0
