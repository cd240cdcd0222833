"""What a plan is: the arm's state it reads, the command it sends, and the joint-space plan.

A plan maps (time since the plan started, measured arm state) to a command (q_ref, tau_ff):
the :class:`Plan` protocol the plan runner executes, one control tick at a time.
:class:`JointSpacePlan` replays a joint trajectory (task 1's, a hold, a move). The task-space
plans of tasks 2 and 3 (:mod:`doorlab.control.plans`) build on this module; this one holds no
control law, so what runs a student's plans (the problem set's simulator) needs nothing of
doorlab's own solutions.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

import numpy as np
from pydrake.trajectories import PiecewisePolynomial

from doorlab.constants import NUM_JOINTS
from doorlab.errors import ConfigError


class ArmState(NamedTuple):
    """Measured arm state at a control tick, the joints in order ``iiwa_joint_1`` .. ``_7``.

    Attributes:
        q: Joint positions (7,) [rad].
        v: Joint velocities (7,) [rad/s] (on the lab's arm: kuka_driver's filtered estimate).
        tau_external: The external (contact) torques on the joints (7,) [N m]: in
            simulation the contact forces' generalized torques on the arm; on the arm KUKA's
            estimate (measured torque minus its model's).
    """

    q: np.ndarray
    v: np.ndarray
    tau_external: np.ndarray


class Command(NamedTuple):
    """What a plan sends to the inner loop, which applies
    tau = Kq (q_ref - q) - Dq v + g(q) + tau_ff (the lab arm: KUKA's joint impedance).

    Attributes:
        q_ref: Joint position reference (7,) [rad].
        tau_ff: Feed-forward joint torque (7,) [N m], added to the loop's.
    """

    q_ref: np.ndarray
    tau_ff: np.ndarray


class Plan(Protocol):
    """Anything the plan runner can execute: a name, a duration [s], and a command per control
    tick (every ``timeline.control_period``, 5 ms, in Python).

    A plan may also offer ``log_table() -> dict[str, numpy.ndarray]``: its own per-tick
    channels (with a ``t`` column [s] since it started), saved in ``log.npz`` as
    ``plan_log.<channel>``.
    """

    name: str
    duration: float  # [s]

    def command(self, t: float, state: ArmState) -> Command:
        """Command at time t [s] since the plan started (t may exceed duration: the plan
        stays active 1 s longer, hold there), from the measured ``state``."""
        ...


_ZERO_TORQUE = np.zeros(NUM_JOINTS)


class JointSpacePlan:
    """Sends q_ref = q_traj(t) (clamped to the trajectory's time span) and tau_ff = 0."""

    def __init__(self, trajectory: PiecewisePolynomial, *, name: str = "joint_space"):
        if trajectory.rows() != NUM_JOINTS or trajectory.cols() != 1:
            raise ConfigError(
                f"a JointSpacePlan needs a ({NUM_JOINTS}, 1) trajectory, got "
                f"({trajectory.rows()}, {trajectory.cols()})"
            )
        self.name = name
        self.trajectory = trajectory
        self.duration = trajectory.end_time() - trajectory.start_time()

    def command(self, t: float, state: ArmState) -> Command:
        """q_ref from the trajectory; the measured state is not used."""
        t_traj = min(
            max(t + self.trajectory.start_time(), self.trajectory.start_time()),
            self.trajectory.end_time(),
        )
        return Command(self.trajectory.value(t_traj).ravel(), _ZERO_TORQUE)

    @classmethod
    def hold(cls, q: np.ndarray, duration: float, *, name: str = "hold") -> JointSpacePlan:
        """Holds q (7,) [rad] for duration [s]."""
        knots = np.column_stack([q, q])
        return cls(PiecewisePolynomial.ZeroOrderHold([0.0, duration], knots), name=name)

    @classmethod
    def cubic(
        cls, times: np.ndarray, q_knots: np.ndarray, *, name: str = "joint_space"
    ) -> JointSpacePlan:
        """Cubic spline through q_knots (n, 7) at times (n,) [s], zero end velocities."""
        q_knots = np.asarray(q_knots, dtype=float)
        zero = np.zeros((NUM_JOINTS, 1))
        trajectory = PiecewisePolynomial.CubicWithContinuousSecondDerivatives(
            np.asarray(times, dtype=float), q_knots.T, zero, zero
        )
        return cls(trajectory, name=name)
