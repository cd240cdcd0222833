"""Plans: what the plan runner executes, one control tick at a time.

A plan maps (time since the plan started, measured arm state) to a command (q_ref, tau_ff)
(:mod:`doorlab.control.plan_base`: the protocol, the state, the command and
:class:`JointSpacePlan`, task 1's, re-exported here). :class:`TaskSpaceVelocityPlan`
(task 2) and :class:`TaskSpaceImpedancePlan` (task 3) close a loop on the pose of L7 and Q
through their own controller plant, never the simulation plant.
"""

from __future__ import annotations

import numpy as np
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import JacobianWrtVariable

from doorlab.cell.frames import L7_FRAME, p_L7Q
from doorlab.cell.geometry import DoorGeometry
from doorlab.config import ImpedancePlanConfig, VelocityPlanConfig
from doorlab.control.laws import PoseError, impedance_law, pose_error, velocity_law
from doorlab.control.plan_base import (  # noqa: F401 - re-exported: doorlab.control.plans.*
    _ZERO_TORQUE,
    ArmState,
    Command,
    JointSpacePlan,
    Plan,
)

_KV = JacobianWrtVariable.kV  # looked up once, not at every tick


class _TaskSpacePlan:
    """Shared part of tasks 2 and 3: the pose error of Q and L7 and the Jacobian at Q."""

    def __init__(
        self,
        geometry: DoorGeometry,
        duration: float,
        controller_plant: MultibodyPlant,
        name: str,
    ):
        self.name = name
        self.duration = duration
        self.geometry = geometry
        self._plant = controller_plant
        self._context = controller_plant.CreateDefaultContext()
        self._L7 = controller_plant.GetFrameByName(L7_FRAME)
        self._W = controller_plant.world_frame()

    def error_and_jacobian(self, t: float, q: np.ndarray) -> tuple[PoseError, np.ndarray]:
        """Pose error at time t [s] and Jv_V_WL7q (6, 7) at measured q (7,) [rad]."""
        self._plant.SetPositions(self._context, q)
        X_WL7: RigidTransform = self._L7.CalcPoseInWorld(self._context)
        # X_WL7 p_L7Q, computed in C++ from the cached kinematics (bit-identical to X_WL7 @
        # p_L7Q, 1 us instead of 3 us: this runs at every control tick).
        p_WQ = self._plant.CalcPointsPositions(self._context, self._L7, p_L7Q, self._W)[:, 0]
        Jv_V_WL7q = self._plant.CalcJacobianSpatialVelocity(
            self._context, _KV, self._L7, p_L7Q, self._W, self._W
        )
        tau = t / self.duration
        error = pose_error(
            p_WQ, X_WL7.rotation(), self.geometry.p_WQ_ref(tau), self.geometry.R_WL7_ref(tau)
        )
        return error, Jv_V_WL7q


class TaskSpaceVelocityPlan(_TaskSpacePlan):
    """Task 2: q_ref = q + J^+ V_des dt, tau_ff = 0 (dt = the control period).

    ``lead`` replaces dt per joint (``velocity.lead: inner_loop``: the lead a stiffness loop
    needs to reach a joint speed, :func:`doorlab.control.adaptive.velocity_lead`).
    """

    def __init__(
        self,
        geometry: DoorGeometry,
        duration: float,
        controller_plant: MultibodyPlant,
        config: VelocityPlanConfig,
        control_period: float,
        lead: np.ndarray | None = None,
    ):
        super().__init__(geometry, duration, controller_plant, "velocity")
        self.config = config
        self.control_period = control_period
        self.lead = control_period if lead is None else np.asarray(lead, dtype=float)

    def command(self, t: float, state: ArmState) -> Command:
        """Maps the pose error to joint velocities through the pseudo-inverse."""
        error, J = self.error_and_jacobian(t, state.q)
        c = self.config
        qdot = velocity_law(error, J, kv=c.kv, kw=c.kw, joint_speed_limit=c.joint_speed_limit)
        return Command(state.q + qdot * self.lead, _ZERO_TORQUE)


class TaskSpaceImpedancePlan(_TaskSpacePlan):
    """Task 3: tau_ff = J^T F, q_ref = measured q."""

    def __init__(
        self,
        geometry: DoorGeometry,
        duration: float,
        controller_plant: MultibodyPlant,
        config: ImpedancePlanConfig,
    ):
        super().__init__(geometry, duration, controller_plant, "impedance")
        self.config = config

    def command(self, t: float, state: ArmState) -> Command:
        """Maps the pose error to a spatial force and joint torques through J^T."""
        error, J = self.error_and_jacobian(t, state.q)
        c = self.config
        tau_ff = impedance_law(error, J, kv=c.kv, kw=c.kw, torque_limit=c.torque_limit)
        return Command(np.array(state.q, dtype=float), tau_ff)
