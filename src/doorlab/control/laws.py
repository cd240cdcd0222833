"""The control laws of tasks 2 and 3 as pure functions: errors and Jacobian in, command out.

Nothing here touches a simulator; the plans in :mod:`doorlab.control.plans` wrap these laws.
Spatial vectors are ordered (angular, translational), as Drake's geometric Jacobians are.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from pydrake.common.eigen_geometry import AngleAxis
from pydrake.math import RotationMatrix


class PoseError(NamedTuple):
    """Pose error of frame L7 and point Q, both expressed in W.

    Attributes:
        theta_n_W: Orientation error as angle x unit axis (3,) [rad]: rotating L7 by this
            (about an axis through L7's origin, in W) gives the reference orientation.
        e_xyz_W: Position error p_WQ_ref - p_WQ (3,) [m].
    """

    theta_n_W: np.ndarray
    e_xyz_W: np.ndarray


def orientation_error(R_WL7: RotationMatrix, R_WL7_ref: RotationMatrix) -> np.ndarray:
    """Angle-axis of R_L7L7r = R_WL7^T R_WL7_ref, re-expressed in W.

    The angle is in [0, pi] (from the rotation matrix, not a quaternion), so the error never
    flips sign when a quaternion would cross hemispheres.

    Returns:
        theta * n_W, shape (3,) [rad].
    """
    # R_WL7 (R_WL7^T R_WL7_ref) R_WL7^T = R_WL7_ref R_WL7^T: the same rotation, in W.
    angle_axis: AngleAxis = (R_WL7_ref @ R_WL7.inverse()).ToAngleAxis()
    return angle_axis.angle() * angle_axis.axis()


def pose_error(
    p_WQ: np.ndarray, R_WL7: RotationMatrix, p_WQ_ref: np.ndarray, R_WL7_ref: RotationMatrix
) -> PoseError:
    """The problem set's errors: e_xyz = p_WQ_ref - p_WQ and theta n of R_L7L7r, in W."""
    return PoseError(
        theta_n_W=orientation_error(R_WL7, R_WL7_ref),
        e_xyz_W=np.asarray(p_WQ_ref, dtype=float) - np.asarray(p_WQ, dtype=float),
    )


def desired_spatial_vector(error: PoseError, kv: float, kw: float) -> np.ndarray:
    """(Kw theta n; Kv e_xyz), shape (6,): a spatial velocity [rad/s, m/s] (task 2, gains in
    1/s) or a spatial force [N m, N] (task 3, gains in N m/rad and N/m)."""
    return np.concatenate((np.multiply(kw, error.theta_n_W), np.multiply(kv, error.e_xyz_W)))


def pseudo_inverse_solve(J: np.ndarray, V: np.ndarray) -> np.ndarray:
    """J^+ V, the minimum-norm joint velocity that realizes V.

    For a full-row-rank J (6, 7) this is J^T (J J^T)^-1 V, a 6x6 solve (a few times cheaper
    than an SVD); when J J^T is numerically singular it falls back to the SVD-based
    pseudo-inverse, which drops the singular directions.
    """
    JJt = J @ J.T
    try:
        y = np.linalg.solve(JJt, V)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(J) @ V
    # |y| ~ |V| / |J J^T| unless J J^T is (numerically) singular along V: then fall back to
    # the SVD pseudo-inverse, which drops the singular directions (one check, no SVD per tick).
    # (J J^T is a Gram matrix: its largest entry in magnitude is on its diagonal.)
    if not np.abs(y).max() * JJt.diagonal().max() <= 1e10 * (np.abs(V).max() + 1e-300):
        return np.linalg.pinv(J) @ V
    return J.T @ y


def velocity_law(
    error: PoseError,
    Jv_V_WL7q: np.ndarray,
    *,
    kv: float,
    kw: float,
    joint_speed_limit: float,
) -> np.ndarray:
    """Task 2: q_dot_des = J^+ V_des, clipped per joint.

    Args:
        error: Pose error of L7 and Q in W.
        Jv_V_WL7q: Geometric Jacobian of L7 at Q in W, shape (6, 7).
        kv: Translational gain [1/s]. kw: Rotational gain [1/s].
        joint_speed_limit: Symmetric clip on each joint speed [rad/s].

    Returns:
        Desired joint velocities (7,) [rad/s].
    """
    V_des = desired_spatial_vector(error, kv, kw)
    qdot = pseudo_inverse_solve(Jv_V_WL7q, V_des)
    return np.minimum(np.maximum(qdot, -joint_speed_limit), joint_speed_limit)


def impedance_law(
    error: PoseError,
    Jv_V_WL7q: np.ndarray,
    *,
    kv: float,
    kw: float,
    torque_limit: float,
) -> np.ndarray:
    """Task 3: tau_ff = J^T F with F = (Kw theta n; Kv e_xyz), clipped per joint.

    Args:
        error: Pose error of L7 and Q in W.
        Jv_V_WL7q: Geometric Jacobian of L7 at Q in W, shape (6, 7).
        kv: Translational stiffness [N/m]. kw: Rotational stiffness [N m/rad].
        torque_limit: Symmetric clip on each joint torque [N m].

    Returns:
        Feedforward joint torques (7,) [N m].
    """
    F = desired_spatial_vector(error, kv, kw)
    return np.minimum(np.maximum(Jv_V_WL7q.T @ F, -torque_limit), torque_limit)


class AdaptiveCommand(NamedTuple):
    """Output of :func:`adaptive_law`.

    Attributes:
        qdot: Desired joint velocities (7,) [rad/s], clipped.
        V_des: The spatial velocity they realize before clipping, (angular; translational)
            (6,) [rad/s, m/s].
    """

    qdot: np.ndarray
    V_des: np.ndarray


def adaptive_law(
    *,
    theta_n_W: np.ndarray,
    F_Q_W: np.ndarray,
    tangent_W: np.ndarray,
    radial_W: np.ndarray,
    height_error: float,
    speed: float,
    force_gain: float,
    force_target: float,
    kz: float,
    kw: float,
    Jv_V_WL7q: np.ndarray,
    joint_speed_limit: float,
) -> AdaptiveCommand:
    """The adaptive plan's law: move along the estimated tangent, comply along the estimated
    radial direction (Karayiannidis et al., T-RO 2016), hold Q's height, turn L7 with the
    estimated door yaw::

        v = speed t + force_gain (F . r + force_target) r + kz e_z z,   w = kw theta n,
        q_dot = J^+ (w; v)

    F . r is the radial component of the force the handle applies to the gripper, so
    force_target is the outward pull the robot should exert on the handle [N]; with
    force_target = 0 the gripper yields to any radial force (an admittance), which turns its
    motion onto the true circle whatever the tangent estimate's error.

    Args:
        theta_n_W: Orientation error of L7 against the reference, in W (3,) [rad].
        F_Q_W: Contact wrench on the gripper at Q, (torque; force) in W (6,) [N m, N].
        tangent_W, radial_W: Unit horizontal directions in W (3,) (or (2,): z = 0).
        height_error: Q's reference height minus its height [m].
        speed: Speed along the tangent [m/s].
        force_gain: Radial admittance [m/(N s)]. force_target: Outward pull [N].
        kz: Height gain [1/s]. kw: Orientation gain [1/s].
        Jv_V_WL7q: Geometric Jacobian of L7 at Q in W (6, 7).
        joint_speed_limit: Symmetric clip on each joint speed [rad/s].
    """
    t = np.zeros(3)
    r = np.zeros(3)
    t[:2] = np.asarray(tangent_W, dtype=float)[:2]
    r[:2] = np.asarray(radial_W, dtype=float)[:2]
    F = np.asarray(F_Q_W, dtype=float)[3:]
    V = np.empty(6)
    V[:3] = kw * np.asarray(theta_n_W, dtype=float)
    V[3:] = speed * t + force_gain * (F @ r + force_target) * r
    V[5] += kz * height_error
    qdot = pseudo_inverse_solve(Jv_V_WL7q, V)
    return AdaptiveCommand(np.minimum(np.maximum(qdot, -joint_speed_limit), joint_speed_limit), V)
