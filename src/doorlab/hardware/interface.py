"""The real cell over LCM: the iiwa's and the WSG's drivers behind the simulated station's ports.

:func:`build_hardware_cell` returns a Diagram with the port names of
:data:`doorlab.episode.wiring.CELL_INPUTS` and :data:`doorlab.episode.wiring.CELL_OUTPUTS`, so the
episode's wiring, plan runner and logger (:mod:`doorlab.episode`) drive it as they drive the
simulated station. Inside, Drake's LCM systems and the drivers' message converters:

- ``IIWA_STATUS`` (``lcmt_iiwa_status``, drake-iiwa-driver, every 5 ms) ->
  ``LcmSubscriberSystem`` -> ``IiwaStatusReceiver``: ``iiwa_position_measured``,
  ``iiwa_velocity_estimated``, ``iiwa_position_commanded``, ``iiwa_torque_commanded``,
  ``iiwa_torque_external``, ``iiwa_state`` ([q; v]) and ``iiwa_status_time`` (the status's
  ``utime`` as seconds);
- ``iiwa_position``, ``iiwa_feedforward_torque`` -> ``IiwaCommandSender`` (position and
  torque mode: tau_ff as ``joint_torque``) -> ``LcmPublisherSystem`` on ``IIWA_COMMAND``,
  which publishes only when forced: the episode (:mod:`doorlab.hardware.episode`) sends one
  command per status, after checking it, with the status's ``utime``;
- ``wsg_position``, ``wsg_force_limit`` -> ``SchunkWsgCommandSender`` -> ``SCHUNK_WSG_COMMAND``
  every 50 ms (20 Hz, the gripper driver's period); ``SCHUNK_WSG_STATUS`` ->
  ``SchunkWsgStatusReceiver``:
  ``wsg_state_measured`` (separation [m], its rate [m/s]) and ``wsg_force_measured`` [N];
- no ``LcmInterfaceSystem``: the diagram never reads the bus. The client's
  :class:`doorlab.hardware.link.DriverLink` does, from Python, and each message it handles
  reaches the subscribers here too (they share its ``DrakeLcm``), so the diagram sees exactly
  the statuses the episode answers. An ``LcmInterfaceSystem`` would read the bus inside
  ``Simulator.AdvanceTo``, which pydrake runs without the GIL, and there call the link's
  Python handler, whose bytes pydrake builds without taking the GIL: a segmentation fault on
  Python >= 3.12 (issue 45; :mod:`doorlab.hardware.link`).
"""

from __future__ import annotations

from dataclasses import dataclass

from drake import (
    lcmt_iiwa_command,
    lcmt_iiwa_status,
    lcmt_schunk_wsg_command,
    lcmt_schunk_wsg_status,
)
from pydrake.lcm import DrakeLcmInterface
from pydrake.manipulation import (
    IiwaCommandSender,
    IiwaControlMode,
    IiwaStatusReceiver,
    SchunkWsgCommandSender,
    SchunkWsgStatusReceiver,
)
from pydrake.systems.framework import Diagram, DiagramBuilder, TriggerType
from pydrake.systems.lcm import LcmPublisherSystem, LcmSubscriberSystem
from pydrake.systems.primitives import Multiplexer

from doorlab.constants import NUM_JOINTS
from doorlab.hardware.protocol import (
    IIWA_COMMAND_CHANNEL,
    IIWA_STATUS_CHANNEL,
    WSG_COMMAND_CHANNEL,
    WSG_STATUS_CHANNEL,
    WSG_STATUS_PERIOD,
)


@dataclass(frozen=True)
class HardwareCell:
    """A built real cell.

    Attributes:
        diagram: The Diagram with the cell's ports (module docstring).
        iiwa_command: The IIWA_COMMAND publisher (publishes only when forced).
        command_sender: Its ``IiwaCommandSender``; the episode fixes its ``time`` input to
            the answered status's utime before each command.
    """

    diagram: Diagram
    iiwa_command: LcmPublisherSystem
    command_sender: IiwaCommandSender


def build_hardware_cell(lcm: DrakeLcmInterface) -> HardwareCell:
    """The real cell on ``lcm`` (a ``DrakeLcm`` on the drivers' URL), which its caller reads
    (``HandleSubscriptions``) between the simulator's calls, never the diagram (module
    docstring)."""
    builder = DiagramBuilder()

    def add(system, name: str):
        system.set_name(name)
        return builder.AddSystem(system)

    status = add(
        LcmSubscriberSystem.Make(
            IIWA_STATUS_CHANNEL, lcmt_iiwa_status, lcm, use_cpp_serializer=True
        ),
        "iiwa_status_subscriber",
    )
    receiver = add(IiwaStatusReceiver(NUM_JOINTS), "iiwa_status_receiver")
    builder.Connect(status.get_output_port(), receiver.get_input_port())
    state = add(Multiplexer([NUM_JOINTS, NUM_JOINTS]), "iiwa_state")
    builder.Connect(receiver.get_position_measured_output_port(), state.get_input_port(0))
    builder.Connect(receiver.get_velocity_estimated_output_port(), state.get_input_port(1))
    builder.ExportOutput(state.get_output_port(), "iiwa_state")
    for name, port in (
        ("iiwa_position_measured", receiver.get_position_measured_output_port()),
        ("iiwa_velocity_estimated", receiver.get_velocity_estimated_output_port()),
        ("iiwa_position_commanded", receiver.get_position_commanded_output_port()),
        ("iiwa_torque_commanded", receiver.get_torque_commanded_output_port()),
        ("iiwa_torque_external", receiver.get_torque_external_output_port()),
        ("iiwa_status_time", receiver.get_time_measured_output_port()),
    ):
        builder.ExportOutput(port, name)

    sender = add(
        IiwaCommandSender(NUM_JOINTS, IiwaControlMode.kPositionAndTorque), "iiwa_command_sender"
    )
    builder.ExportInput(sender.get_position_input_port(), "iiwa_position")
    builder.ExportInput(sender.get_torque_input_port(), "iiwa_feedforward_torque")
    command = add(
        LcmPublisherSystem.Make(
            IIWA_COMMAND_CHANNEL,
            lcmt_iiwa_command,
            lcm,
            use_cpp_serializer=True,
            publish_triggers={TriggerType.kForced},
        ),
        "iiwa_command_publisher",
    )
    builder.Connect(sender.get_output_port(), command.get_input_port())

    wsg_sender = add(SchunkWsgCommandSender(), "wsg_command_sender")
    builder.ExportInput(wsg_sender.get_position_input_port(), "wsg_position")
    builder.ExportInput(wsg_sender.get_force_limit_input_port(), "wsg_force_limit")
    wsg_command = add(
        LcmPublisherSystem.Make(
            WSG_COMMAND_CHANNEL,
            lcmt_schunk_wsg_command,
            lcm,
            publish_period=WSG_STATUS_PERIOD,
            use_cpp_serializer=True,
        ),
        "wsg_command_publisher",
    )
    builder.Connect(wsg_sender.get_command_output_port(), wsg_command.get_input_port())
    wsg_status = add(
        LcmSubscriberSystem.Make(
            WSG_STATUS_CHANNEL, lcmt_schunk_wsg_status, lcm, use_cpp_serializer=True
        ),
        "wsg_status_subscriber",
    )
    wsg_receiver = add(SchunkWsgStatusReceiver(), "wsg_status_receiver")
    builder.Connect(wsg_status.get_output_port(), wsg_receiver.get_status_input_port())
    builder.ExportOutput(wsg_receiver.get_state_output_port(), "wsg_state_measured")
    builder.ExportOutput(wsg_receiver.get_force_output_port(), "wsg_force_measured")

    diagram = builder.Build()
    diagram.set_name("doorlab_hardware_cell")
    return HardwareCell(diagram, command, sender)
