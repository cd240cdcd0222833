"""The adaptive plan: opens a door whose hinge it does not know.

After the grasp it uses only the measured arm state and the arm's external torques: no
hinge, radius or arc from the model. Per control tick it

1. computes Q's pose, velocity and the Jacobian at Q on its own controller plant;
2. estimates the contact wrench at Q from tau_external (least squares through J^T);
3. updates the hinge estimate from Q's path
   (:class:`doorlab.control.hinge_estimation.HingeEstimator`);
4. commands q_ref = q + q_dot dt with q_dot from :func:`doorlab.control.laws.adaptive_law`: speed
   along the estimated tangent (ramped up, kept on the planned progress by feedback of the
   measured one, slowed down near the target angle), radial
   admittance, Q's grasp height held, L7 turned by the estimated door yaw (from the
   tangent's rotation, then from the hinge fit; rate-limited);
5. records its running estimates (a named table, see :meth:`AdaptivePlan.log_table`).

It stops when its own estimate of the door's rotation reaches ``adaptive.target_angle``.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import JacobianWrtVariable

from doorlab.cell.frames import L7_FRAME, p_L7Q
from doorlab.cell.station import STIFFNESS_LOOPS, loop_gains
from doorlab.config import AdaptivePlanConfig, InnerLoopConfig
from doorlab.constants import NUM_JOINTS
from doorlab.control.hinge_estimation import HingeEstimator, estimate_contact_wrench, signed_angle
from doorlab.control.laws import adaptive_law, orientation_error
from doorlab.control.plan_base import ArmState, Command

LOG_CHANNELS = (
    "t",  # [s] time since the plan started (the episode's time in EpisodeResult.plan_log)
    "hinge_x",  # [m] estimated hinge axis position in W (nan before the fit is trusted)
    "hinge_y",  # [m]
    "radius",  # [m] estimated distance hinge to Q (nan before the fit is trusted)
    "door_angle",  # [rad] estimated counter-clockwise rotation of the door (0 before)
    "fit_ready",  # 1 once the hinge fit is trusted, else 0
    "tangent_x",  # unit direction Q is moved along, in W
    "tangent_y",
    "force_radial",  # [N] estimated contact force on the gripper along the radial estimate
    "force_tangential",  # [N] ... along the tangent estimate
    "speed",  # [m/s] commanded speed along the tangent
    "wrench_residual",  # [N m] external torque no wrench at Q explains
)
"""The named channels of the adaptive plan's log, with units."""


def velocity_lead(inner_loop: InnerLoopConfig, control_period: float) -> np.ndarray:
    """Per-joint lead (7,) [s] turning a desired joint speed into q_ref (AdaptivePlan).

    Stiffness loops (doorlab's, KUKA's): Dq / Kq + dt / 2 (:func:`doorlab.cell.station.loop_gains`).
    The inverse-dynamics PID differentiates q_ref itself, so there the lead is the control
    period (as in the velocity plan).
    """
    if inner_loop.kind in STIFFNESS_LOOPS:
        kq, dq = loop_gains(inner_loop)
        return dq / kq + control_period / 2
    return np.full(NUM_JOINTS, control_period)


def _rot_z(angle: float) -> RotationMatrix:
    return RotationMatrix.MakeZRotation(angle)


class AdaptivePlan:
    """Opens the grasped door along its estimated arc (module docstring).

    Args:
        duration: Nominal duration [s] (the plan keeps commanding after it: hold).
        controller_plant: The controllers' arm model (this plan keeps its own context).
        config: Gains and target.
        control_period: The plan runner's period [s].
        velocity_lead: Per-joint lead (7,) [s]: q_ref = q + q_dot * velocity_lead. The
            stiffness inner loop reaches a joint speed w in steady state only with
            q_ref - q = (Dq / Kq) w, and q_ref is held over a period while q moves on, so
            the lead is Dq / Kq + dt / 2 there (:func:`velocity_lead`); the problem set's velocity
            plan uses dt and gets about half its commanded speed, which its position
            feedback hides, and this plan has none along the tangent.
    """

    def __init__(
        self,
        duration: float,
        controller_plant: MultibodyPlant,
        config: AdaptivePlanConfig,
        control_period: float,
        velocity_lead: np.ndarray,
    ):
        self.name = "adaptive"
        self.velocity_lead = np.asarray(velocity_lead, dtype=float)
        self.duration = duration
        self.config = config
        self.control_period = control_period
        self._plant = controller_plant
        self._context = controller_plant.CreateDefaultContext()
        self._L7 = controller_plant.GetFrameByName(L7_FRAME)
        self._W = controller_plant.world_frame()
        self._target = math.radians(config.target_angle)
        self._estimator: HingeEstimator | None = None
        self._R_WL7_0: RotationMatrix | None = None
        self._z0 = 0.0
        self._yaw_ref = 0.0
        self._tangent_ref: np.ndarray | None = None
        self._s = 0.0  # [m] measured progress along the tangent
        self._s_ref = 0.0  # [m] planned progress
        self._rows: list[tuple[float, ...]] = []

    def _start(self, X_WL7: RigidTransform, p_WQ: np.ndarray) -> None:
        """First tick: remember the grasp pose; pull opposite the approach direction."""
        c = self.config
        self._R_WL7_0 = X_WL7.rotation()
        self._z0 = float(p_WQ[2])
        approach_W = self._R_WL7_0.col(2)  # L7's z axis: the gripper's approach direction
        self._estimator = HingeEstimator(
            -approach_W[:2],
            min_sagitta=c.min_sagitta,
            velocity_time_constant=c.velocity_time_constant,
            min_speed=c.min_speed,
        )

    def command(self, t: float, state: ArmState) -> Command:
        """One control tick (t [s] since the plan started)."""
        c = self.config
        self._plant.SetPositions(self._context, state.q)
        X_WL7 = self._L7.CalcPoseInWorld(self._context)
        p_WQ = X_WL7 @ p_L7Q
        J = self._plant.CalcJacobianSpatialVelocity(
            self._context, JacobianWrtVariable.kV, self._L7, p_L7Q, self._W, self._W
        )
        if self._estimator is None:
            self._start(X_WL7, p_WQ)
        V_WQ = J @ state.v
        estimate = self._estimator.update(p_WQ, V_WQ[3:], self.control_period)
        wrench = estimate_contact_wrench(J, state.tau_external)

        # The planned speed ramps up along a smoothstep: slow while the tangent estimate
        # turns from the initial guess onto the true tangent, so the radial force of that
        # transient stays small. Progress along the tangent: the planned arc length s_ref
        # against the measured one (Q's velocity along the tangent estimate, integrated);
        # feeding back their difference keeps the planned timeline whatever the door's
        # resistance slows the arm by.
        dt = self.control_period
        x = min(t / c.ramp_time, 1.0)
        planned = c.speed * x * x * (3.0 - 2.0 * x)
        self._s += float(V_WQ[3:5] @ estimate.tangent) * dt
        speed = planned + c.progress_gain * (self._s_ref - self._s)
        speed = min(max(speed, 0.0), 2.0 * c.speed)
        if estimate.fit_ready:
            left = max(self._target - abs(estimate.door_angle), 0.0) * estimate.radius
            if c.approach_gain * left < speed:  # near the target: slow down, no wind-up
                speed = c.approach_gain * left
                planned = speed
                self._s_ref = self._s
        self._s_ref += planned * dt
        # The door's yaw: from the hinge fit once it is trusted; before, the rotation of the
        # measured tangent since it settled (ramp plus three filter time constants: by then it
        # has turned from the initial guess onto the true tangent), which misses only the
        # door's rotation before that moment (about a degree).
        if self._tangent_ref is None and t >= c.ramp_time + 3 * c.velocity_time_constant:
            self._tangent_ref = estimate.tangent.copy()
        door_yaw = estimate.door_angle
        if not estimate.fit_ready and self._tangent_ref is not None:
            door_yaw = signed_angle(self._tangent_ref, estimate.tangent)
        step = c.yaw_rate_limit * self.control_period
        self._yaw_ref += min(max(door_yaw - self._yaw_ref, -step), step)
        R_WL7_ref = _rot_z(self._yaw_ref) @ self._R_WL7_0
        command = adaptive_law(
            theta_n_W=orientation_error(X_WL7.rotation(), R_WL7_ref),
            F_Q_W=wrench.F_Q_W,
            tangent_W=estimate.tangent,
            radial_W=estimate.radial,
            height_error=self._z0 - float(p_WQ[2]),
            speed=speed,
            force_gain=c.force_gain,
            force_target=c.force_target,
            kz=c.kz,
            kw=c.kw,
            Jv_V_WL7q=J,
            joint_speed_limit=c.joint_speed_limit,
        )
        F = wrench.F_Q_W[3:5]
        self._rows.append(
            (
                t,
                *estimate.center,
                estimate.radius,
                estimate.door_angle,
                float(estimate.fit_ready),
                *estimate.tangent,
                float(F @ estimate.radial),
                float(F @ estimate.tangent),
                speed,
                wrench.residual,
            )
        )
        return Command(state.q + command.qdot * self.velocity_lead, np.zeros(NUM_JOINTS))

    def log_table(self) -> dict[str, np.ndarray]:
        """The running estimates, one row per control tick: {channel: (n,)} (LOG_CHANNELS)."""
        data = np.array(self._rows, dtype=float).reshape(-1, len(LOG_CHANNELS))
        return {name: data[:, i].copy() for i, name in enumerate(LOG_CHANNELS)}
