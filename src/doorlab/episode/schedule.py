"""The episode's timeline: the scheduled plans and the joint-space trajectory they start with.

Timeline of an episode (the original's, station facts §4): hold q_initial, move with a cubic to
the first user plan's start, then the user's plans; every plan stays active for its duration
plus ``PLAN_SETTLE_TIME``; ``extra_time`` follows the last plan. Shared by the simulated and
the real cell (:mod:`doorlab.episode`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from pydrake.trajectories import PiecewisePolynomial

from doorlab.config import Scenario
from doorlab.control.plan_base import JointSpacePlan, Plan
from doorlab.errors import ConfigError

PLAN_SETTLE_TIME = 1.0
"""Every plan stays active this long after its duration [s] (the original's timeline)."""


@dataclass(frozen=True)
class ScheduledPlan:
    """A plan with its active window [t_start, t_end) [s] and its gripper setpoint [m]."""

    plan: Plan
    t_start: float
    t_end: float
    gripper_width: float


def make_schedule(
    plans: Sequence[Plan],
    gripper_widths: Sequence[float],
    *,
    q_initial: np.ndarray,
    q_start: np.ndarray,
    scenario: Scenario,
) -> list[ScheduledPlan]:
    """The original timeline: hold, cubic move to ``q_start``, then ``plans``.

    Args:
        plans: The user's plans, in order.
        gripper_widths: Finger separation setpoint for each user plan [m].
        q_initial: Where the arm starts (7,) [rad].
        q_start: Where the first user plan starts (7,) [rad].
        scenario: Durations and the approach gripper width.
    """
    if len(plans) != len(gripper_widths):
        raise ConfigError(
            f"need one gripper setpoint per plan: {len(plans)} plans, "
            f"{len(gripper_widths)} setpoints"
        )
    if not plans:
        raise ConfigError("need at least one plan")
    timeline = scenario.timeline
    approach = scenario.station.gripper.approach_width
    move = JointSpacePlan.cubic(
        [0.0, timeline.approach_duration], np.vstack([q_initial, q_start]), name="move_to_start"
    )
    every = [
        (JointSpacePlan.hold(q_initial, timeline.hold_duration), approach),
        (move, approach),
        *zip(plans, gripper_widths, strict=True),
    ]
    schedule = []
    t = 0.0
    for plan, width in every:
        t_end = t + plan.duration + PLAN_SETTLE_TIME
        schedule.append(ScheduledPlan(plan, t, t_end, float(width)))
        t = t_end
    return schedule


def joint_space_prefix(schedule: Sequence[ScheduledPlan]) -> int:
    """How many scheduled plans, from the start, are pure joint trajectories (no feedback)."""
    k = 0
    while k < len(schedule) and isinstance(schedule[k].plan, JointSpacePlan):
        k += 1
    return k


def first_tick(t: float, period: float) -> float:
    """The first tick k * period at or after t [s] (float noise tolerated)."""
    return math.ceil(t / period - 1e-9) * period


def tick_lag(time_step: float, period: float) -> float:
    """How long after a tick its command may switch on without missing a plant step [s].

    Ticks and plant steps share the grid of g = gcd(time_step, period); a discrete update at
    tick t_k reaches the plant at its first step after t_k, which is at least g later: a
    switch at t_k + g / 2 does the same, clear of float noise on either side.
    """
    ns = math.gcd(round(time_step * 1e9), round(period * 1e9))
    return 0.5 * ns * 1e-9


def prefix_trajectory(
    schedule: Sequence[ScheduledPlan], k: int, t_final: float
) -> PiecewisePolynomial:
    """The q_ref of the first ``k`` (joint-space) scheduled plans as one trajectory in episode
    time: each plan's trajectory from its start, its end value held until the next plan (the
    last one's until ``t_final``) [rad].

    Args:
        schedule: The episode's schedule. k: :func:`joint_space_prefix` of it (>= 1).
        t_final: Where the trajectory ends [s].
    """
    pieces: list[PiecewisePolynomial] = []
    for i, scheduled in enumerate(schedule[:k]):
        trajectory = scheduled.plan.trajectory
        piece = trajectory.Clone()
        piece.shiftRight(scheduled.t_start - trajectory.start_time())
        t_next = schedule[i + 1].t_start if i + 1 < k else t_final
        q_end = trajectory.value(trajectory.end_time())
        if t_next > piece.end_time():
            hold = PiecewisePolynomial.ZeroOrderHold(
                [piece.end_time(), t_next], np.hstack([q_end, q_end])
            )
            piece.ConcatenateInTime(hold)
        pieces.append(piece)
    total = pieces[0]
    for piece in pieces[1:]:
        total.ConcatenateInTime(piece)
    return total
