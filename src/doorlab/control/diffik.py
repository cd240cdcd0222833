"""Differential IK with joint limits along the handle's arc: the ``diffik`` controller.

The law (:func:`diffik_law`) asks Drake's differential-IK QP
(``pydrake.multibody.inverse_kinematics.DoDifferentialInverseKinematics``, in Drake 1.51 and
1.58 alike) for the joint velocity whose task velocity J v has the direction of the velocity
plan's V_des = (Kw theta n; Kv e) and as much of its size as the joint position and velocity
limits allow::

    max alpha - |P (v - K (q_nominal - q))|^2 / 100   over v, alpha
    s.t.  J v = alpha V_des,  0 <= alpha <= 1,
          q_min <= q + v dt <= q_max,  -v_max <= v <= v_max

(P spans J's null space; K, the centering gain, is 0 by default: the null-space motion is
then the least, as J^+'s). The problem set's velocity plan clips each joint of J^+ V_des on
its own instead, which turns the task velocity off V_des's direction and knows no position
limit.

The plan (:class:`DiffIkPlan`) integrates the solution into its own joint state, q_ref <- q_ref
+ v dt, and computes the error and J at that state, as Drake's
``DifferentialInverseKinematicsIntegrator`` does (the velocity plan: at the measured q, with
q_ref = q + v dt). So q_ref runs ahead of the measured arm by what the inner loop needs, and
the arm follows it as it follows IK's spline.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from pydrake.multibody.inverse_kinematics import (
    DifferentialInverseKinematicsParameters,
    DifferentialInverseKinematicsStatus,
    DoDifferentialInverseKinematics,
)
from pydrake.multibody.plant import MultibodyPlant

from doorlab.cell.geometry import DoorGeometry
from doorlab.config import DiffIkPlanConfig
from doorlab.constants import JOINT_POSITION_LIMITS, NUM_JOINTS
from doorlab.control.laws import PoseError, desired_spatial_vector
from doorlab.control.plans import ArmState, Command, _TaskSpacePlan

LOG_CHANNELS = (
    "t",  # [s] time since the plan started (the episode's time in EpisodeResult.plan_log)
    "scale",  # [-] |J v| / |V_des|: 1 when the limits allowed all of V_des (nan: V_des = 0)
    "solved",  # 1 when the QP found a solution, else 0 (the plan then holds q_ref)
)
"""The named channels of the diffik plan's log, with units."""


def diffik_parameters(
    control_period: float,
    *,
    joint_speed_limit: float,
    position_lower: np.ndarray,
    position_upper: np.ndarray,
    q_nominal: np.ndarray | None = None,
    centering_gain: float = 0.0,
) -> DifferentialInverseKinematicsParameters:
    """Drake's differential-IK parameters for the arm (7 joints).

    Args:
        control_period: The QP's time step dt [s] (the position limits are on q + v dt).
        joint_speed_limit: Symmetric joint velocity limit [rad/s].
        position_lower, position_upper: Joint position limits (7,) [rad].
        q_nominal: The null space's pull target (7,) [rad] (default: zeros, unused at K = 0).
        centering_gain: Drake's joint centering gain K [1/s].
    """
    n = NUM_JOINTS
    params = DifferentialInverseKinematicsParameters(n, n)
    params.set_time_step(control_period)
    params.set_joint_position_limits((np.asarray(position_lower), np.asarray(position_upper)))
    limit = np.full(n, float(joint_speed_limit))
    params.set_joint_velocity_limits((-limit, limit))
    if q_nominal is not None:
        params.set_nominal_joint_position(np.asarray(q_nominal, dtype=float))
    params.set_joint_centering_gain(centering_gain * np.eye(n))
    return params


class DiffIkCommand(NamedTuple):
    """Output of :func:`diffik_law`.

    Attributes:
        qdot: Joint velocities (7,) [rad/s] (zeros when the QP found no solution).
        V_des: The task velocity asked for (6,) [rad/s; m/s].
        scale: |J qdot| / |V_des| in [0, 1] (nan when V_des = 0). solved: The QP's success.
    """

    qdot: np.ndarray
    V_des: np.ndarray
    scale: float
    solved: bool


def diffik_law(
    error: PoseError,
    Jv_V_WL7q: np.ndarray,
    q: np.ndarray,
    v: np.ndarray,
    params: DifferentialInverseKinematicsParameters,
    *,
    kv: float,
    kw: float,
) -> DiffIkCommand:
    """V_des = (kw theta n; kv e) solved by Drake's differential-IK QP under ``params``' limits
    (module docstring).

    Args:
        error: Pose error of L7 and Q in W.
        Jv_V_WL7q: Geometric Jacobian of L7 at Q in W (6, 7).
        q: The joint state the limits apply to (7,) [rad]. v: Its velocity (7,) [rad/s]
            (used by acceleration limits only; none are set by :func:`diffik_parameters`).
        params: The QP's limits and time step (:func:`diffik_parameters`).
        kv: Translational gain [1/s]. kw: Rotational gain [1/s].
    """
    V_des = desired_spatial_vector(error, kv, kw)
    result = DoDifferentialInverseKinematics(
        np.asarray(q, dtype=float), np.asarray(v, dtype=float), V_des, Jv_V_WL7q, params
    )
    solved = result.status != DifferentialInverseKinematicsStatus.kNoSolutionFound
    qdot = result.joint_velocities if solved and result.joint_velocities is not None else None
    if qdot is None:
        return DiffIkCommand(np.zeros(NUM_JOINTS), V_des, 0.0, False)
    qdot = np.asarray(qdot, dtype=float).ravel()
    size = float(np.linalg.norm(V_des))
    scale = float(np.linalg.norm(Jv_V_WL7q @ qdot)) / size if size > 0 else float("nan")
    return DiffIkCommand(qdot, V_des, scale, True)


class DiffIkPlan(_TaskSpacePlan):
    """``diffik``: differential IK with joint limits, integrated into q_ref (module docstring).

    Args:
        geometry: The (believed) door. duration: The arc's duration [s].
        controller_plant: The controllers' arm model (its own context).
        config: Gains and limits. control_period: The plan runner's period [s] (the QP's dt
            and the integration step).
    """

    def __init__(
        self,
        geometry: DoorGeometry,
        duration: float,
        controller_plant: MultibodyPlant,
        config: DiffIkPlanConfig,
        control_period: float,
    ):
        super().__init__(geometry, duration, controller_plant, "diffik")
        self.config = config
        self.control_period = control_period
        self._q: np.ndarray | None = None
        self._v = np.zeros(NUM_JOINTS)
        self._params: DifferentialInverseKinematicsParameters | None = None
        self._rows: list[tuple[float, float, float]] = []

    def _start(self, q: np.ndarray) -> None:
        """First tick: integrate from the measured q; pull the null space towards it."""
        c = self.config
        self._q = np.array(q, dtype=float)
        inside = JOINT_POSITION_LIMITS - c.joint_limit_margin
        # A joint already outside the margin keeps its position as its limit (the QP needs a
        # feasible start: v = 0 must satisfy the limits).
        lower = np.minimum(-inside, self._q)
        upper = np.maximum(inside, self._q)
        self._params = diffik_parameters(
            self.control_period,
            joint_speed_limit=c.joint_speed_limit,
            position_lower=lower,
            position_upper=upper,
            q_nominal=self._q.copy(),
            centering_gain=c.centering_gain,
        )

    def command(self, t: float, state: ArmState) -> Command:
        """One tick: the QP at the integrated state, then q_ref <- q_ref + v dt."""
        if self._q is None:
            self._start(state.q)
        error, J = self.error_and_jacobian(t, self._q)
        c = self.config
        command = diffik_law(error, J, self._q, self._v, self._params, kv=c.kv, kw=c.kw)
        self._v = command.qdot
        self._q = self._q + command.qdot * self.control_period
        self._rows.append((t, command.scale, float(command.solved)))
        return Command(self._q.copy(), np.zeros(NUM_JOINTS))

    def log_table(self) -> dict[str, np.ndarray]:
        """The QP's outcome, one row per control tick: {channel: (n,)} (LOG_CHANNELS)."""
        data = np.array(self._rows, dtype=float).reshape(-1, len(LOG_CHANNELS))
        return {name: data[:, i].copy() for i, name in enumerate(LOG_CHANNELS)}
