"""A controller of your own in one file: damped least squares (DLS) along the handle's arc.

doorlab runs it through every command, as it runs its built-ins::

    doorlab run --controller examples/dls_controller.py:dls --doors closed
    doorlab bench --controller examples/dls_controller.py:dls --controller velocity

The problem set's velocity plan maps the pose error through the pseudo-inverse J^+, whose
joint speeds grow without bound near a singularity. DLS (Wampler 1986; Nakamura and Hanafusa
1986) trades a little tracking for bounded speeds there:

    V_des = (kw theta n; kv e),   q_dot = J^T (J J^T + lambda^2 I)^-1 V_des,   q_ref = q + q_dot dt

with e = p_WQ_ref - p_WQ [m] and theta n L7's orientation error [rad] (both in W), J the
(6, 7) Jacobian of L7's spatial velocity at Q in W, lambda the damping [m/s per rad/s]. Only
doorlab's public contract is used (``doorlab.ArcPlan``, ``doorlab.Command``,
``doorlab.grasp_configuration``) and pydrake.
"""

from __future__ import annotations

import numpy as np
from pydrake.multibody.tree import JacobianWrtVariable

import doorlab

P_L7Q = np.array([0.0, 0.0, 0.214])
"""The grasp point Q in L7 [m] (doorlab.cell.frames.p_L7Q)."""


class DampedLeastSquaresPlan:
    """q_ref = q + dt J^T (J J^T + lambda^2 I)^-1 (kw theta n; kv e), tau_ff = 0.

    Args:
        geometry: The believed door (``p_WQ_ref(tau)``, ``R_WL7_ref(tau)``, tau in [0, 1]).
        duration: The arc's duration [s]. plant: The controllers' arm model (7 positions).
        dt: The control period [s]. kv: Position gain [1/s]. kw: Orientation gain [1/s].
        damping: lambda [-]. speed_limit: Clip on each joint speed [rad/s].
    """

    name = "dls"

    def __init__(
        self,
        geometry,
        duration: float,
        plant,
        dt: float,
        *,
        kv: float = 100.0,
        kw: float = 50.0,
        damping: float = 0.05,
        speed_limit: float = 1.0,
    ) -> None:
        self.geometry, self.duration, self.dt = geometry, duration, dt
        self.kv, self.kw, self.damping, self.speed_limit = kv, kw, damping, speed_limit
        self.plant = plant
        self.context = plant.CreateDefaultContext()  # the controller's own context
        self.L7 = plant.GetFrameByName("iiwa_link_7")
        self.W = plant.world_frame()

    def command(self, t: float, state: doorlab.ArmState) -> doorlab.Command:
        """The command at t [s] since the arc started, from the measured state."""
        tau = min(t / self.duration, 1.0)
        self.plant.SetPositions(self.context, state.q)
        X_WL7 = self.L7.CalcPoseInWorld(self.context)
        e = self.geometry.p_WQ_ref(tau) - X_WL7 @ P_L7Q  # [m], in W
        # R_WL7_ref R_WL7^T: L7's orientation error as a rotation in W, as angle x axis
        angle_axis = (self.geometry.R_WL7_ref(tau) @ X_WL7.rotation().inverse()).ToAngleAxis()
        theta_n = angle_axis.angle() * angle_axis.axis()  # [rad]
        J = self.plant.CalcJacobianSpatialVelocity(
            self.context, JacobianWrtVariable.kV, self.L7, P_L7Q, self.W, self.W
        )
        V = np.concatenate((self.kw * theta_n, self.kv * e))
        q_dot = J.T @ np.linalg.solve(J @ J.T + self.damping**2 * np.eye(6), V)
        q_dot = np.clip(q_dot, -self.speed_limit, self.speed_limit)
        return doorlab.Command(state.q + q_dot * self.dt, np.zeros(7))


def dls(scenario, geometry, plant) -> doorlab.ArcPlan:
    """Damped least squares along the arc (lambda 0.05), from the velocity plan's grasp."""
    plan = DampedLeastSquaresPlan(
        geometry, scenario.timeline.arc_duration, plant, scenario.timeline.control_period
    )
    return doorlab.ArcPlan(plan, doorlab.grasp_configuration(scenario, geometry, plant))
