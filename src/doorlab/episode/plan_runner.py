"""The plan runner: the outer loop that executes the scheduled plans at the control period.

The same system runs on the simulated station and on the real cell: it reads the ports
``iiwa_state`` and ``iiwa_torque_external`` and writes ``iiwa_position`` and
``iiwa_feedforward_torque`` (:mod:`doorlab.episode.wiring` wires it to either).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from pydrake.systems.framework import LeafSystem

from doorlab.constants import NUM_JOINTS
from doorlab.control.plan_base import ArmState
from doorlab.episode.schedule import ScheduledPlan


class PlanRunner(LeafSystem):
    """Executes a schedule of plans at a fixed control period (the outer loop), in Python.

    The episode hands it only the part of the schedule that needs feedback, from ``t_first``
    (the first tick) on; before that its outputs are zero. It sends q_ref - ``q_offset``: the
    episode adds ``q_offset`` back in C++ (the joint-space trajectory's end value, which the
    trajectory source keeps sending), so q_ref is continuous at the handoff.

    Timing: the plan ticking at t_k = t_first + k period sees the arm after every plant step at
    or before t_k, and its command acts from the first plant step after t_k. The runner's
    update event fires ``lag`` after each tick (the simulated episode passes
    :func:`doorlab.episode.schedule.tick_lag`: half the grid that ticks and plant steps share, so no
    step lies in between; the default 0 fires at the tick itself) and hands the plan t_k
    itself. (An
    event at t_k exactly would leave that order to float rounding when t_k is a plant step:
    Drake sums offset + k period and n time_step separately, and at the default 5 ms / 2 ms
    about one such tick in five fell an ulp before the step, saw the arm one step earlier
    and acted one step sooner, or an ulp after it.)

    Input ports: ``iiwa_state`` (14: q [rad], v [rad/s]), ``iiwa_torque_external`` (7).
    Output ports (state outputs, no Python per simulation step): ``iiwa_position`` (q_ref),
    ``iiwa_feedforward_torque`` (tau_ff).
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
        super().__init__()
        self.set_name("plan_runner")
        self._period = control_period
        self._t_first = t_first
        self._lag = lag
        self._schedule = list(schedule)
        self._starts = [s.t_start for s in self._schedule]
        self._cursor = 0
        self._x = self.DeclareVectorInputPort("iiwa_state", 2 * NUM_JOINTS)
        self._tau_ext = self.DeclareVectorInputPort("iiwa_torque_external", NUM_JOINTS)
        self._q_offset = (
            np.zeros(NUM_JOINTS) if q_offset is None else np.asarray(q_offset, float).copy()
        )
        self._q_ref = self.DeclareDiscreteState(NUM_JOINTS)
        self._tau_ff = self.DeclareDiscreteState(NUM_JOINTS)
        self.DeclareStateOutputPort("iiwa_position", self._q_ref)
        self.DeclareStateOutputPort("iiwa_feedforward_torque", self._tau_ff)
        self.DeclarePeriodicDiscreteUpdateEvent(control_period, t_first + lag, self._tick)

    def active(self, t: float) -> ScheduledPlan:
        """The scheduled plan active at time t [s] (the last one after the schedule ends)."""
        # Ticks come in increasing time: move a cursor instead of searching the schedule.
        while self._cursor + 1 < len(self._schedule) and t >= self._starts[self._cursor + 1]:
            self._cursor += 1
        while self._cursor > 0 and t < self._starts[self._cursor]:
            self._cursor -= 1
        return self._schedule[self._cursor]

    def _tick(self, context, discrete_state) -> None:
        k = round((context.get_time() - self._lag - self._t_first) / self._period)
        t = self._t_first + k * self._period
        scheduled = self.active(t)
        x = self._x.Eval(context)
        state = ArmState(x[:NUM_JOINTS], x[NUM_JOINTS:], self._tau_ext.Eval(context))
        command = scheduled.plan.command(t - scheduled.t_start, state)
        discrete_state.set_value(self._q_ref, command.q_ref - self._q_offset)
        discrete_state.set_value(self._tau_ff, command.tau_ff)
