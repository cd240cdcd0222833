"""Jacobian velocity mapping with the arc's velocity fed forward: a doorlab controller plug-in.

    V_des = V_ref + (kw theta n; kv e),   q_dot = J^+ V_des (clipped),   q_ref = q + q_dot dt

e = p_WQ_ref - p_WQ [m] and theta n L7's orientation error [rad], both in W; V_ref the
reference's spatial velocity at Q (angular; translational) [rad/s, m/s], in W, from the arc:
the handle moves along a circle about the hinge at a constant angular rate, sweep / T, and L7's
reference turns about W's z axis at the same rate, in the opposite sense of the hinge angle.
"""

from __future__ import annotations

import numpy as np
from pydrake.multibody.tree import JacobianWrtVariable

import doorlab
from doorlab.control.laws import pose_error, pseudo_inverse_solve

__all__ = ["CONTROLLER", "FeedforwardPlan", "build", "reference_velocity"]

P_L7Q = np.array([0.0, 0.0, 0.214])
"""The grasp point Q in L7 [m] (doorlab.cell.frames.p_L7Q)."""


def reference_velocity(geometry, tau: float, duration: float) -> np.ndarray:
    """The arc's spatial velocity at Q, (angular; translational) in W (6,) [rad/s, m/s], at
    tau in [0, 1] of an arc of ``duration`` [s] (zero outside the arc)."""
    if not 0.0 <= tau <= 1.0:
        return np.zeros(6)
    rate = geometry.sweep / duration  # [rad/s] the handle's angle about the hinge
    theta = geometry.theta0 + geometry.sweep * tau
    r = geometry.r_handle
    # p = p_hinge - r (sin theta, cos theta, 0): its derivative with theta' = rate
    v = -r * rate * np.array([np.cos(theta), -np.sin(theta), 0.0])
    w = np.array([0.0, 0.0, -rate])  # R_WL7_ref's yaw is -sweep tau (+ the cupboard's)
    return np.concatenate((w, v))


class FeedforwardPlan:
    """The plan: see the module docstring. ``kv``, ``kw`` [1/s] as the velocity plan's."""

    name = "feedforward"

    def __init__(
        self,
        geometry,
        duration: float,
        plant,
        dt: float,
        *,
        kv: float = 100.0,
        kw: float = 50.0,
        speed_limit: float = 1.0,
    ) -> None:
        self.geometry, self.duration, self.dt = geometry, duration, dt
        self.kv, self.kw, self.speed_limit = kv, kw, speed_limit
        self.plant = plant
        self.context = plant.CreateDefaultContext()
        self.L7 = plant.GetFrameByName("iiwa_link_7")
        self.W = plant.world_frame()

    def command(self, t: float, state: doorlab.ArmState) -> doorlab.Command:
        """q_ref from the feed-forward and the pose error at t [s] since the arc started."""
        tau = t / self.duration
        clipped = min(max(tau, 0.0), 1.0)
        self.plant.SetPositions(self.context, state.q)
        X_WL7 = self.L7.CalcPoseInWorld(self.context)
        error = pose_error(
            X_WL7 @ P_L7Q,
            X_WL7.rotation(),
            self.geometry.p_WQ_ref(clipped),
            self.geometry.R_WL7_ref(clipped),
        )
        J = self.plant.CalcJacobianSpatialVelocity(
            self.context, JacobianWrtVariable.kV, self.L7, P_L7Q, self.W, self.W
        )
        V = reference_velocity(self.geometry, tau, self.duration) + np.concatenate(
            (self.kw * error.theta_n_W, self.kv * error.e_xyz_W)
        )
        q_dot = np.clip(pseudo_inverse_solve(J, V), -self.speed_limit, self.speed_limit)
        return doorlab.Command(state.q + q_dot * self.dt, np.zeros(7))


def build(scenario, geometry, plant) -> doorlab.ArcPlan:
    """The plan along the scenario's arc, from the velocity plan's grasp configuration."""
    plan = FeedforwardPlan(
        geometry, scenario.timeline.arc_duration, plant, scenario.timeline.control_period
    )
    return doorlab.ArcPlan(plan, doorlab.grasp_configuration(scenario, geometry, plant))


CONTROLLER = doorlab.Controller(
    name="feedforward",
    title="Velocity mapping with feed-forward",
    summary="q_dot = J^+ (V_ref + K e): the arc's velocity fed forward, the pose error fed back",
    build=build,
)
"""What the entry point names (``pyproject.toml``:
``feedforward = "doorlab_feedforward:CONTROLLER"``)."""
