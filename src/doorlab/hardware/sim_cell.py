"""doorlab's simulated cell behind the real drivers' LCM protocol, as a diagram
(``doorlab sim-driver`` runs it as a process: :mod:`doorlab.hardware.sim_driver`).

The same station as an episode (:func:`doorlab.station.build_station`: plant, inner loop,
gripper controller), started as an episode starts (q_home, the gripper's initial width, the
doors open or closed), speaking the protocol of :mod:`doorlab.hardware.protocol` as the
drivers behave:

- ``IIWA_STATUS`` every 5 ms of simulated time (slots k x 5 ms, the first at t = 0, each
  sent just after the plant step at its slot, see below), paced to real time (a status goes
  out when the wall clock reaches its slot): ``joint_position_measured`` and
  ``joint_velocity_estimated`` (the plant's; exact, where the real driver filters),
  ``joint_position_commanded`` (the command the inner loop tracks, after the clamp below),
  ``joint_torque_commanded`` (the station's ``iiwa_torque_commanded``: what the joints
  receive), ``joint_torque_measured`` (the same: a perfect joint torque sensor),
  ``joint_torque_external`` (the contact torques on the arm's joints); ``joint_position_ipo``
  is zero (Drake's IiwaStatusSender fills it so).
- **utime** is its slot's simulation time in microseconds (0 at the first status, exact
  multiples of 5000), not the epoch; with ``utime_warmup`` the first 200 statuses carry -1,
  as the real driver's do until its clock filter is ready.
- ``SCHUNK_WSG_STATUS`` every 50 ms (20 Hz; the real driver is a little slower), utime the
  simulation time [us]: finger separation [mm], its rate [mm/s], grip force [N].
- ``IIWA_COMMAND`` (position and torque): ``joint_position`` (clamped to the joint limits less
  1 deg) -> the station's ``iiwa_position``, ``joint_torque`` -> ``iiwa_feedforward_torque``.
  ``SCHUNK_WSG_COMMAND``: ``target_position_mm`` / 1000 -> ``wsg_position``, ``force`` ->
  ``wsg_force_limit``. The newest command is applied from the next plant step after it is
  read and held when commands stop; until the first command the arm holds its start pose
  (not clamped: q_home's joint 4, -2.094 rad, is within 1 deg of its limit, so a command of
  q_home moves that joint to -2.077 rad, as on the real arm) and the gripper its initial
  width at the scenario's force limit.
- **Start guard**: a command within 0.25 s of the first status aborts the driver before the
  command reaches the plant, as kuka_driver throws and exits.

- A command whose utime is negative (kuka_driver: -1) means "no command": the arm holds its
  start pose with zero feed-forward torque until a valid command comes.

Not modelled: the real driver's external-torque stop (doorlab's contact torques stay far below
its limits, :data:`~doorlab.hardware.protocol.EXTERNAL_TORQUE_LIMITS`), KUKA's own joint
impedance (the station's inner loop with the scenario's Kq, Dq tracks the commands), and
``joint_position_ipo``.

How it runs. Only Drake's C++ systems act per plant step:

    LcmSubscriberSystem(IIWA_COMMAND) -> IiwaCommandReceiver -> gate (clamp, hold) -> station
    LcmSubscriberSystem(SCHUNK_WSG_COMMAND) -> SchunkWsgCommandReceiver -> station
    station -> IiwaStatusSender -> LcmPublisherSystem(IIWA_STATUS, 5 ms)
    station -> SchunkWsgStatusSender -> LcmPublisherSystem(SCHUNK_WSG_STATUS, 50 ms)

The timing matches an episode in one process, where the plan's command, computed at its tick
from the plant as it stands, acts from the next plant step. An ``LcmInterfaceSystem`` reads
the bus at every simulator step, and Drake's simulator sleeps at the *start* of a step to keep
pace; two C++ ticks (``ZeroOrderHold`` systems, no output used) place those steps:

- a **read tick** ``READ_LEAD`` (1 us) before every plant step: the read after its sleep
  catches every command that arrived before the step is due, and that step applies it;
- a **status tick** at each status's slot t_k (every 5 ms): the status goes out when the wall
  clock reaches t_k, ``STATUS_DELAY`` (1 us of simulation time) later, so a status on a plant
  step reports the plant after that step's update, as the one-process plan sees it.

A command for the status at t_k therefore acts from the first plant step after t_k, as in
one process, if it arrives before that step (1 ms for a status between two 2 ms steps, 2 ms
for one on a step); later, it acts a plant step (or more) later. Python runs only per
simulator call: during the start guard (0.25 s) a monitor per step checks the command count;
after it one ``AdvanceTo`` runs until the end (Drake checks for signals between steps).

Add it to a diagram with :func:`add_sim_driver`, e.g. next to a client on one
``DrakeLcm("memq://")``, deterministic (no real-time pacing)::

    lcm = DrakeLcm("memq://")
    builder = DiagramBuilder()
    builder.AddSystem(LcmInterfaceSystem(lcm))  # once per DrakeLcm, before any subscriber
    driver = add_sim_driver(builder, lcm, scenario, add_lcm_interface=False, record=True)
    ...  # the client's LcmSubscriberSystem(IIWA_STATUS), its publisher of IIWA_COMMAND
    simulator = Simulator(builder.Build())  # realtime rate 0: as fast as it computes
    ResetIntegratorFromFlags(simulator, "explicit_euler", scenario.station.time_step)
    driver.initialize(simulator.get_mutable_context())  # q_home, gripper, doors
    simulator.set_monitor(driver.start_guard_monitor())  # optional: the 0.25 s abort,
    simulator.AdvanceTo(0.25)                             # Python per step while it is set
    simulator.clear_monitor()
    simulator.AdvanceTo(24.0)
    truth = driver.ground_truth(simulator.get_context())

(``tests/test_sim_driver.py`` runs this with a client of Drake's C++ LCM systems.) On memq a
message is delivered at the bus's next read, the simulator step after it was published.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pydrake.symbolic as sym
from drake import (
    lcmt_iiwa_command,
    lcmt_iiwa_status,
    lcmt_schunk_wsg_command,
    lcmt_schunk_wsg_status,
)
from pydrake.lcm import DrakeLcm
from pydrake.manipulation import (
    IiwaCommandReceiver,
    IiwaControlMode,
    IiwaStatusSender,
    SchunkWsgCommandReceiver,
    SchunkWsgStatusSender,
)
from pydrake.systems.framework import Context, DiagramBuilder, EventStatus
from pydrake.systems.lcm import LcmInterfaceSystem, LcmPublisherSystem, LcmSubscriberSystem
from pydrake.systems.primitives import (
    ConstantVectorSource,
    Demultiplexer,
    Multiplexer,
    SymbolicVectorSystem,
    TrajectorySource,
    VectorLogSink,
    ZeroOrderHold,
)
from pydrake.trajectories import PiecewisePolynomial

from doorlab.config import Scenario
from doorlab.constants import NUM_JOINTS, Q_HOME
from doorlab.errors import ConfigError
from doorlab.hardware.ground_truth import (
    GroundTruth,
)
from doorlab.hardware.protocol import (
    DRIVER_JOINT_LIMITS,
    IIWA_COMMAND_CHANNEL,
    IIWA_STATUS_CHANNEL,
    IIWA_STATUS_PERIOD,
    JOINT_LIMIT_MARGIN,
    START_COMMAND_GUARD,
    UTIME_WARMUP_STATUSES,
    WSG_COMMAND_CHANNEL,
    WSG_STATUS_CHANNEL,
    WSG_STATUS_PERIOD,
)
from doorlab.station import Station, build_station, initialize_cell

_UTIME_HORIZON = 1e8
"""The utime source is defined up to this simulation time [s] (three years)."""
READ_LEAD = 1e-6
"""The bus is read this long before each plant step [s] (the read tick)."""
STATUS_DELAY = 1e-6
"""Each IIWA_STATUS is published this long after its slot k x 5 ms [s]: after the plant step
at that time, whose update it reports."""


def _utime_source(utime_warmup: bool) -> PiecewisePolynomial:
    """IiwaStatusSender's ``time_measured`` [s] as a function of simulation time.

    A status is sent at t = k * 5 ms + ``STATUS_DELAY`` and carries utime k * 5000: the
    sender truncates time_measured * 1e6 to an integer, and k * 0.005 * 1e6 is often a hair
    under k * 5000, so half a microsecond added makes the truncation a rounding. The warm-up
    holds -1e-6 (utime -1) until half a period before the 201st status.
    """
    offset = 0.5e-6 - STATUS_DELAY
    if not utime_warmup:
        return PiecewisePolynomial.FirstOrderHold(
            [0.0, _UTIME_HORIZON], np.array([[offset, _UTIME_HORIZON + offset]])
        )
    t_ready = (UTIME_WARMUP_STATUSES - 0.5) * IIWA_STATUS_PERIOD
    t_ramp = t_ready + 0.2 * IIWA_STATUS_PERIOD  # no status falls in [t_ready, t_ramp]
    return PiecewisePolynomial.FirstOrderHold(
        [0.0, t_ready, t_ramp, _UTIME_HORIZON],
        np.array([[-1e-6, -1e-6, t_ramp + offset, _UTIME_HORIZON + offset]]),
    )


_LOG_PORTS = (
    ("plant_state", "station", "plant_state"),
    ("q_commanded", "station", "iiwa_position_commanded"),
    ("tau_feedforward", "iiwa_command_applied", "y1"),
    ("tau_commanded", "station", "iiwa_torque_commanded"),
    ("tau_external", "station", "iiwa_torque_external"),
    ("wsg_state", "station", "wsg_state_measured"),
    ("wsg_force", "station", "wsg_force_measured"),
    ("wsg_position_commanded", "wsg_command", "position"),
    ("wsg_force_limit", "wsg_command", "force_limit"),
)
"""(channel, system, output port) of the ground-truth logger's multiplexed input."""


@dataclass(frozen=True)
class SimDriverSystems:
    """The simulated driver's systems in a diagram (returned by :func:`add_sim_driver`).

    Attributes:
        station: The station (its diagram is a subsystem named ``station``).
        iiwa_command_subscriber, wsg_command_subscriber: The command subscribers.
        iiwa_status_publisher, wsg_status_publisher: The status publishers.
        logger: The ground-truth logger (None unless ``record``).
        command_logger: The log of the applied command's utime at each plant step (None
            unless ``record``; see :meth:`command_delays`).
        scenario: The scenario the station and its initial state come from.
        q_initial: The arm's start pose (7,) [rad].
        utime_warmup: Whether the first 200 statuses carry utime -1.
        log_sizes: Sizes of the logger's channels, in the order of its input.
    """

    station: Station
    iiwa_command_subscriber: LcmSubscriberSystem
    wsg_command_subscriber: LcmSubscriberSystem
    iiwa_status_publisher: LcmPublisherSystem
    wsg_status_publisher: LcmPublisherSystem
    logger: VectorLogSink | None
    command_logger: VectorLogSink | None
    scenario: Scenario
    q_initial: np.ndarray
    utime_warmup: bool
    log_sizes: tuple[int, ...] = ()

    def initialize(self, root_context: Context) -> None:
        """Sets the cell's initial state as an episode's: q_initial, gripper, doors."""
        initialize_cell(
            self.station,
            root_context,
            q_initial=self.q_initial,
            gripper_width=self.scenario.station.gripper.initial_width,
            door_angles=self.scenario.initial_door_angles(),
        )

    def iiwa_commands_received(self) -> int:
        """How many IIWA_COMMAND messages the driver has read from the bus so far."""
        return self.iiwa_command_subscriber.WaitForMessage(-1, None, 1e-9)

    def wsg_commands_received(self) -> int:
        """How many SCHUNK_WSG_COMMAND messages the driver has read from the bus so far."""
        return self.wsg_command_subscriber.WaitForMessage(-1, None, 1e-9)

    def start_guard_monitor(
        self, guard: float = START_COMMAND_GUARD
    ) -> Callable[[Context], EventStatus]:
        """A Simulator monitor that ends the simulation when a command is read within
        ``guard`` [s] of simulation time of the first status (t = 0), before it acts.

        The simulator then stops with a "reached termination" status whose message starts
        with "start guard". It runs Python at every simulator step: clear it
        (``simulator.clear_monitor()``) once the guard is over.
        """

        def monitor(context: Context) -> EventStatus:
            t = context.get_time()
            if t < guard and self.iiwa_commands_received() > 0:
                return EventStatus.ReachedTermination(
                    self.iiwa_command_subscriber, start_guard_message(guard, t)
                )
            return EventStatus.DidNothing()

        return monitor

    def command_delays(self, root_context: Context) -> np.ndarray:
        """For each IIWA_COMMAND the plant applied (needs ``record=True``): how many plant
        steps after the first step following its status (the command's utime) it first acted
        (0: as in one process; 1: it arrived after that step's read tick).

        Returns:
            (m,) int: one entry per command, in the order applied.
        """
        if self.command_logger is None:
            raise ConfigError("the driver was built without record=True: no command log")
        log = self.command_logger.FindLog(root_context)
        t, utime = log.sample_times(), log.data()[0]
        h = self.scenario.station.time_step
        # Before any message the receiver's time is 0: a new command is a change of it
        # (so one answering the first status, utime 0, is not told apart: the start guard
        # aborts on it anyway); a negative utime is "no command".
        first = np.flatnonzero(np.diff(utime) != 0) + 1
        first = first[utime[first] >= 0]
        due = (np.floor(utime[first] / h + 1e-6) + 1) * h
        return np.rint((t[first] - due) / h).astype(int)

    def ground_truth(self, root_context: Context) -> GroundTruth:
        """The logged ground truth up to the context's time (needs ``record=True``): at each
        log slot T, the cell just after the plant step at T (as a status at T reports it),
        up to the last slot a log period before the context's time."""
        if self.logger is None:
            raise ConfigError("the driver was built without record=True: no ground truth")
        log = self.logger.FindLog(root_context)
        # The logger's entry at slot j holds the sample taken just after slot j - 1 (its first
        # entry, at t = 0, the hold's initial value): each sample is put at its own slot.
        t = log.sample_times()[1:] - self.scenario.timeline.log_period
        samples = log.data().T[1:]
        columns = np.cumsum([0, *self.log_sizes])
        data = {
            name: samples[:, start:end]
            for (name, _, _), start, end in zip(_LOG_PORTS, columns[:-1], columns[1:], strict=True)
        }
        return GroundTruth.from_channels(self.station, t, data, utime_warmup=self.utime_warmup)


def start_guard_message(guard: float = START_COMMAND_GUARD, after: float | None = None) -> str:
    """The abort's message (kuka_driver: "First command received within guard time").

    Args:
        guard: The guard [s]. after: When the command was read, after the first status [s].
    """
    when = "" if after is None else f" (read {after:.3f} s after it)"
    return (
        f"start guard: an IIWA_COMMAND arrived within {guard:g} s of the first status{when}; "
        "the driver aborts, as the real one does (wait before the first command)"
    )


_NO_MESSAGE_POSITION = 1e6
"""The command receiver's "measured position" input [rad]: its position output before the
first message, far outside any joint's range, marks "no command yet"."""
_NO_MESSAGE_THRESHOLD = 100.0
"""A receiver position above this [rad] is the no-message marker."""


def _command_gate(q_initial: np.ndarray) -> SymbolicVectorSystem:
    """u = [p (7), tau (7), t_cmd (1)] -> [q_ref (7), tau_ff (7)], as kuka_driver applies a
    command: p clamped to the joint limits less 1 deg, tau as sent; while there is no command
    (p is the receiver's no-message marker, or the command's utime is negative: -1 means
    "no command") the start pose ``q_initial``, unclamped, and zero torque.

    A ``SymbolicVectorSystem``: its expressions are evaluated in C++.
    """
    u = sym.MakeVectorVariable(2 * NUM_JOINTS + 1, "u")
    p, tau, t_cmd = u[:NUM_JOINTS], u[NUM_JOINTS : 2 * NUM_JOINTS], u[-1]
    limit = DRIVER_JOINT_LIMITS - JOINT_LIMIT_MARGIN
    none = sym.logical_or(p[0] > _NO_MESSAGE_THRESHOLD, t_cmd < 0)
    q_ref = [
        sym.if_then_else(none, float(q0), sym.min(sym.max(p_i, -float(lim)), float(lim)))
        for p_i, q0, lim in zip(p, q_initial, limit, strict=True)
    ]
    tau_ff = [sym.if_then_else(none, 0.0, tau_i) for tau_i in tau]
    return SymbolicVectorSystem(input=u, output=np.array(q_ref + tau_ff))


def _add_iiwa_command(builder: DiagramBuilder, lcm: DrakeLcm, station_system, q_initial):
    """IIWA_COMMAND -> the station's q_ref and tau_ff, as kuka_driver applies commands.

    The newest message, decoded in C++ (IiwaCommandReceiver, position and torque), then
    :func:`_command_gate`. kuka_driver clamps only what it answers LCM with: until the first
    command the arm holds ``q_initial`` unclamped (q_home's joint 4, -2.094 rad, lies within
    1 deg of its limit). The receiver's position before any message is its "measured
    position" input, here :data:`_NO_MESSAGE_POSITION`: that is how the gate tells "no
    command yet" from a command.

    Returns:
        (the subscriber, the receiver, the applied command: a Demultiplexer, outputs q_ref
        and tau_ff).
    """

    def add(name: str, system):
        return builder.AddNamedSystem(name, system)

    subscriber = add(
        "iiwa_command_subscriber",
        LcmSubscriberSystem.Make(
            IIWA_COMMAND_CHANNEL, lcmt_iiwa_command, lcm, use_cpp_serializer=True
        ),
    )
    receiver = add(
        "iiwa_command", IiwaCommandReceiver(NUM_JOINTS, IiwaControlMode.kPositionAndTorque)
    )
    builder.Connect(subscriber.get_output_port(), receiver.get_message_input_port())
    marker = add(
        "no_command_marker", ConstantVectorSource(np.full(NUM_JOINTS, _NO_MESSAGE_POSITION))
    )
    builder.Connect(marker.get_output_port(), receiver.get_position_measured_input_port())
    inputs = add("iiwa_command_gate_input", Multiplexer([NUM_JOINTS, NUM_JOINTS, 1]))
    builder.Connect(receiver.get_commanded_position_output_port(), inputs.get_input_port(0))
    builder.Connect(receiver.get_commanded_torque_output_port(), inputs.get_input_port(1))
    builder.Connect(receiver.GetOutputPort("time"), inputs.get_input_port(2))
    gate = add("iiwa_command_gate", _command_gate(np.asarray(q_initial, float)))
    builder.Connect(inputs.get_output_port(), gate.get_input_port())
    applied = add("iiwa_command_applied", Demultiplexer([NUM_JOINTS, NUM_JOINTS]))
    builder.Connect(gate.get_output_port(), applied.get_input_port())
    builder.Connect(applied.get_output_port(0), station_system.GetInputPort("iiwa_position"))
    builder.Connect(
        applied.get_output_port(1), station_system.GetInputPort("iiwa_feedforward_torque")
    )
    return subscriber, receiver, applied


def _add_wsg_command(builder: DiagramBuilder, lcm: DrakeLcm, station_system, gripper):
    """SCHUNK_WSG_COMMAND -> the station's wsg_position [m] and wsg_force_limit [N]; until the
    first command the gripper's initial width and force limit. Returns (subscriber, receiver).
    """
    subscriber = builder.AddNamedSystem(
        "wsg_command_subscriber",
        LcmSubscriberSystem.Make(
            WSG_COMMAND_CHANNEL, lcmt_schunk_wsg_command, lcm, use_cpp_serializer=True
        ),
    )
    receiver = builder.AddNamedSystem(
        "wsg_command",
        SchunkWsgCommandReceiver(
            initial_position=gripper.initial_width, initial_force=gripper.force_limit
        ),
    )
    builder.Connect(subscriber.get_output_port(), receiver.GetInputPort("command_message"))
    builder.Connect(
        receiver.get_position_output_port(), station_system.GetInputPort("wsg_position")
    )
    builder.Connect(
        receiver.get_force_limit_output_port(), station_system.GetInputPort("wsg_force_limit")
    )
    return subscriber, receiver


def _add_statuses(
    builder: DiagramBuilder,
    lcm: DrakeLcm,
    station_system,
    plant_step: float,
    utime_warmup: bool,
):
    """The station's outputs -> IIWA_STATUS every 5 ms and SCHUNK_WSG_STATUS every 50 ms, and
    the read and status ticks (``plant_step``: the plant's step h [s]).
    Returns (iiwa publisher, wsg publisher)."""

    def add(name: str, system):
        return builder.AddNamedSystem(name, system)

    iiwa_status = add("iiwa_status", IiwaStatusSender(NUM_JOINTS))
    for sender_port, station_port in (
        ("position_commanded", "iiwa_position_commanded"),
        ("position_measured", "iiwa_position_measured"),
        ("velocity_estimated", "iiwa_velocity_estimated"),
        ("torque_commanded", "iiwa_torque_commanded"),
        ("torque_external", "iiwa_torque_external"),
    ):  # torque_measured left open: the sender reports torque_commanded
        builder.Connect(
            station_system.GetOutputPort(station_port), iiwa_status.GetInputPort(sender_port)
        )
    utime = add("status_utime", TrajectorySource(_utime_source(utime_warmup)))
    builder.Connect(utime.get_output_port(), iiwa_status.GetInputPort("time_measured"))

    def publisher(name: str, channel: str, lcm_type: type, period: float, offset: float, sender):
        system = add(
            name,
            LcmPublisherSystem.Make(
                channel,
                lcm_type,
                lcm,
                publish_period=period,
                publish_offset=offset,
                use_cpp_serializer=True,
            ),
        )
        builder.Connect(sender.get_output_port(), system.get_input_port())
        return system

    iiwa_pub = publisher(
        "iiwa_status_publisher",
        IIWA_STATUS_CHANNEL,
        lcmt_iiwa_status,
        IIWA_STATUS_PERIOD,
        STATUS_DELAY,
        iiwa_status,
    )
    wsg_status = add("wsg_status", SchunkWsgStatusSender())
    builder.Connect(
        station_system.GetOutputPort("wsg_state_measured"), wsg_status.get_state_input_port()
    )
    builder.Connect(
        station_system.GetOutputPort("wsg_force_measured"), wsg_status.get_force_input_port()
    )
    wsg_pub = publisher(
        "wsg_status_publisher",
        WSG_STATUS_CHANNEL,
        lcmt_schunk_wsg_status,
        WSG_STATUS_PERIOD,
        0.0,
        wsg_status,
    )

    # The read and status ticks (module docstring): simulator steps that start READ_LEAD
    # before every plant step and at every status slot (C++, no output used).
    tick_input = add("tick_input", ConstantVectorSource([0.0]))
    h = plant_step
    for name, period, offset in (
        ("read_tick", h, h - READ_LEAD),
        ("status_tick", IIWA_STATUS_PERIOD, 0.0),
    ):
        tick = add(name, ZeroOrderHold(period, 1, offset_sec=offset))
        builder.Connect(tick_input.get_output_port(), tick.get_input_port())
    return iiwa_pub, wsg_pub


def add_sim_driver(
    builder: DiagramBuilder,
    lcm: DrakeLcm,
    scenario: Scenario,
    *,
    q_initial: np.ndarray = Q_HOME,
    utime_warmup: bool = False,
    record: bool = False,
    add_lcm_interface: bool = True,
) -> SimDriverSystems:
    """Adds doorlab's station behind the drivers' LCM protocol to ``builder``.

    Args:
        builder: The diagram to add to.
        lcm: The LCM bus (``DrakeLcm(url)``; ``DrakeLcm("memq://")`` for one process).
        scenario: A validated scenario: the station (physics, inner loop, gripper) and the
            initial state (doors, gripper width); ``timeline.log_period`` is the ground
            truth's sample period.
        q_initial: The arm's start pose (7,) [rad] (the episode's: q_home).
        utime_warmup: Send utime -1 in the first 200 statuses, as the real driver does.
        record: Log the ground truth (see :meth:`SimDriverSystems.ground_truth`).
        add_lcm_interface: Add the ``LcmInterfaceSystem`` that reads ``lcm`` at every step
            (added first, before the subscribers). Pass False when the diagram already has
            one for this ``lcm`` (one per bus), added before this call.

    Returns:
        The systems (call :meth:`SimDriverSystems.initialize` on the simulator's context).
    """
    if add_lcm_interface:
        builder.AddNamedSystem("lcm_interface", LcmInterfaceSystem(lcm))
    station = build_station(scenario.station)
    station_system = builder.AddNamedSystem("station", station.diagram)
    q_initial = np.asarray(q_initial, float).copy()
    iiwa_sub, iiwa_receiver, iiwa_command = _add_iiwa_command(
        builder, lcm, station_system, q_initial
    )
    wsg_sub, wsg_command = _add_wsg_command(builder, lcm, station_system, scenario.station.gripper)
    iiwa_pub, wsg_pub = _add_statuses(
        builder, lcm, station_system, scenario.station.time_step, utime_warmup
    )

    logger = command_logger = None
    log_sizes: tuple[int, ...] = ()
    if record:
        # At every plant step t_n (logged at the end of the step ending there, after the read
        # tick): the utime [s] of the status that the command the step applies answers.
        command_logger = builder.AddNamedSystem(
            "applied_command_logger", VectorLogSink(1, scenario.station.time_step)
        )
        builder.Connect(iiwa_receiver.GetOutputPort("time"), command_logger.get_input_port())
        systems = {
            "station": station_system,
            "iiwa_command_applied": iiwa_command,
            "wsg_command": wsg_command,
        }
        ports = [systems[system].GetOutputPort(port) for _, system, port in _LOG_PORTS]
        log_sizes = tuple(p.size() for p in ports)
        mux = builder.AddNamedSystem("ground_truth_channels", Multiplexer(list(log_sizes)))
        for i, port in enumerate(ports):
            builder.Connect(port, mux.get_input_port(i))
        # Sampled as a status is: STATUS_DELAY after each slot, after the plant step there
        # (a hold), logged at the next slot; ground_truth() puts each sample at its slot.
        size, period = mux.get_output_port().size(), scenario.timeline.log_period
        hold = builder.AddNamedSystem(
            "ground_truth_sample", ZeroOrderHold(period, size, offset_sec=STATUS_DELAY)
        )
        builder.Connect(mux.get_output_port(), hold.get_input_port())
        logger = builder.AddNamedSystem("ground_truth_logger", VectorLogSink(size, period))
        builder.Connect(hold.get_output_port(), logger.get_input_port())

    return SimDriverSystems(
        station=station,
        iiwa_command_subscriber=iiwa_sub,
        wsg_command_subscriber=wsg_sub,
        iiwa_status_publisher=iiwa_pub,
        wsg_status_publisher=wsg_pub,
        logger=logger,
        command_logger=command_logger,
        scenario=scenario,
        q_initial=q_initial,
        utime_warmup=utime_warmup,
        log_sizes=log_sizes,
    )
