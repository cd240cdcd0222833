"""The lab arm's cell: the simulated station behind kuka_driver's cycle, as one Diagram.

Both a one-process run with ``station.driver.timing: kuka_driver``
(:mod:`doorlab.episode.simulation`) and ``doorlab sim-driver`` (:mod:`doorlab.hardware.sim_cell`)
build the arm from :func:`build_arm_cell`, so that they keep the same timing, filter and
gains (one copy, read from the scenario). What kuka_driver does (``kuka-driver/kuka_driver.cc``
of RobotLocomotion/drake-iiwa-driver; :mod:`doorlab.kuka`), at each cycle t_k = k x 5 ms:

1. the state of this cycle: the plant after its steps up to t_k, and kuka_driver's velocity
   estimate (a 40 Hz low-pass of the finite difference of the measured positions);
2. the newest command that arrived before the cycle is applied from it on (the joint
   positions clamped to the limits less 1 deg, the feed-forward torque as sent); no command
   yet (or one with utime -1) holds the start pose, unclamped, with no torque;
3. the status of this cycle: that state, and the command the arm tracked up to it.

A plan (or a client) that computes its answer from status k therefore acts from cycle k + 1,
one period after the state it was computed from, however fast it answers within the period.

How it is built (C++ systems only; the offset c is :func:`cycle_offset`: a quarter of the
grid that cycles and plant steps share, so no plant step falls between the cycle's events):

- ``command_gate`` (a ``SymbolicVectorSystem``): [q (7), tau (7), valid (1)] -> [clamped q or
  the start pose, tau or 0, valid];
- ``command_latch``: a ``ZeroOrderHold`` (5 ms, offset c) of the gate's output and the
  gripper's command [position, force limit], feeding the station: the applied command;
- ``velocity_memory`` (``ZeroOrderHold``, 5 ms, offset c) holding [q_{k-1}; v_{k-1}] and
  ``velocity_filter`` (a ``MatrixGain``): v_k = alpha v_{k-1} + (1 - alpha)(q_k - q_{k-1})/dt;
- ``status_sampler`` (``ZeroOrderHold``, 5 ms, offset c): the status, :data:`STATUS_LAYOUT`.
  All three update at the same event, so the sampler reads the command the arm tracked up to
  the cycle and the filter's output for this cycle's q.

The gripper's controller differentiates its setpoint at the 5 ms cycle (doorlab's cell: every
50 ms, the WSG firmware's rate, whose phase would depend on when a client started; the
setpoint's derivative keeps its integral either way). Until the first command is applied the
arm's and fingers' joints are locked (the arm stands
still, as the real one does in KUKA's position hold before FRI commands it): its start state
is exact, whatever the time between the driver's start and the first command.
:meth:`ArmCell.unlock` frees them (Python between two simulator calls, after the cycle that
applied the first command).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pydrake.symbolic as sym
from pydrake.systems.framework import Context, Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import (
    Demultiplexer,
    MatrixGain,
    Multiplexer,
    PassThrough,
    SymbolicVectorSystem,
    ZeroOrderHold,
)

from doorlab.cell.arm_model import (
    add_command_latency,
    add_external_torque_estimate,
    latency_active,
    load_data_error,
    seed_random_sources,
)
from doorlab.cell.frames import ARM_JOINTS, FINGER_JOINTS
from doorlab.cell.safety import Violation
from doorlab.cell.station import Station, build_station, initialize_cell, make_controller_plant
from doorlab.config import StationConfig
from doorlab.constants import NUM_JOINTS
from doorlab.errors import SafetyStop
from doorlab.kuka import (
    CYCLE_PERIOD,
    DRIVER_JOINT_LIMITS,
    JOINT_LIMIT_MARGIN,
    external_torque_limits,
    filter_gain,
)

STATUS_LAYOUT = (
    ("q_measured", NUM_JOINTS),
    ("q_commanded", NUM_JOINTS),
    ("tau_feedforward", NUM_JOINTS),
    ("tau_commanded", NUM_JOINTS),
    ("tau_external", NUM_JOINTS),
    ("v_estimated", NUM_JOINTS),
    ("v_measured", NUM_JOINTS),
    ("wsg_commanded", 2),
    ("door_angles", 2),
)
"""The status sampler's vector, in order: (name, size). ``q_commanded`` and
``tau_feedforward`` (and ``wsg_commanded``: separation [m], force limit [N]) are the command the
arm tracked up to the cycle; ``v_estimated`` is kuka_driver's filtered velocity. ``v_measured``
(the plant's exact velocity) and ``door_angles`` (the hinges, left and right [rad]) are not in
IIWA_STATUS: the truth at the same instant."""
STATUS_SIZE = sum(size for _, size in STATUS_LAYOUT)
APPLIED_LAYOUT = (
    ("q_ref", NUM_JOINTS),
    ("tau_ff", NUM_JOINTS),
    ("valid", 1),
    ("wsg_position", 1),
    ("wsg_force_limit", 1),
)
"""The command latch's vector (the command the arm tracks from the last cycle on)."""
APPLIED_SIZE = sum(size for _, size in APPLIED_LAYOUT)
WATCH_DELAY = 0.5e-6
"""The external-torque check runs this long after the cycle's events [s] (before a status goes
out, :data:`doorlab.hardware.sim_bus.STATUS_DELAY` after them)."""


def cycle_offset(time_step: float) -> float:
    """The cycle's events happen this long after each t_k = k x 5 ms [s].

    A quarter of g = gcd(time_step, 5 ms): plant steps and cycles lie on that grid, so a plant
    step at t_k comes before the cycle's events and the next one (at least g later) after
    them, clear of float noise either way; a plan's tick, half a grid after t_k
    (:func:`doorlab.episode.schedule.tick_lag`), sees this cycle's status.
    """
    ns = math.gcd(round(time_step * 1e9), round(CYCLE_PERIOD * 1e9))
    return 0.25 * ns * 1e-9


def _offsets(layout) -> dict[str, slice]:
    columns = np.cumsum([0, *(size for _, size in layout)])
    return {
        name: slice(int(a), int(b))
        for (name, _), a, b in zip(layout, columns[:-1], columns[1:], strict=True)
    }


STATUS_SLICES = _offsets(STATUS_LAYOUT)
APPLIED_SLICES = _offsets(APPLIED_LAYOUT)


def _command_gate(q_initial: np.ndarray) -> SymbolicVectorSystem:
    """[q (7), tau (7), valid (1)] -> [q_ref (7), tau_ff (7), valid (1)], as kuka_driver
    hands a command to FRI: q clamped to the joint limits less 1 deg, tau as sent; no valid
    command (valid <= 0.5): the start pose ``q_initial`` unclamped and zero torque. Its
    expressions are evaluated in C++."""
    u = sym.MakeVectorVariable(2 * NUM_JOINTS + 1, "u")
    p, tau, valid = u[:NUM_JOINTS], u[NUM_JOINTS : 2 * NUM_JOINTS], u[-1]
    limit = DRIVER_JOINT_LIMITS - JOINT_LIMIT_MARGIN
    none = valid < 0.5
    q_ref = [
        sym.if_then_else(none, float(q0), sym.min(sym.max(p_i, -float(lim)), float(lim)))
        for p_i, q0, lim in zip(p, q_initial, limit, strict=True)
    ]
    tau_ff = [sym.if_then_else(none, 0.0, tau_i) for tau_i in tau]
    flag = sym.if_then_else(none, 0.0, 1.0)
    return SymbolicVectorSystem(input=u, output=np.array([*q_ref, *tau_ff, flag]))


@dataclass(frozen=True)
class ArmCell:
    """A built arm cell (see the module docstring).

    Input ports: ``iiwa_position`` (7) [rad], ``iiwa_feedforward_torque`` (7) [N m],
    ``iiwa_command_valid`` (1: 1 a command, 0 none), ``wsg_position`` (1) [m],
    ``wsg_force_limit`` (1) [N].

    Output ports, the status (held from one cycle to the next): ``iiwa_position_measured``,
    ``iiwa_velocity_estimated`` (kuka_driver's filter), ``iiwa_state`` ([q; v_estimated]),
    ``iiwa_position_commanded``, ``iiwa_torque_commanded``, ``iiwa_torque_external`` and
    ``status`` (all of :data:`STATUS_LAYOUT`); the truth: ``plant_state``, ``door_angles``,
    ``wsg_state_measured``, ``wsg_force_measured``, ``station_torque_commanded``,
    ``station_torque_external``, ``station_position_measured``, ``applied_command``
    (:data:`APPLIED_LAYOUT`), ``applied_iiwa_position``, ``applied_feedforward_torque``.

    Attributes:
        diagram: The Diagram. station: The station inside it.
        q_initial: The start pose (7,) [rad] (held until the first command).
        config: The station's configuration. offset: :func:`cycle_offset` [s].
    """

    diagram: Diagram
    station: Station
    q_initial: np.ndarray
    config: StationConfig
    offset: float
    latch: ZeroOrderHold
    memory: ZeroOrderHold
    sampler: ZeroOrderHold
    latency_holds: tuple[ZeroOrderHold, ...] = ()
    random_sources: tuple = ()

    def _joints(self):
        plant = self.station.plant
        arm = [plant.GetJointByName(name, self.station.iiwa) for name in ARM_JOINTS]
        return arm + [plant.GetJointByName(name, self.station.wsg) for name in FINGER_JOINTS]

    def initialize(
        self, root_context: Context, *, door_angles: tuple[float, float], lock: bool = True
    ) -> None:
        """The start: q_initial, the gripper at its initial width, the doors; no command
        (the start pose held), the filter at rest; the arm and fingers locked."""
        gripper = self.config.gripper
        initialize_cell(
            self.station,
            root_context,
            q_initial=self.q_initial,
            gripper_width=gripper.initial_width,
            door_angles=door_angles,
        )
        q0, zero = self.q_initial, np.zeros(NUM_JOINTS)
        applied = np.concatenate([q0, zero, [0.0, gripper.initial_width, gripper.force_limit]])
        self.latch.SetVectorState(self.latch.GetMyMutableContextFromRoot(root_context), applied)
        seed_random_sources(self.random_sources, root_context)
        for hold in self.latency_holds:  # the latency's holds: the start pose, no torque
            hold.SetVectorState(
                hold.GetMyMutableContextFromRoot(root_context), applied[: 2 * NUM_JOINTS]
            )
        memory = self.memory.GetMyMutableContextFromRoot(root_context)
        self.memory.SetVectorState(memory, np.concatenate([q0, zero]))
        status = np.zeros(STATUS_SIZE)
        status[STATUS_SLICES["q_measured"]] = q0
        status[STATUS_SLICES["q_commanded"]] = q0
        status[STATUS_SLICES["wsg_commanded"]] = [gripper.initial_width, gripper.force_limit]
        self.sampler.SetVectorState(self.sampler.GetMyMutableContextFromRoot(root_context), status)
        if lock:
            plant_context = self.station.plant.GetMyMutableContextFromRoot(root_context)
            for joint in self._joints():
                joint.Lock(plant_context)

    def locked(self, root_context: Context) -> bool:
        """Whether the arm still stands locked (no command applied yet)."""
        plant_context = self.station.plant.GetMyContextFromRoot(root_context)
        return self._joints()[0].is_locked(plant_context)

    def unlock(self, root_context: Context) -> None:
        """Frees the arm's and fingers' joints (the first command is applied)."""
        plant_context = self.station.plant.GetMyMutableContextFromRoot(root_context)
        for joint in self._joints():
            joint.Unlock(plant_context)

    def command_applied(self, root_context: Context) -> bool:
        """Whether the latch holds a valid command (applied from its last cycle on)."""
        latched = self.latch.GetMyContextFromRoot(root_context).get_discrete_state_vector()
        return bool(latched.value()[APPLIED_SLICES["valid"]][0] > 0.5)


def _add_command_latch(
    builder: DiagramBuilder, cell, q_initial: np.ndarray, offset: float, config: StationConfig
):
    """Commands -> gate -> latch (-> ``station.arm``'s latency) -> the station; returns (latch,
    its Demultiplexer, the latency's holds)."""
    n = NUM_JOINTS
    gate_in = builder.AddNamedSystem("command_gate_input", Multiplexer([n, n, 1]))
    for i, name in enumerate(("iiwa_position", "iiwa_feedforward_torque", "iiwa_command_valid")):
        builder.ExportInput(gate_in.get_input_port(i), name)
    gate = builder.AddNamedSystem("command_gate", _command_gate(q_initial))
    builder.Connect(gate_in.get_output_port(), gate.get_input_port())
    latch_in = builder.AddNamedSystem("command_latch_input", Multiplexer([2 * n + 1, 1, 1]))
    builder.Connect(gate.get_output_port(), latch_in.get_input_port(0))
    for i, name in ((1, "wsg_position"), (2, "wsg_force_limit")):
        wsg = builder.AddNamedSystem(f"{name}_input", PassThrough(1))
        builder.ExportInput(wsg.get_input_port(), name)
        builder.Connect(wsg.get_output_port(), latch_in.get_input_port(i))
    latch = builder.AddNamedSystem(
        "command_latch", ZeroOrderHold(CYCLE_PERIOD, APPLIED_SIZE, offset_sec=offset)
    )
    builder.Connect(latch_in.get_output_port(), latch.get_input_port())
    applied = builder.AddNamedSystem("applied_command", Demultiplexer([n, n, 1, 1, 1]))
    builder.Connect(latch.get_output_port(), applied.get_input_port())
    holds, sources = [], []
    arm = config.arm
    if latency_active(arm):  # the arm's latency beyond the cycle (station.arm)
        command = builder.AddNamedSystem("applied_arm_command", Multiplexer([n, n]))
        builder.Connect(applied.get_output_port(0), command.get_input_port(0))
        builder.Connect(applied.get_output_port(1), command.get_input_port(1))
        delayed, holds, sources = add_command_latency(
            builder, command.get_output_port(), arm, time_step=config.time_step, offset=offset
        )
        split = builder.AddNamedSystem("delayed_arm_command", Demultiplexer([n, n]))
        builder.Connect(delayed, split.get_input_port())
        arm_ports = [split.get_output_port(0), split.get_output_port(1)]
    else:
        arm_ports = [applied.get_output_port(0), applied.get_output_port(1)]
    for port, name in zip(arm_ports, ("iiwa_position", "iiwa_feedforward_torque"), strict=True):
        builder.Connect(port, cell.GetInputPort(name))
    for i, name in ((3, "wsg_position"), (4, "wsg_force_limit")):
        builder.Connect(applied.get_output_port(i), cell.GetInputPort(name))
    builder.ExportOutput(latch.get_output_port(), "applied_command")
    builder.ExportOutput(applied.get_output_port(0), "applied_iiwa_position")
    builder.ExportOutput(applied.get_output_port(1), "applied_feedforward_torque")
    return latch, applied, holds, sources


def _add_velocity_filter(builder: DiagramBuilder, q_port, cutoff: float, offset: float):
    """kuka_driver's velocity filter, v_k = G [q_k; q_{k-1}; v_{k-1}]: returns (its memory,
    the gain whose output is this cycle's v_k)."""
    n = NUM_JOINTS
    memory = builder.AddNamedSystem(
        "velocity_memory", ZeroOrderHold(CYCLE_PERIOD, 2 * n, offset_sec=offset)
    )
    filter_in = builder.AddNamedSystem("velocity_filter_input", Multiplexer([n, 2 * n]))
    builder.Connect(q_port, filter_in.get_input_port(0))
    builder.Connect(memory.get_output_port(), filter_in.get_input_port(1))
    velocity = builder.AddNamedSystem("velocity_filter", MatrixGain(filter_gain(cutoff)))
    builder.Connect(filter_in.get_output_port(), velocity.get_input_port())
    memory_in = builder.AddNamedSystem("velocity_memory_input", Multiplexer([n, n]))
    builder.Connect(q_port, memory_in.get_input_port(0))
    builder.Connect(velocity.get_output_port(), memory_in.get_input_port(1))
    builder.Connect(memory_in.get_output_port(), memory.get_input_port())
    return memory, velocity


def _add_status(builder: DiagramBuilder, cell, applied, velocity, offset: float, config):
    """Each cycle's status (:data:`STATUS_LAYOUT`) sampled and exported, its external torque
    KUKA's estimate (:func:`doorlab.cell.arm_model.add_external_torque_estimate`); returns the
    sampler."""
    n = NUM_JOINTS
    tau_external, noise = _external_torque(builder, cell, config.arm)
    plant_v = builder.AddNamedSystem("plant_velocity", PassThrough(n))
    builder.Connect(cell.GetOutputPort("iiwa_velocity_estimated"), plant_v.get_input_port())
    wsg_commanded = builder.AddNamedSystem("wsg_commanded", Multiplexer([1, 1]))
    builder.Connect(applied.get_output_port(3), wsg_commanded.get_input_port(0))
    builder.Connect(applied.get_output_port(4), wsg_commanded.get_input_port(1))
    sources = {
        "q_measured": cell.GetOutputPort("iiwa_position_measured"),
        "q_commanded": applied.get_output_port(0),
        "tau_feedforward": applied.get_output_port(1),
        "tau_commanded": cell.GetOutputPort("iiwa_torque_commanded"),
        "tau_external": tau_external,
        "v_estimated": velocity.get_output_port(),
        "v_measured": plant_v.get_output_port(),
        "wsg_commanded": wsg_commanded.get_output_port(),
        "door_angles": cell.GetOutputPort("door_angles"),
    }
    sizes = [size for _, size in STATUS_LAYOUT]
    sampler_in = builder.AddNamedSystem("status_sampler_input", Multiplexer(sizes))
    for i, (name, _) in enumerate(STATUS_LAYOUT):
        builder.Connect(sources[name], sampler_in.get_input_port(i))
    sampler = builder.AddNamedSystem(
        "status_sampler", ZeroOrderHold(CYCLE_PERIOD, STATUS_SIZE, offset_sec=offset)
    )
    builder.Connect(sampler_in.get_output_port(), sampler.get_input_port())
    status = builder.AddNamedSystem("status", Demultiplexer(sizes))
    builder.Connect(sampler.get_output_port(), status.get_input_port())
    fields = {name: status.get_output_port(i) for i, (name, _) in enumerate(STATUS_LAYOUT)}
    builder.ExportOutput(sampler.get_output_port(), "status")
    for name, port_name in (
        ("q_measured", "iiwa_position_measured"),
        ("v_estimated", "iiwa_velocity_estimated"),
        ("q_commanded", "iiwa_position_commanded"),
        ("tau_commanded", "iiwa_torque_commanded"),
        ("tau_external", "iiwa_torque_external"),
    ):
        builder.ExportOutput(fields[name], port_name)
    state = builder.AddNamedSystem("iiwa_state", Multiplexer([n, n]))
    builder.Connect(fields["q_measured"], state.get_input_port(0))
    builder.Connect(fields["v_estimated"], state.get_input_port(1))
    builder.ExportOutput(state.get_output_port(), "iiwa_state")
    return sampler, noise


def _external_torque(builder: DiagramBuilder, cell, arm):
    """KUKA's estimate of the external torques (the contact torques when its model is
    exact and noise-free)."""
    believed = true = None
    if load_data_error(arm):
        believed, true = make_controller_plant(arm.load_mass), make_controller_plant()
    return add_external_torque_estimate(
        builder,
        cell.GetOutputPort("iiwa_torque_external"),
        cell.GetOutputPort("iiwa_state"),
        arm,
        believed=believed,
        true=true,
    )


def build_arm_cell(config: StationConfig, *, q_initial: np.ndarray) -> ArmCell:
    """The station behind kuka_driver's cycle (module docstring).

    Args:
        config: The station (physics, inner loop, gripper) and ``driver`` (the velocity
            filter's cut-off).
        q_initial: The start pose (7,) [rad], held until the first command.
    """
    q_initial = np.asarray(q_initial, float).copy()
    builder = DiagramBuilder()
    station = build_station(config, gripper_period=CYCLE_PERIOD)
    cell = builder.AddNamedSystem("station", station.diagram)
    offset = cycle_offset(config.time_step)
    latch, applied, holds, sources = _add_command_latch(builder, cell, q_initial, offset, config)
    memory, velocity = _add_velocity_filter(
        builder,
        cell.GetOutputPort("iiwa_position_measured"),
        config.driver.velocity_filter_cutoff,
        offset,
    )
    sampler, noise = _add_status(builder, cell, applied, velocity, offset, config)
    for name in ("plant_state", "door_angles", "wsg_state_measured", "wsg_force_measured"):
        builder.ExportOutput(cell.GetOutputPort(name), name)
    for name in ("torque_commanded", "torque_external", "position_measured"):
        builder.ExportOutput(cell.GetOutputPort(f"iiwa_{name}"), f"station_{name}")
    diagram = builder.Build()
    diagram.set_name("doorlab_arm_cell")
    return ArmCell(
        diagram,
        station,
        q_initial,
        config,
        offset,
        latch,
        memory,
        sampler,
        tuple(holds),
        tuple(sources + noise),
    )


class ExternalTorqueFreeze(SafetyStop):
    """kuka_driver's external-torque stop: a joint's |tau_external| over its limit at a
    cycle (the driver prints the robot state and exits; nothing is applied after it).

    Attributes:
        violation: The :class:`doorlab.cell.safety.Violation` (limit ``external_torque``).
    """


class ExternalTorqueWatch(LeafSystem):
    """Checks each cycle's status as kuka_driver does before it applies the command: raises
    :class:`ExternalTorqueFreeze` when a joint's |tau_external| exceeds its limit.

    Its publish event fires ``offset`` after each cycle t_k (after the status sampler's update
    at :func:`cycle_offset`, before the status goes out and before the next plant step). Python
    per cycle (5 ms), not per plant step. Input port: ``iiwa_torque_external`` (7) [N m].

    Args:
        ext_trq_limit: kuka_driver's ``--ext_trq_limit`` [N m] (``station.driver``).
        offset: When after t_k it checks [s]. t_zero: The cycle time that is t = 0 in the
            violations it reports (the episode's start) [s].
    """

    def __init__(self, ext_trq_limit: float, *, offset: float, t_zero: float = 0.0):
        super().__init__()
        self.set_name("external_torque_watch")
        self.limits = external_torque_limits(ext_trq_limit)
        self._offset = offset
        self._t_zero = t_zero
        self._tau = self.DeclareVectorInputPort("iiwa_torque_external", NUM_JOINTS)
        self.DeclarePeriodicPublishEvent(CYCLE_PERIOD, offset, self._check)

    def _check(self, context) -> None:
        tau = np.abs(self._tau.Eval(context))
        over = tau > self.limits
        if over.any():
            joint = int(np.argmax(tau / self.limits))
            k = round((context.get_time() - self._offset) / CYCLE_PERIOD)
            t = k * CYCLE_PERIOD - self._t_zero
            violation = Violation(
                "external_torque", joint, float(tau[joint]), float(self.limits[joint]), t
            )
            raise ExternalTorqueFreeze(violation)


def read_cycle_log(logger, root_context: Context) -> dict[str, np.ndarray]:
    """Every cycle's status from a ``VectorLogSink`` of the cell's ``status`` port that
    publishes every 5 ms: ``t`` (m,) [s], the cycle's time, and the channels of
    :data:`STATUS_LAYOUT` (m, size). The sink's entry at k x 5 ms holds the status of cycle
    k - 1 (a publish reads the state before that instant's updates)."""
    log = logger.FindLog(root_context)
    times, data = log.sample_times(), log.data().T
    keep = times > 0.5 * CYCLE_PERIOD
    out = {"t": times[keep] - CYCLE_PERIOD}
    for name, columns in STATUS_SLICES.items():
        out[name] = data[keep][:, columns]
    return out
