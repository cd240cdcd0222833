"""The simulated driver's LCM side (:mod:`doorlab.hardware.sim_cell` puts it around the arm
cell): ``IIWA_COMMAND`` and ``SCHUNK_WSG_COMMAND`` decoded in C++ into the cell's command
inputs, the cell's state sent as ``IIWA_STATUS`` every cycle and ``SCHUNK_WSG_STATUS`` every
50 ms, and the read tick. Only Drake's C++ systems: nothing here runs Python per step.
"""

from __future__ import annotations

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
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.lcm import LcmPublisherSystem, LcmSubscriberSystem
from pydrake.systems.primitives import (
    ConstantVectorSource,
    Multiplexer,
    SymbolicVectorSystem,
    TrajectorySource,
    ZeroOrderHold,
)
from pydrake.trajectories import PiecewisePolynomial

from doorlab.cell.arm_cell import ArmCell
from doorlab.constants import NUM_JOINTS
from doorlab.hardware.protocol import (
    IIWA_COMMAND_CHANNEL,
    IIWA_STATUS_CHANNEL,
    IIWA_STATUS_PERIOD,
    UTIME_WARMUP_STATUSES,
    WSG_COMMAND_CHANNEL,
    WSG_STATUS_CHANNEL,
    WSG_STATUS_PERIOD,
)

_UTIME_HORIZON = 1e8
"""The utime source is defined up to this simulation time [s] (three years)."""
READ_LEAD = 1e-6
"""The bus is read this long before each cycle's events [s] (the read tick)."""
STATUS_DELAY = 1e-6
"""Each IIWA_STATUS is published this long after its cycle's events [s]."""


def _utime_source(utime_warmup: bool, publish_offset: float) -> PiecewisePolynomial:
    """IiwaStatusSender's ``time_measured`` [s] as a function of simulation time.

    The status of cycle k is sent at t = k * 5 ms + ``publish_offset`` and carries utime
    k * 5000: the sender truncates time_measured * 1e6 to an integer, and k * 0.005 * 1e6 is
    often a hair under k * 5000, so half a microsecond added makes the truncation a rounding.
    The warm-up holds -1e-6 (utime -1) until half a period before the 201st status.
    """
    offset = 0.5e-6 - publish_offset
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


_NO_MESSAGE_POSITION = 1e6
"""The command receiver's "measured position" input [rad]: its position output before the
first message, far outside any joint's range, marks "no command yet"."""
_NO_MESSAGE_THRESHOLD = 100.0
"""A receiver position above this [rad] is the no-message marker."""


def _command_valid() -> SymbolicVectorSystem:
    """[p (7), utime] -> 1 for a command, 0 for none (the receiver's no-message marker in p,
    or a negative utime: kuka_driver's -1, "no command")."""
    u = sym.MakeVectorVariable(NUM_JOINTS + 1, "u")
    none = sym.logical_or(u[0] > _NO_MESSAGE_THRESHOLD, u[NUM_JOINTS] < 0)
    return SymbolicVectorSystem(input=u, output=[sym.if_then_else(none, 0.0, 1.0)])


def add_iiwa_command(builder: DiagramBuilder, lcm: DrakeLcm, arm_system):
    """IIWA_COMMAND -> the arm cell's command inputs: the newest message, decoded in C++
    (IiwaCommandReceiver, position and torque), and whether it is a command. The receiver's
    position before any message is its "measured position" input, here
    :data:`_NO_MESSAGE_POSITION`: that is how "no command yet" is told from a command.

    Returns:
        (the subscriber, the receiver).
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
    position = receiver.get_commanded_position_output_port()
    builder.Connect(position, arm_system.GetInputPort("iiwa_position"))
    builder.Connect(
        receiver.get_commanded_torque_output_port(),
        arm_system.GetInputPort("iiwa_feedforward_torque"),
    )
    valid_in = add("command_valid_input", Multiplexer([NUM_JOINTS, 1]))
    builder.Connect(position, valid_in.get_input_port(0))
    builder.Connect(receiver.GetOutputPort("time"), valid_in.get_input_port(1))
    valid = add("command_valid", _command_valid())
    builder.Connect(valid_in.get_output_port(), valid.get_input_port())
    builder.Connect(valid.get_output_port(), arm_system.GetInputPort("iiwa_command_valid"))
    return subscriber, receiver


def add_wsg_command(builder: DiagramBuilder, lcm: DrakeLcm, arm_system, gripper):
    """SCHUNK_WSG_COMMAND -> the arm cell's wsg_position [m] and wsg_force_limit [N]; until
    the first command the gripper's initial width and force limit. Returns the subscriber."""
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
    builder.Connect(receiver.get_position_output_port(), arm_system.GetInputPort("wsg_position"))
    builder.Connect(
        receiver.get_force_limit_output_port(), arm_system.GetInputPort("wsg_force_limit")
    )
    return subscriber


def _publisher(builder, lcm, name, channel, lcm_type, period, offset, sender):
    system = builder.AddNamedSystem(
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


def add_statuses(
    builder: DiagramBuilder, lcm: DrakeLcm, arm: ArmCell, arm_system, utime_warmup: bool
):
    """The arm cell's status -> IIWA_STATUS every cycle, STATUS_DELAY after its events; its
    gripper -> SCHUNK_WSG_STATUS every 50 ms; the read tick. Returns (iiwa, wsg publisher)."""

    def add(name: str, system):
        return builder.AddNamedSystem(name, system)

    offset = arm.offset + STATUS_DELAY
    iiwa_status = add("iiwa_status", IiwaStatusSender(NUM_JOINTS))
    for sender_port, arm_port in (
        ("position_commanded", "iiwa_position_commanded"),
        ("position_measured", "iiwa_position_measured"),
        ("velocity_estimated", "iiwa_velocity_estimated"),
        ("torque_commanded", "iiwa_torque_commanded"),
        ("torque_external", "iiwa_torque_external"),
    ):  # torque_measured left open: the sender reports torque_commanded
        builder.Connect(arm_system.GetOutputPort(arm_port), iiwa_status.GetInputPort(sender_port))
    utime = add("status_utime", TrajectorySource(_utime_source(utime_warmup, offset)))
    builder.Connect(utime.get_output_port(), iiwa_status.GetInputPort("time_measured"))
    iiwa_pub = _publisher(
        builder,
        lcm,
        "iiwa_status_publisher",
        IIWA_STATUS_CHANNEL,
        lcmt_iiwa_status,
        IIWA_STATUS_PERIOD,
        offset,
        iiwa_status,
    )
    wsg_status = add("wsg_status", SchunkWsgStatusSender())
    builder.Connect(
        arm_system.GetOutputPort("wsg_state_measured"), wsg_status.get_state_input_port()
    )
    builder.Connect(
        arm_system.GetOutputPort("wsg_force_measured"), wsg_status.get_force_input_port()
    )
    wsg_pub = _publisher(
        builder,
        lcm,
        "wsg_status_publisher",
        WSG_STATUS_CHANNEL,
        lcmt_schunk_wsg_status,
        WSG_STATUS_PERIOD,
        0.0,
        wsg_status,
    )
    _add_read_tick(builder, arm.offset)
    return iiwa_pub, wsg_pub


def _add_read_tick(builder: DiagramBuilder, offset: float) -> None:
    """The read tick (:mod:`doorlab.hardware.sim_cell`): a simulator step that starts
    READ_LEAD before every cycle's events at ``offset`` [s] after k x 5 ms (C++, no output
    used)."""
    tick_input = builder.AddNamedSystem("tick_input", ConstantVectorSource([0.0]))
    tick = builder.AddNamedSystem(
        "read_tick", ZeroOrderHold(IIWA_STATUS_PERIOD, 1, offset_sec=offset - READ_LEAD)
    )
    builder.Connect(tick_input.get_output_port(), tick.get_input_port())
