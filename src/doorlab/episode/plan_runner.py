"""The plan runner: the outer loop that executes the scheduled plans at the control period.

The same runner drives the simulated station and the real cell: it reads the cell's output
ports ``iiwa_state`` and ``iiwa_torque_external`` and sets the values of two C++ sources that
:mod:`doorlab.episode.wiring` connects to ``iiwa_position`` and ``iiwa_feedforward_torque``.

It is not a system of the diagram: the episode advances the simulator through
:meth:`PlanRunner.advance_to`, which stops the simulator at each tick, runs the plan there and
sets the command. Any Python ``LeafSystem`` in a diagram costs at every simulation step, not
only at its own events: Drake's ``Simulator`` asks every subsystem for its witness functions
after each discrete update (each plant step), and pydrake answers for a Python system by
taking the GIL and looking for a Python override (about 9,000 instructions a step, and 6-7 %
of a closed-door episode's CPU time with a system that never ticks; issue 35,
``docs/explanation/performance.md``). With the ticks driven from here the diagram is C++ only
and Python runs at the control period alone.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Diagram, OutputPort
from pydrake.systems.primitives import ConstantVectorSource

from doorlab.constants import NUM_JOINTS
from doorlab.control.plan_base import ArmState
from doorlab.episode.schedule import ScheduledPlan


class PlanRunner:
    """Executes a schedule of plans at a fixed control period (the outer loop), in Python.

    The episode hands it only the part of the schedule that needs feedback, from ``t_first``
    (the first tick) on; before that its commands are zero. It sends q_ref - ``q_offset``: the
    episode adds ``q_offset`` back in C++ (the joint-space trajectory's end value, which the
    trajectory source keeps sending), so q_ref is continuous at the handoff.

    Timing: the plan ticking at t_k = t_first + k period sees the arm after every plant step at
    or before t_k, and its command acts from the first plant step after t_k. The runner stops
    the simulator ``lag`` after each tick (the simulated episode passes
    :func:`doorlab.episode.schedule.tick_lag`: half the grid that ticks and plant steps share,
    so no step lies in between; the default 0 stops at the tick itself) and hands the plan t_k
    itself. (A stop at t_k exactly would leave that order to float rounding when t_k is a
    plant step: at the default 5 ms / 2 ms about one such tick in five fell an ulp before the
    step, saw the arm one step earlier and acted one step sooner, or an ulp after it.) The
    stop times are Drake's for a periodic event with offset t_first + lag, so the episode is
    the one a ``LeafSystem`` with that event gave, bit for bit.

    Ports (:meth:`connect`): reads ``iiwa_state`` (14: q [rad], v [rad/s]) and
    ``iiwa_torque_external`` (7) [N m]; sets the values of the q_ref and tau_ff sources (7).
    """

    def __init__(
        self,
        schedule: Sequence[ScheduledPlan],
        *,
        control_period: float,
        t_first: float = 0.0,
        lag: float = 0.0,
        q_offset: np.ndarray | None = None,
    ):
        self._period = control_period
        self._t_first = t_first
        self._lag = lag
        self._offset = t_first + lag  # the stop times: offset + k period, as Drake sums them
        self._schedule = list(schedule)
        self._starts = [s.t_start for s in self._schedule]
        self._cursor = 0
        self._q_offset = (
            np.zeros(NUM_JOINTS) if q_offset is None else np.asarray(q_offset, float).copy()
        )
        self._io: tuple | None = None  # (state, torque_external, cell, q_ref, tau_ff)
        self._simulator = None  # the simulator it last advanced, its contexts, the next tick
        self._contexts: tuple = ()
        self._next = 0

    def connect(
        self,
        cell: Diagram,
        state: OutputPort,
        torque_external: OutputPort,
        q_ref: ConstantVectorSource,
        tau_ff: ConstantVectorSource,
    ) -> None:
        """Where the runner reads and writes (the wiring calls this once, before the build).

        Args:
            cell: The cell's system, which owns ``state`` and ``torque_external``.
            state: Its ``iiwa_state`` port. torque_external: Its ``iiwa_torque_external``.
            q_ref: The source of q_ref - q_offset (7) [rad]. tau_ff: The source of tau_ff (7).
        """
        self._io = (state, torque_external, cell, q_ref, tau_ff)

    def active(self, t: float) -> ScheduledPlan:
        """The scheduled plan active at time t [s] (the last one after the schedule ends)."""
        # Ticks come in increasing time: move a cursor instead of searching the schedule.
        while self._cursor + 1 < len(self._schedule) and t >= self._starts[self._cursor + 1]:
            self._cursor += 1
        while self._cursor > 0 and t < self._starts[self._cursor]:
            self._cursor -= 1
        return self._schedule[self._cursor]

    def advance_to(self, simulator: Simulator, t: float) -> None:
        """``simulator.AdvanceTo(t)``, running every tick whose stop (t_k + lag) is at or
        before ``t`` [s] on the way (a tick whose stop is ``t`` itself runs before the first
        step after ``t``, as a discrete update at ``t`` would)."""
        io = self._bind(simulator)
        period, offset, k = self._period, self._offset, self._next
        while (t_stop := offset + k * period) <= t:
            simulator.AdvanceTo(t_stop)
            self._tick(k, io)
            k += 1
            self._next = k
        simulator.AdvanceTo(t)

    def _tick(self, k: int, io: tuple) -> None:
        """Tick k (at t_k): the arm as the cell reports it, the active plan, its command."""
        state, torque, cell_context, q_source, q_context, tau_source, tau_context = io
        x = state.Eval(cell_context)
        t = self._t_first + k * self._period
        scheduled = self.active(t)
        command = scheduled.plan.command(
            t - scheduled.t_start,
            ArmState(x[:NUM_JOINTS], x[NUM_JOINTS:], torque.Eval(cell_context)),
        )
        # Mutable access is what tells Drake the values changed: ask for it at each tick.
        q_source.get_mutable_source_value(q_context).SetFromVector(command.q_ref - self._q_offset)
        tau_source.get_mutable_source_value(tau_context).SetFromVector(command.tau_ff)

    def _bind(self, simulator: Simulator) -> tuple:
        """The ports and the contexts in ``simulator``'s; on a simulator not seen before, the
        next tick is the first whose stop is after its time."""
        if self._io is None:
            raise RuntimeError("PlanRunner.connect() was not called (doorlab's wiring does it)")
        if self._simulator is not simulator:
            root = simulator.get_mutable_context()
            state, torque, cell, q_source, tau_source = self._io
            self._contexts = (
                state,
                torque,
                cell.GetMyContextFromRoot(root),
                q_source,
                q_source.GetMyMutableContextFromRoot(root),
                tau_source,
                tau_source.GetMyMutableContextFromRoot(root),
            )
            self._next = max(0, math.floor((root.get_time() - self._offset) / self._period) + 1)
            self._simulator = simulator
        return self._contexts
