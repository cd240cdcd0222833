"""One episode over either cell: the wiring, the logger and the logs, whatever the cell is.

A *cell* is a Diagram with the simulated station's port names (the original
ManipulationStation's): inputs ``iiwa_position``, ``iiwa_feedforward_torque``,
``wsg_position``, ``wsg_force_limit``; outputs ``iiwa_state``, ``iiwa_position_measured``,
``iiwa_velocity_estimated``, ``iiwa_position_commanded``, ``iiwa_torque_commanded``,
``iiwa_torque_external``, ``wsg_state_measured``. :mod:`doorlab.episode.simulation` runs an episode
on the simulated station (:mod:`doorlab.cell.station`), :mod:`doorlab.hardware` on the real cell
over
LCM; both use what is here:

- :func:`wire_commands`: the joint-space prefix of the schedule (hold, move, grasp: C++
  trajectory sources), the plan runner after it, the gripper setpoint and force limit;
- :class:`EpisodeLogger`: one logger of named channels;
- :func:`schedule_fields`: the schedule's part of an :class:`EpisodeResult`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Diagram, DiagramBuilder, OutputPort
from pydrake.systems.primitives import (
    Adder,
    ConstantVectorSource,
    LogVectorOutput,
    Multiplexer,
    TrajectorySource,
    VectorLogSink,
)
from pydrake.trajectories import PiecewisePolynomial

from doorlab.config import Scenario
from doorlab.constants import NUM_JOINTS
from doorlab.episode.plan_runner import PlanRunner
from doorlab.episode.schedule import (
    ScheduledPlan,
    first_tick,
    joint_space_prefix,
    prefix_trajectory,
)

CELL_INPUTS = ("iiwa_position", "iiwa_feedforward_torque", "wsg_position", "wsg_force_limit")
"""Input ports every cell has: q_ref (7) [rad], tau_ff (7) [N m], the finger separation
setpoint (1) [m] and the grip force limit (1) [N]."""
CELL_OUTPUTS = (
    "iiwa_state",
    "iiwa_position_measured",
    "iiwa_velocity_estimated",
    "iiwa_position_commanded",
    "iiwa_torque_commanded",
    "iiwa_torque_external",
    "wsg_state_measured",
)
"""Output ports every cell has (see :mod:`doorlab.cell.station` for their units)."""


@dataclass(frozen=True)
class CommandWiring:
    """What :func:`wire_commands` added.

    Attributes:
        runner: The plan runner (None when every plan is a joint-space plan).
        q_ref: The q_ref the cell receives (7) [rad]. tau_ff: The tau_ff it receives (7).
        wsg_position: The finger separation setpoint (1) [m].
    """

    runner: PlanRunner | None
    q_ref: OutputPort
    tau_ff: OutputPort
    wsg_position: OutputPort

    def advance_to(self, simulator: Simulator, t: float) -> None:
        """Advances ``simulator`` to ``t`` [s], running the plan runner's ticks on the way
        (:meth:`PlanRunner.advance_to`; a plain ``AdvanceTo`` when there is no runner)."""
        if self.runner is None:
            simulator.AdvanceTo(t)
        else:
            self.runner.advance_to(simulator, t)


def wire_commands(
    builder: DiagramBuilder,
    cell: Diagram,
    schedule: Sequence[ScheduledPlan],
    *,
    scenario: Scenario,
    q_initial: np.ndarray,
    t_final: float,
    lag: float,
    gripper_link: tuple[float, float] | None = None,
) -> CommandWiring:
    """Adds the systems that command ``cell`` through ``schedule`` and connects its inputs.

    q_ref: the joint-space plans at the start (hold, move, grasp; all of an IK episode) come
    from C++ trajectory sources; the Python plan runner takes over at the first plan that
    needs feedback (its first tick), with no Python before it. The sources then keep sending
    their last value q_handoff, and the runner sends q_ref - q_handoff: the sum is q_ref.
    They send exactly what the runner would have: the plans sampled at its ticks t_k, each
    sample switched on ``lag`` after t_k, as the runner's command is.

    Args:
        builder: The episode's builder, which holds ``cell``.
        cell: A Diagram with the ports :data:`CELL_INPUTS` and :data:`CELL_OUTPUTS`.
        schedule: The episode's schedule (:func:`doorlab.episode.schedule.make_schedule`).
        scenario: The control period, the gripper's force limit.
        q_initial: Where the arm starts (7,) [rad] (held when no plan needs the runner).
        t_final: The episode's end [s].
        lag: How long after each tick its command switches on [s]
            (:func:`doorlab.episode.schedule.tick_lag` in simulation).
        gripper_link: (period, delay) [s]: the gripper's setpoint reaches the cell as a
            client sends it to the arm's drivers (:func:`gripper_as_sent`); None: at once.
    """

    def add(system, name: str):
        system.set_name(name)
        return builder.AddSystem(system)

    period = scenario.timeline.control_period
    k = joint_space_prefix(schedule)
    t_first = first_tick(schedule[k].t_start, period) if k < len(schedule) else t_final
    q_ref_sum = add(Adder(2, NUM_JOINTS), "q_ref")
    if k > 0:
        prefix = prefix_trajectory(schedule, k, t_final + 1.0)
        ticks = np.arange(int(np.floor(t_first / period - 1e-9)) + 1) * period
        ticks = ticks[ticks < t_first - 1e-9] if k < len(schedule) else ticks
        samples = np.column_stack([prefix.value(t).ravel() for t in ticks])
        q_handoff = samples[:, -1]
        held = np.column_stack([samples, q_handoff])
        end = t_final + 1.0
        applied = PiecewisePolynomial.ZeroOrderHold([0.0, *(ticks[1:] + lag), end], held)
        joint_source = add(TrajectorySource(applied), "joint_space_plans")
    else:
        q_handoff = np.asarray(q_initial, float)
        joint_source = add(ConstantVectorSource(q_handoff), "joint_space_plans")
    builder.Connect(joint_source.get_output_port(), q_ref_sum.get_input_port(0))
    runner = None
    zero = np.zeros(NUM_JOINTS)
    if k < len(schedule):
        runner = PlanRunner(
            schedule[k:], control_period=period, t_first=t_first, lag=lag, q_offset=q_handoff
        )
        q_ref_source = add(ConstantVectorSource(zero), "plan_runner_q_ref")
        tau_ff_source = add(ConstantVectorSource(zero), "plan_runner_tau_ff")
        runner.connect(
            cell,
            cell.GetOutputPort("iiwa_state"),
            cell.GetOutputPort("iiwa_torque_external"),
            q_ref_source,
            tau_ff_source,
        )
    else:
        q_ref_source = add(ConstantVectorSource(zero), "no_runner")
        tau_ff_source = add(ConstantVectorSource(zero), "no_feedforward")
    q_ref_runner = q_ref_source.get_output_port()
    tau_ff_port = tau_ff_source.get_output_port()
    builder.Connect(q_ref_runner, q_ref_sum.get_input_port(1))
    builder.Connect(q_ref_sum.get_output_port(), cell.GetInputPort("iiwa_position"))
    builder.Connect(tau_ff_port, cell.GetInputPort("iiwa_feedforward_torque"))
    wsg = _wire_gripper(
        builder, cell, schedule, scenario, t_final=t_final, lag=lag, link=gripper_link
    )
    return CommandWiring(runner, q_ref_sum.get_output_port(), tau_ff_port, wsg)


def _wire_gripper(
    builder: DiagramBuilder,
    cell: Diagram,
    schedule: Sequence[ScheduledPlan],
    scenario: Scenario,
    *,
    t_final: float,
    lag: float,
    link: tuple[float, float] | None = None,
) -> OutputPort:
    """The gripper's setpoint: a C++ zero-order hold switching ``lag`` after the tick that
    starts each plan (as the runner's command does), or as sent over ``link``
    (:func:`gripper_as_sent`); the force limit a constant."""
    period = scenario.timeline.control_period
    widths = [s.gripper_width for s in schedule]
    switches = [first_tick(s.t_start, period) + lag for s in schedule[1:]]
    setpoint = PiecewisePolynomial.ZeroOrderHold(
        [0.0, *switches, t_final + 1.0], np.array([[*widths, widths[-1]]])
    )
    if link is not None:
        setpoint = gripper_as_sent(
            setpoint, scenario.station.gripper.initial_width, *link, t_final=t_final
        )
    wsg = builder.AddSystem(TrajectorySource(setpoint))
    wsg.set_name("wsg_position")
    builder.Connect(wsg.get_output_port(), cell.GetInputPort("wsg_position"))
    force_limit = builder.AddSystem(ConstantVectorSource([scenario.station.gripper.force_limit]))
    force_limit.set_name("wsg_force_limit")
    builder.Connect(force_limit.get_output_port(), cell.GetInputPort("wsg_force_limit"))
    return wsg.get_output_port()


def gripper_as_sent(
    setpoint: PiecewisePolynomial,
    initial_width: float,
    period: float,
    delay: float,
    *,
    t_final: float,
) -> PiecewisePolynomial:
    """The gripper's setpoint as a hardware client sends it and the arm's drivers apply it: the
    client publishes the setpoint at j x ``period`` (its 20 Hz ``SCHUNK_WSG_COMMAND``), each
    value acts ``delay`` later (the driver's next cycle); before the first, ``initial_width``.

    Args:
        setpoint: The episode's setpoint [m] as a function of time.
        initial_width: What the gripper holds before the first command [m].
        period: The client's publish period [s]. delay: From a publish to its effect [s].
        t_final: The episode's end [s].
    """
    sends = np.arange(int(np.floor((t_final + 1.0) / period)) + 1) * period
    values = [initial_width, *(float(setpoint.value(t)[0, 0]) for t in sends)]
    breaks = [0.0, *(sends + delay)]
    return PiecewisePolynomial.ZeroOrderHold(
        [*breaks, breaks[-1] + period], np.array([[*values, values[-1]]])
    )


class EpisodeLogger:
    """One logger of named channels: one C++ Multiplexer, one publish per sample (not one
    per channel), every ``period`` [s]."""

    def __init__(self, builder: DiagramBuilder, channels: Mapping[str, OutputPort], period: float):
        self.names = tuple(channels)
        self._sizes = [port.size() for port in channels.values()]
        mux = builder.AddSystem(Multiplexer(self._sizes))
        mux.set_name("log_channels")
        for i, port in enumerate(channels.values()):
            builder.Connect(port, mux.get_input_port(i))
        self.sink: VectorLogSink = LogVectorOutput(mux.get_output_port(), builder, period)

    def read(self, context) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The sample times (n,) [s] and each channel's samples (n, size), from the root
        ``context`` of the built diagram."""
        log = self.sink.FindLog(context)
        columns = np.cumsum([0, *self._sizes])
        samples = log.data().T
        data = {
            name: samples[:, start:end]
            for name, start, end in zip(self.names, columns[:-1], columns[1:], strict=True)
        }
        return log.sample_times(), data
