"""The control laws' cores, without a simulator."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.math import RollPitchYaw, RotationMatrix
from pydrake.multibody.tree import JacobianWrtVariable

from doorlab.cell.frames import L7_FRAME, p_L7Q
from doorlab.cell.station import make_controller_plant
from doorlab.constants import Q_HOME
from doorlab.control.laws import (
    PoseError,
    desired_spatial_vector,
    impedance_law,
    orientation_error,
    pose_error,
    pseudo_inverse_solve,
    velocity_law,
)

RNG = np.random.default_rng(7)
Q_GRASP = np.array([0.05, 0.30, -0.02, -1.52, -0.04, 0.54, 0.07])  # near the handle


@pytest.fixture(scope="module")
def arm():
    plant = make_controller_plant()
    return plant, plant.CreateDefaultContext()


def jacobian(arm, q):
    plant, context = arm
    plant.SetPositions(context, q)
    L7, W = plant.GetFrameByName(L7_FRAME), plant.world_frame()
    return plant.CalcJacobianSpatialVelocity(context, JacobianWrtVariable.kV, L7, p_L7Q, W, W)


def fk(arm, q):
    plant, context = arm
    plant.SetPositions(context, q)
    return plant.GetFrameByName(L7_FRAME).CalcPoseInWorld(context)


def test_zero_error_gives_zero_commands(arm):
    """Zero pose error: zero joint velocity (task 2) and zero feedforward torque (task 3)."""
    X = fk(arm, Q_GRASP)
    error = pose_error(X @ p_L7Q, X.rotation(), X @ p_L7Q, X.rotation())
    J = jacobian(arm, Q_GRASP)
    assert np.all(velocity_law(error, J, kv=100, kw=50, joint_speed_limit=1.0) == 0.0)
    assert np.all(impedance_law(error, J, kv=100, kw=50, torque_limit=20.0) == 0.0)


@pytest.mark.parametrize("q", [Q_HOME, Q_GRASP, RNG.uniform(-1.5, 1.5, 7)])
def test_jacobian_matches_finite_differences_of_forward_kinematics(arm, q):
    """Jv_V_WL7q's rows match central differences of p_WQ (translational) and of R_WL7
    (angular, via the skew part of dR R^T): step 1e-6 rad, error O(h^2) ~ 1e-12, so 1e-7."""
    J = jacobian(arm, q)
    h = 1e-6
    for j in range(7):
        dq = np.zeros(7)
        dq[j] = h
        Xp, Xm = fk(arm, q + dq), fk(arm, q - dq)
        v = (Xp @ p_L7Q - Xm @ p_L7Q) / (2 * h)
        dR = (Xp.rotation().matrix() - Xm.rotation().matrix()) / (2 * h)
        W = dR @ fk(arm, q).rotation().matrix().T
        w = np.array([W[2, 1], W[0, 2], W[1, 0]])
        np.testing.assert_allclose(J[3:, j], v, atol=1e-7)
        np.testing.assert_allclose(J[:3, j], w, atol=1e-7)


def test_pseudo_inverse_maps_desired_spatial_velocity_exactly(arm):
    """J q_dot = V_des for the velocity law (J has full row rank at the grasp pose)."""
    J = jacobian(arm, Q_GRASP)
    error = PoseError(np.array([0.001, -0.002, 0.003]), np.array([0.0005, 0.0002, -0.0004]))
    qdot = velocity_law(error, J, kv=100, kw=50, joint_speed_limit=10.0)
    np.testing.assert_allclose(J @ qdot, desired_spatial_vector(error, 100, 50), atol=1e-12)
    np.testing.assert_allclose(qdot, np.linalg.pinv(J) @ (J @ qdot), atol=1e-12)


def test_pseudo_inverse_is_minimum_norm_near_a_singularity():
    """With two equal rows (rank 5) the solve falls back to the SVD pseudo-inverse."""
    J = RNG.normal(size=(6, 7))
    J[5] = J[4]
    V = RNG.normal(size=6)
    np.testing.assert_allclose(pseudo_inverse_solve(J, V), np.linalg.pinv(J) @ V, atol=1e-12)


def test_transpose_maps_spatial_force_to_joint_torque_by_virtual_work(arm):
    """tau = J^T F: the joint power tau . q_dot equals the spatial power F . (J q_dot)."""
    J = jacobian(arm, Q_GRASP)
    error = PoseError(np.array([0.01, 0.0, -0.02]), np.array([0.003, -0.001, 0.002]))
    tau = impedance_law(error, J, kv=100, kw=50, torque_limit=1e9)
    F = desired_spatial_vector(error, 100, 50)
    np.testing.assert_allclose(tau, J.T @ F, atol=1e-12)
    qdot = RNG.normal(size=7)
    assert tau @ qdot == pytest.approx(F @ (J @ qdot), rel=1e-12)


def test_commands_are_clipped_at_their_limits(arm):
    """Large errors saturate q_dot at the speed limit and tau_ff at the torque limit."""
    J = jacobian(arm, Q_GRASP)
    error = PoseError(np.array([0.5, 0.5, 0.5]), np.array([0.5, -0.5, 0.5]))
    assert np.max(np.abs(velocity_law(error, J, kv=100, kw=50, joint_speed_limit=1.0))) == 1.0
    assert np.max(np.abs(impedance_law(error, J, kv=1e4, kw=1e4, torque_limit=20.0))) == 20.0


def test_gains_scale_the_command_linearly(arm):
    """Doubling both gains doubles the unclipped commands (the laws are linear in the error)."""
    J = jacobian(arm, Q_GRASP)
    error = PoseError(np.array([0.001, 0.002, 0.0]), np.array([0.001, 0.0, -0.001]))
    q1 = velocity_law(error, J, kv=50, kw=25, joint_speed_limit=1e9)
    q2 = velocity_law(error, J, kv=100, kw=50, joint_speed_limit=1e9)
    np.testing.assert_allclose(q2, 2 * q1, rtol=1e-12)


@pytest.mark.parametrize("angle", [0.1, 1.0, 2.5, np.pi - 1e-3])
def test_orientation_error_is_the_rotation_to_the_reference(angle):
    """Rotating L7 by theta n (in W) about its origin lands exactly on the reference."""
    axis = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    R_WL7 = RollPitchYaw(0.3, 2.3, -0.4).ToRotationMatrix()
    from pydrake.common.eigen_geometry import AngleAxis

    R_ref = RotationMatrix(AngleAxis(angle, axis)) @ R_WL7
    theta_n = orientation_error(R_WL7, R_ref)
    assert np.linalg.norm(theta_n) == pytest.approx(angle, abs=1e-9)
    np.testing.assert_allclose(theta_n / angle, axis, atol=1e-9)


def test_orientation_error_does_not_flip_across_the_quaternion_hemisphere():
    """A reference yawing through 0 while L7 sits near RPY(0, 3pi/4, 0) (whose quaternion
    has a small w, so q and -q swap hemispheres easily) gives an error that varies
    continuously in the yaw: no sign flip between neighbouring samples."""
    R_WL7 = RollPitchYaw(0.0, 3 * np.pi / 4, 0.0).ToRotationMatrix()
    yaws = np.linspace(-0.8, 0.8, 401)
    references = [RollPitchYaw(0, 3 * np.pi / 4, y).ToRotationMatrix() for y in yaws]
    errors = np.array([orientation_error(R_WL7, R) for R in references])
    steps = np.linalg.norm(np.diff(errors, axis=0), axis=1)
    assert steps.max() < 2 * (yaws[1] - yaws[0])
    np.testing.assert_allclose(np.linalg.norm(errors, axis=1), np.abs(yaws), atol=1e-9)
    # The error of a pure yaw is about W's z axis, with the yaw's sign.
    np.testing.assert_allclose(errors[:, 2], yaws, atol=1e-9)


def adaptive_command(J, **overrides):
    """adaptive_law with neutral inputs (no force, no orientation or height error)."""
    from doorlab.control.laws import adaptive_law

    inputs = dict(
        theta_n_W=np.zeros(3),
        F_Q_W=np.zeros(6),
        tangent_W=np.array([-1.0, 0.0, 0.0]),
        radial_W=np.array([0.0, -1.0, 0.0]),
        height_error=0.0,
        speed=0.02,
        force_gain=0.01,
        force_target=0.0,
        kz=10.0,
        kw=5.0,
        Jv_V_WL7q=J,
        joint_speed_limit=1.0,
    )
    inputs.update(overrides)
    return adaptive_law(**inputs)


def test_adaptive_law_moves_q_along_the_tangent_without_force(arm):
    """No force and no errors: J q_dot is exactly speed * tangent (no rotation, no drift)."""
    J = jacobian(arm, Q_GRASP)
    command = adaptive_command(J)
    assert np.allclose(J @ command.qdot, [0, 0, 0, -0.02, 0, 0], atol=1e-12)


def test_adaptive_law_yields_to_radial_force(arm):
    """A radial contact force of 2 N adds force_gain * 2 N of velocity in the force's
    direction (an admittance), tangential and vertical forces add nothing, and flipping the
    radial estimate's sign changes nothing (its sign is unknown before the fit)."""
    J = jacobian(arm, Q_GRASP)
    F = np.array([0, 0, 0, 0.0, 2.0, 0.0])  # pushes Q along +y, i.e. along -radial
    F_other = np.array([0.1, 0, 0, 3.0, 2.0, -4.0])  # + tangential, vertical and torque
    for radial in ([0.0, -1.0, 0.0], [0.0, 1.0, 0.0]):
        for force in (F, F_other):
            V = J @ adaptive_command(J, F_Q_W=force, radial_W=np.array(radial)).qdot
            assert np.allclose(V, [0, 0, 0, -0.02, 0.01 * 2.0, 0], atol=1e-12)
    # force_target: the robot keeps pulling outward by that much when nothing pushes back.
    V = J @ adaptive_command(J, force_target=1.5).qdot
    assert np.allclose(V[3:], [-0.02, -0.01 * 1.5, 0], atol=1e-12)


def test_adaptive_law_corrects_height_and_orientation(arm):
    """Height and orientation errors map to kz e_z upwards and kw theta n."""
    J = jacobian(arm, Q_GRASP)
    theta = np.array([0.0, 0.0, 0.01])  # small: no joint reaches the speed clip
    V = J @ adaptive_command(J, speed=0.0, height_error=0.003, theta_n_W=theta).qdot
    assert np.allclose(V, [0, 0, 5.0 * 0.01, 0, 0, 10.0 * 0.003], atol=1e-10)


def test_adaptive_law_clips_joint_speeds(arm):
    J = jacobian(arm, Q_GRASP)
    command = adaptive_command(J, speed=50.0, joint_speed_limit=0.3)
    assert np.max(np.abs(command.qdot)) == pytest.approx(0.3)
    assert command.V_des[3] == pytest.approx(-50.0)
