"""doorlab's simulated arm behind the real drivers' LCM protocol, as a diagram (``doorlab
sim-driver`` runs it as a process: :mod:`doorlab.hardware.sim_driver`).

The arm is :func:`doorlab.cell.arm_cell.build_arm_cell`'s: the station (the scenario's physics and
inner loop: ``kuka_joint_impedance`` for KUKA's loop) behind kuka_driver's cycle, the same
cell a one-process run with ``station.driver.timing: kuka_driver`` builds, from the same
scenario fields. Around it, the protocol as the drivers speak it (:mod:`doorlab.kuka`, read
from drake-iiwa-driver's ``kuka-driver/kuka_driver.cc``):

- each cycle t_k = k x 5 ms (events ``c`` after it, :func:`doorlab.cell.arm_cell.cycle_offset`):
  the newest ``IIWA_COMMAND`` read before the cycle is applied from it on (``joint_position``
  clamped to the joint limits less 1 deg, ``joint_torque`` the feed-forward torque); then the
  external torques are checked (over kuka_driver's limits the driver stops, as it exits); then
  ``IIWA_STATUS`` goes out with this cycle's state: ``joint_position_measured``,
  ``joint_velocity_estimated`` (kuka_driver's 40 Hz low-pass of the finite difference),
  ``joint_position_commanded`` (the command the arm tracked up to this cycle),
  ``joint_torque_commanded`` = ``joint_torque_measured`` (what the joints receive),
  ``joint_torque_external`` (KUKA's estimate: the contact torques on the arm's joints plus
  what its load data leaves out, plus noise, :mod:`doorlab.cell.arm_model`); ``joint_position_ipo``
  is zero (Drake's IiwaStatusSender). A client that answers status k before cycle k + 1 gets
  exactly the same episode however fast it is; a later answer acts a cycle (or more) later,
  and the driver counts those (:meth:`SimDriverSystems.command_delays`).
- **utime** is the cycle's simulation time in microseconds (0 at the first status, exact
  multiples of 5000), not the epoch; with ``utime_warmup`` the first 200 statuses carry -1,
  as the real driver's do until its clock filter is ready.
- No command yet, or one whose utime is negative (kuka_driver: -1, "no command"): the arm
  holds its start pose (not clamped: q_home's joint 4, -2.094 rad, is within 1 deg of its
  limit, so a command of q_home moves it to -2.077 rad, as on the arm) with no torque. Until
  the first command is applied the arm and fingers stand still (locked joints,
  :meth:`SimDriverSystems.advance_to`).
- ``SCHUNK_WSG_COMMAND``: ``target_position_mm`` / 1000 and ``force``, applied at the arm's
  next cycle; until the first, the gripper's initial width and force limit.
  ``SCHUNK_WSG_STATUS`` every 50 ms (20 Hz; the real driver is a little slower): finger
  separation [mm], its rate [mm/s], grip force [N].
- **Start guard**: a command within 0.25 s of the first status aborts the driver before the
  command reaches the plant, as kuka_driver throws and exits.

Not modelled: ``joint_position_ipo``; the schunk driver's own 50 ms loop (its commands act at
the arm's next cycle).

How it runs. Only Drake's C++ systems act per plant step:

    LcmSubscriberSystem(IIWA_COMMAND) -> IiwaCommandReceiver -> the arm cell
    LcmSubscriberSystem(SCHUNK_WSG_COMMAND) -> SchunkWsgCommandReceiver -> the arm cell
    the arm cell's status -> IiwaStatusSender -> LcmPublisherSystem(IIWA_STATUS, 5 ms)
    the arm cell -> SchunkWsgStatusSender -> LcmPublisherSystem(SCHUNK_WSG_STATUS, 50 ms)

An ``LcmInterfaceSystem`` reads the bus at every simulator step, and Drake's simulator sleeps
at the *start* of a step to keep pace; a **read tick** (a C++ ``ZeroOrderHold``, no output
used) places a step ``READ_LEAD`` (1 us) before each cycle's events, so the read after its
sleep catches every command that arrived before the cycle is due. Each status leaves
``STATUS_DELAY`` (1 us) after the cycle's events. Python runs once per simulator call (per
cycle until the first command is applied, and per cycle in the external-torque check: 200 Hz,
not per plant step); during the start guard (0.25 s) a monitor checks each step.

Who reads the bus (``read_bus``): an ``LcmInterfaceSystem`` at every step (``doorlab
sim-driver``: its bus has only C++ subscribers), or, for a client in this process on
``memq://`` whose handlers are Python, :meth:`SimDriverSystems.advance_to` from Python just
after each status goes out. An ``LcmInterfaceSystem`` must never read a bus with Python
handlers: it does so inside ``Simulator.AdvanceTo``, where pydrake builds the handler's bytes
without the GIL, a segmentation fault on Python >= 3.12 (:mod:`doorlab.hardware.link`,
issue 45).

Add it to a diagram with :func:`add_sim_driver`, e.g. next to a client of Drake's C++ LCM
systems on one ``DrakeLcm("memq://")``, deterministic (no real-time pacing)::

    lcm = DrakeLcm("memq://")
    builder = DiagramBuilder()
    builder.AddSystem(LcmInterfaceSystem(lcm))  # once per DrakeLcm, before any subscriber
    driver = add_sim_driver(builder, lcm, scenario, read_bus="caller", record=True)
    ...  # the client's LcmSubscriberSystem(IIWA_STATUS), its publisher of IIWA_COMMAND
    simulator = Simulator(builder.Build())  # realtime rate 0: as fast as it computes
    ResetIntegratorFromFlags(simulator, "explicit_euler", scenario.station.time_step)
    driver.initialize(simulator.get_mutable_context())  # q_home, gripper, doors; locked
    simulator.set_monitor(driver.start_guard_monitor())  # optional: the 0.25 s abort,
    simulator.AdvanceTo(0.25)                             # Python per step while it is set
    simulator.clear_monitor()
    driver.advance_to(simulator, 24.0)  # frees the arm at the first command's cycle
    truth = driver.ground_truth(simulator.get_context())

(``tests/test_sim_driver.py`` runs this with a client of Drake's C++ LCM systems.) On memq a
message is delivered at the bus's next read, the simulator step after it was published.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pydrake.lcm import DrakeLcm
from pydrake.systems.analysis import Simulator, SimulatorStatus
from pydrake.systems.framework import Context, DiagramBuilder, EventStatus
from pydrake.systems.lcm import LcmInterfaceSystem, LcmPublisherSystem, LcmSubscriberSystem
from pydrake.systems.primitives import (
    Multiplexer,
    VectorLogSink,
    ZeroOrderHold,
)

from doorlab.cell.arm_cell import (
    STATUS_SIZE,
    STATUS_SLICES,
    WATCH_DELAY,
    ArmCell,
    ExternalTorqueWatch,
    build_arm_cell,
    read_cycle_log,
)
from doorlab.cell.station import Station
from doorlab.config import Scenario
from doorlab.constants import Q_HOME
from doorlab.errors import ConfigError
from doorlab.hardware.ground_truth import GroundTruth
from doorlab.hardware.protocol import (
    IIWA_STATUS_PERIOD,
    START_COMMAND_GUARD,
)
from doorlab.hardware.sim_bus import (
    STATUS_DELAY,
    add_iiwa_command,
    add_statuses,
    add_wsg_command,
)

READ_BUS = ("every_step", "every_cycle", "caller")
"""Who reads the bus (:func:`add_sim_driver`)."""


_GROUND_TRUTH_PORTS = (
    ("plant_state", "plant_state"),
    ("status", "status"),
    ("wsg_state", "wsg_state_measured"),
    ("wsg_force", "wsg_force_measured"),
)
"""(channel, the arm cell's output port) of the ground-truth logger's multiplexed input."""


@dataclass(frozen=True)
class SimDriverSystems:
    """The simulated driver's systems in a diagram (returned by :func:`add_sim_driver`).

    Attributes:
        arm: The arm cell (:class:`doorlab.cell.arm_cell.ArmCell`; a subsystem named ``arm``).
        iiwa_command_subscriber, wsg_command_subscriber: The command subscribers.
        iiwa_status_publisher, wsg_status_publisher: The status publishers.
        logger: The ground-truth logger (None unless ``record``).
        command_logger: The applied command's utime at each cycle (None unless ``record``;
            see :meth:`command_delays`).
        cycle_logger: Every cycle's status (None unless ``record``; :meth:`cycle_log`).
        scenario: The scenario the arm and its initial state come from.
        utime_warmup: Whether the first 200 statuses carry utime -1.
        log_sizes: Sizes of the ground-truth logger's channels, in the order of its input.
        lcm: The bus. read_bus: Who reads it (:data:`READ_BUS`; :func:`add_sim_driver`).
    """

    arm: ArmCell
    iiwa_command_subscriber: LcmSubscriberSystem
    wsg_command_subscriber: LcmSubscriberSystem
    iiwa_status_publisher: LcmPublisherSystem
    wsg_status_publisher: LcmPublisherSystem
    logger: VectorLogSink | None
    command_logger: VectorLogSink | None
    cycle_logger: VectorLogSink | None
    scenario: Scenario
    utime_warmup: bool
    log_sizes: tuple[int, ...] = ()
    lcm: DrakeLcm | None = None
    read_bus: str = "every_step"

    @property
    def station(self) -> Station:
        """The station inside the arm cell."""
        return self.arm.station

    @property
    def q_initial(self) -> np.ndarray:
        """The arm's start pose (7,) [rad]."""
        return self.arm.q_initial

    @property
    def status_offset(self) -> float:
        """The status of cycle k goes out at k x 5 ms + this [s]."""
        return self.arm.offset + STATUS_DELAY

    def initialize(self, root_context: Context) -> None:
        """Sets the cell's initial state as an episode's: q_initial, gripper, doors, no
        command, the arm and fingers locked until the first command."""
        self.arm.initialize(root_context, door_angles=self.scenario.initial_door_angles())

    def advance_to(self, simulator: Simulator, t: float) -> SimulatorStatus | None:
        """``simulator.AdvanceTo(t)``; while the arm is locked, one cycle at a time, freeing it
        right after the cycle that applied the first command (before the next plant step).
        With ``read_bus="every_cycle"`` it reads the bus from Python first (what was
        published since the last call), then just after each status goes out on the way
        (:attr:`status_offset` after each cycle): every handler, the client's too, runs with
        the GIL held, and on memq:// a command published by a handler that answers the status
        is delivered in the same read, before the next cycle.

        Returns:
            The last call's status (it stops early when a monitor ends the simulation), or
            None when the simulator already stood at ``t``.
        """
        status = None
        if self.read_bus == "every_cycle":
            context = simulator.get_context()
            offset = self.status_offset  # status k goes out at k x 5 ms + offset
            k = math.floor((context.get_time() - offset) / IIWA_STATUS_PERIOD + 1e-9) + 1
            self.lcm.HandleSubscriptions(0)
            while (t_read := k * IIWA_STATUS_PERIOD + offset) <= t:
                status = self._advance(simulator, t_read)
                if status is not None and _stopped(status):
                    return status
                self.lcm.HandleSubscriptions(0)
                k += 1
        return self._advance(simulator, t) or status

    def _advance(self, simulator: Simulator, t: float) -> SimulatorStatus | None:
        """:meth:`advance_to` without the reads."""
        context = simulator.get_mutable_context()
        status = None
        while self.arm.locked(context) and context.get_time() < t:
            k = np.floor((context.get_time() - self.status_offset) / IIWA_STATUS_PERIOD + 1e-9)
            status = simulator.AdvanceTo(min(t, (k + 1) * IIWA_STATUS_PERIOD + self.status_offset))
            if _stopped(status):
                return status
            if self.arm.command_applied(context):
                self.arm.unlock(context)
        if context.get_time() < t:
            status = simulator.AdvanceTo(t)
        return status

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
        """For each IIWA_COMMAND the arm applied (needs ``record=True``): how many cycles
        after the one following its status (the command's utime) it was first applied (0:
        kuka_driver's timing, the answer came within the period; 1: a cycle late, ...).

        Returns:
            (m,) int: one entry per command, in the order applied.
        """
        if self.command_logger is None:
            raise ConfigError("the driver was built without record=True: no command log")
        log = self.command_logger.FindLog(root_context)
        t, utime = log.sample_times(), log.data()[0]
        # Entry j (at j x 5 ms) holds the utime [s] latched at cycle j - 1; before any
        # message the receiver's time is 0, so a new command is a change of it (one
        # answering the first status, utime 0, is not told apart: the start guard aborts on
        # it anyway); a negative utime is "no command".
        cycle = np.rint(t / IIWA_STATUS_PERIOD).astype(int) - 1
        first = np.flatnonzero(np.diff(utime) != 0) + 1
        first = first[utime[first] >= 0]
        answered = np.rint(utime[first] / IIWA_STATUS_PERIOD).astype(int)
        return cycle[first] - (answered + 1)

    def cycle_log(self, root_context: Context) -> dict[str, np.ndarray]:
        """Every cycle's status (needs ``record=True``;
        :func:`doorlab.cell.arm_cell.read_cycle_log`)."""
        if self.cycle_logger is None:
            raise ConfigError("the driver was built without record=True: no cycle log")
        return read_cycle_log(self.cycle_logger, root_context)

    def ground_truth(self, root_context: Context) -> GroundTruth:
        """The logged ground truth up to the context's time (needs ``record=True``): at each
        log slot T, the plant just after its step at T and the last status at or before T,
        up to the last slot a log period before the context's time."""
        if self.logger is None:
            raise ConfigError("the driver was built without record=True: no ground truth")
        log = self.logger.FindLog(root_context)
        # The logger's entry at slot j holds the sample taken just after slot j - 1 (its first
        # entry, at t = 0, the hold's initial value): each sample is put at its own slot.
        t = log.sample_times()[1:] - self.scenario.timeline.log_period
        samples = log.data().T[1:]
        columns = np.cumsum([0, *self.log_sizes])
        raw = {
            name: samples[:, start:end]
            for (name, _), start, end in zip(
                _GROUND_TRUTH_PORTS, columns[:-1], columns[1:], strict=True
            )
        }
        status = raw.pop("status")
        data = {name: status[:, columns] for name, columns in STATUS_SLICES.items()}
        data["wsg_position_commanded"] = data["wsg_commanded"][:, :1]
        data["wsg_force_limit"] = data["wsg_commanded"][:, 1:]
        data.update(raw)
        return GroundTruth.from_channels(self.station, t, data, utime_warmup=self.utime_warmup)


def _stopped(status: SimulatorStatus) -> bool:
    """Whether ``AdvanceTo`` stopped before its boundary (a monitor ended the simulation)."""
    return not status.succeeded() or status.reason() != status.ReturnReason.kReachedBoundaryTime


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


def _add_records(builder: DiagramBuilder, arm: ArmCell, arm_system, receiver, scenario):
    """The ground truth (every log period, sampled as a status is), each cycle's applied
    command's utime and each cycle's status. Returns (logger, command logger, cycle logger,
    the ground truth's channel sizes)."""
    period = IIWA_STATUS_PERIOD
    # Each cycle: the utime [s] of the status that the command applied from it answers.
    applied_utime = builder.AddNamedSystem(
        "applied_command_utime", ZeroOrderHold(period, 1, offset_sec=arm.offset)
    )
    builder.Connect(receiver.GetOutputPort("time"), applied_utime.get_input_port())
    command_logger = builder.AddNamedSystem("applied_command_logger", VectorLogSink(1, period))
    builder.Connect(applied_utime.get_output_port(), command_logger.get_input_port())
    cycle_logger = builder.AddNamedSystem("cycle_logger", VectorLogSink(STATUS_SIZE, period))
    builder.Connect(arm_system.GetOutputPort("status"), cycle_logger.get_input_port())

    ports = [arm_system.GetOutputPort(port) for _, port in _GROUND_TRUTH_PORTS]
    sizes = tuple(p.size() for p in ports)
    mux = builder.AddNamedSystem("ground_truth_channels", Multiplexer(list(sizes)))
    for i, port in enumerate(ports):
        builder.Connect(port, mux.get_input_port(i))
    # Sampled as a status is: STATUS_DELAY after each slot's cycle events (a hold), logged at
    # the next slot; ground_truth() puts each sample at its slot.
    size, log_period = mux.get_output_port().size(), scenario.timeline.log_period
    hold = builder.AddNamedSystem(
        "ground_truth_sample",
        ZeroOrderHold(log_period, size, offset_sec=arm.offset + STATUS_DELAY),
    )
    builder.Connect(mux.get_output_port(), hold.get_input_port())
    logger = builder.AddNamedSystem("ground_truth_logger", VectorLogSink(size, log_period))
    builder.Connect(hold.get_output_port(), logger.get_input_port())
    return logger, command_logger, cycle_logger, sizes


def add_sim_driver(
    builder: DiagramBuilder,
    lcm: DrakeLcm,
    scenario: Scenario,
    *,
    q_initial: np.ndarray = Q_HOME,
    utime_warmup: bool = False,
    record: bool = False,
    read_bus: str = "every_step",
) -> SimDriverSystems:
    """Adds doorlab's arm behind the drivers' LCM protocol to ``builder``.

    Args:
        builder: The diagram to add to.
        lcm: The LCM bus (``DrakeLcm(url)``; ``DrakeLcm("memq://")`` for one process).
        scenario: A validated scenario: the station (physics, inner loop, gripper, the
            driver's filter and external-torque limit) and the initial state (doors, gripper
            width); ``timeline.log_period`` is the ground truth's sample period.
        q_initial: The arm's start pose (7,) [rad] (the episode's: q_home).
        utime_warmup: Send utime -1 in the first 200 statuses, as the real driver does.
        record: Log the ground truth, each cycle's status and applied command
            (:meth:`SimDriverSystems.ground_truth`, ``cycle_log``, ``command_delays``).
        read_bus: Who reads ``lcm`` (:data:`READ_BUS`): ``every_step``, an
            ``LcmInterfaceSystem`` added here (first, before the subscribers), when every
            handler of the bus is C++ (a driver in its own process); ``every_cycle``,
            :meth:`SimDriverSystems.advance_to` from Python after each status, when the bus
            has Python handlers (a client in this process on memq://; module docstring);
            ``caller``, the diagram's own ``LcmInterfaceSystem`` for this ``lcm`` (one per
            bus), added before this call.

    Returns:
        The systems (call :meth:`SimDriverSystems.initialize` on the simulator's context,
        and advance with :meth:`SimDriverSystems.advance_to`).
    """
    if read_bus not in READ_BUS:
        raise ConfigError(f"read_bus {read_bus!r}: choose one of {', '.join(READ_BUS)}")
    if read_bus == "every_step":
        builder.AddNamedSystem("lcm_interface", LcmInterfaceSystem(lcm))
    arm = build_arm_cell(scenario.station, q_initial=q_initial)
    arm_system = builder.AddNamedSystem("arm", arm.diagram)
    iiwa_sub, iiwa_receiver = add_iiwa_command(builder, lcm, arm_system)
    wsg_sub = add_wsg_command(builder, lcm, arm_system, scenario.station.gripper)
    iiwa_pub, wsg_pub = add_statuses(builder, lcm, arm, arm_system, utime_warmup)
    watch = builder.AddNamedSystem(
        "external_torque_watch",
        ExternalTorqueWatch(
            scenario.station.driver.external_torque_limit, offset=arm.offset + WATCH_DELAY
        ),
    )
    builder.Connect(arm_system.GetOutputPort("iiwa_torque_external"), watch.get_input_port())
    logger = command_logger = cycle_logger = None
    log_sizes: tuple[int, ...] = ()
    if record:
        logger, command_logger, cycle_logger, log_sizes = _add_records(
            builder, arm, arm_system, iiwa_receiver, scenario
        )
    return SimDriverSystems(
        arm=arm,
        iiwa_command_subscriber=iiwa_sub,
        wsg_command_subscriber=wsg_sub,
        iiwa_status_publisher=iiwa_pub,
        wsg_status_publisher=wsg_pub,
        logger=logger,
        command_logger=command_logger,
        cycle_logger=cycle_logger,
        scenario=scenario,
        utime_warmup=utime_warmup,
        log_sizes=log_sizes,
        lcm=lcm,
        read_bus=read_bus,
    )
