"""The diffik and osc controllers' laws, without a simulator: operational-space control on closed
forms (a one-link and a two-link arm, whose task-space inertia is known analytically) and on the
iiwa's model, and Drake's differential-IK QP against the pseudo-inverse and under its limits."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydrake.multibody.tree import JacobianWrtVariable

from doorlab.cell.frames import L7_FRAME, p_L7Q
from doorlab.cell.geometry import default_door_geometry
from doorlab.cell.station import make_controller_plant
from doorlab.config import DiffIkPlanConfig, OscPlanConfig
from doorlab.constants import JOINT_POSITION_LIMITS, NUM_JOINTS, Q_GRASP
from doorlab.control.diffik import DiffIkPlan, diffik_law, diffik_parameters
from doorlab.control.laws import PoseError, pseudo_inverse_solve, velocity_law
from doorlab.control.osc import osc_gains, osc_law, task_space_inertia
from doorlab.control.plans import ArmState

RNG = np.random.default_rng(46)


# -- closed forms ---------------------------------------------------------------------------


def two_link(q: np.ndarray, m1=1.3, m2=0.7, l1=0.5, l2=0.4) -> tuple[np.ndarray, np.ndarray]:
    """Mass matrix and end-point Jacobian (x, y) of a planar two-link arm with point masses at
    the links' ends (the textbook closed form)."""
    c2 = math.cos(q[1])
    s1, c1 = math.sin(q[0]), math.cos(q[0])
    s12, c12 = math.sin(q[0] + q[1]), math.cos(q[0] + q[1])
    M = np.array(
        [
            [
                (m1 + m2) * l1**2 + m2 * l2**2 + 2 * m2 * l1 * l2 * c2,
                m2 * l2**2 + m2 * l1 * l2 * c2,
            ],
            [m2 * l2**2 + m2 * l1 * l2 * c2, m2 * l2**2],
        ]
    )
    J = np.array([[-l1 * s1 - l2 * s12, -l2 * s12], [l1 * c1 + l2 * c12, l2 * c12]])
    return M, J


def test_one_link_task_inertia_is_the_point_mass():
    """A point mass m on a massless link of length l: M = m l^2, J = l along the tangent, so
    Lambda = (l (m l^2)^-1 l)^-1 = m, whatever l."""
    for m, l in ((2.0, 0.3), (0.5, 1.7)):
        Lambda = task_space_inertia(np.array([[l]]), np.array([[m * l**2]]))
        assert Lambda == pytest.approx(np.array([[m]]), rel=1e-12)


@pytest.mark.parametrize("q", [(0.3, 1.1), (-1.0, 2.0), (2.5, -0.7)])
def test_two_link_task_inertia_matches_its_closed_form(q):
    """Square, invertible J: Lambda = J^-T M J^-1 (to rounding)."""
    M, J = two_link(np.array(q))
    expected = np.linalg.inv(J).T @ M @ np.linalg.inv(J)
    assert task_space_inertia(J, M) == pytest.approx(expected, rel=1e-10, abs=1e-12)


def test_two_link_commanded_acceleration_is_met_in_every_direction():
    """tau = J^T Lambda a makes the end point accelerate by exactly a (q_dot = 0: no bias), the
    decoupling the task-space inertia buys; J^T a alone (the impedance plan's law) does not."""
    M, J = two_link(np.array([0.4, 1.3]))
    for a in (np.array([1.0, 0.0]), np.array([0.0, 1.0]), np.array([-0.3, 0.8])):
        tau = osc_law(a, np.zeros(2), J, M, kp=1.0, kd=0.0, torque_limit=1e9).tau_ff
        assert J @ np.linalg.solve(M, tau) == pytest.approx(a, abs=1e-12)
        plain = J.T @ a
        x_ddot = J @ np.linalg.solve(M, plain)
        sine = (x_ddot[0] * a[1] - x_ddot[1] * a[0]) / np.linalg.norm(a)
        assert abs(sine) > 0.05 * np.linalg.norm(x_ddot)  # turned off a


def test_zero_error_and_rate_give_zero_torque():
    """No error, no error rate, no model terms: tau_ff = 0 exactly (two-link and iiwa)."""
    M, J = two_link(np.array([0.4, 1.3]))
    out = osc_law(np.zeros(2), np.zeros(2), J, M, kp=100.0, kd=20.0, torque_limit=20.0)
    assert np.all(out.tau_ff == 0.0)
    plant = make_controller_plant()
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, Q_GRASP)
    M7 = plant.CalcMassMatrix(context)
    J7 = _jacobian(plant, context)
    kp, kd = osc_gains(OscPlanConfig())
    out = osc_law(np.zeros(6), np.zeros(6), J7, M7, kp=kp, kd=kd, torque_limit=20.0)
    assert np.all(out.tau_ff == 0.0)


def _jacobian(plant, context) -> np.ndarray:
    L7, W = plant.GetFrameByName(L7_FRAME), plant.world_frame()
    return plant.CalcJacobianSpatialVelocity(context, JacobianWrtVariable.kV, L7, p_L7Q, W, W)


@pytest.fixture(scope="module")
def iiwa():
    plant = make_controller_plant()
    return plant, plant.CreateDefaultContext()


def test_iiwa_error_dynamics_are_the_commanded_ones(iiwa):
    """On the iiwa's model at a moving state: with tau_ff from the law, the arm's dynamics under
    the inner loop (M q_ddot = tau_ff - D v - C v: gravity cancelled, q_ref = q) give the task
    acceleration x_ddot = J q_ddot + J_dot v = a_ref + Kp e + Kd e_dot exactly, rotation and
    translation alike: the model terms and the damping are compensated in the task's
    directions (relative 1e-9: a 7x7 solve)."""
    plant, context = iiwa
    q = Q_GRASP + RNG.normal(0, 0.1, NUM_JOINTS)
    v = RNG.normal(0, 0.3, NUM_JOINTS)
    plant.SetPositions(context, q)
    plant.SetVelocities(context, v)
    M = plant.CalcMassMatrix(context)
    J = _jacobian(plant, context)
    Cv = plant.CalcBiasTerm(context)
    L7, W = plant.GetFrameByName(L7_FRAME), plant.world_frame()
    Jdot_v = plant.CalcBiasSpatialAcceleration(
        context, JacobianWrtVariable.kV, L7, p_L7Q, W, W
    ).get_coeffs()
    D = np.array([13.3, 27.7, 16.7, 10.9, 5.7, 5.8, 5.6])
    kp, kd = osc_gains(OscPlanConfig(wn_translation=12.0, wn_rotation=7.0, zeta=0.8))
    e, e_dot, a_ref = RNG.normal(0, 0.01, 6), RNG.normal(0, 0.05, 6), RNG.normal(0, 0.02, 6)
    out = osc_law(
        e, e_dot, J, M, kp=kp, kd=kd, torque_limit=1e9, a_ref=a_ref, Jdot_v=Jdot_v, Cv=Cv,
        damping_torque=D * v,
    )  # fmt: skip
    q_ddot = np.linalg.solve(M, out.tau_ff - D * v - Cv)
    expected = a_ref + kp * e + kd * e_dot
    assert J @ q_ddot + Jdot_v == pytest.approx(expected, rel=1e-9, abs=1e-9)
    assert out.Lambda == pytest.approx(out.Lambda.T, abs=1e-9)
    assert np.all(np.linalg.eigvalsh(out.Lambda) > 0)


def test_osc_torques_are_clipped():
    M, J = two_link(np.array([0.4, 1.3]))
    out = osc_law(np.array([10.0, -10.0]), np.zeros(2), J, M, kp=1e4, kd=0.0, torque_limit=3.0)
    assert np.max(np.abs(out.tau_ff)) == pytest.approx(3.0)


def test_gains_are_the_natural_frequencies():
    kp, kd = osc_gains(OscPlanConfig(wn_translation=10.0, wn_rotation=5.0, zeta=0.5))
    assert kp.tolist() == [25.0] * 3 + [100.0] * 3
    assert kd.tolist() == [5.0] * 3 + [10.0] * 3


def test_reference_velocity_is_the_arcs_derivative():
    """V_WQ_ref and A_WQ_ref are the time derivatives of p_WQ_ref and of L7's yaw along the arc
    (central differences, step 1e-4 s: error O(h^2) ~ 1e-11 m/s)."""
    geometry = default_door_geometry()
    duration, h = 10.0, 1e-4
    for tau in (0.1, 0.5, 0.9):
        t = tau * duration
        p = [geometry.p_WQ_ref((t + s) / duration) for s in (-h, 0.0, h)]
        V = geometry.V_WQ_ref(tau, duration)
        assert V[3:] == pytest.approx((p[2] - p[0]) / (2 * h), abs=1e-9)
        A = geometry.A_WQ_ref(tau, duration)
        assert A[3:] == pytest.approx((p[2] - 2 * p[1] + p[0]) / h**2, abs=1e-6)
        R = [geometry.R_WL7_ref((t + s) / duration) for s in (-h, h)]
        w = (R[1] @ R[0].inverse()).ToAngleAxis()
        assert V[:3] == pytest.approx(w.angle() * w.axis() / (2 * h), abs=1e-9)
    assert np.all(geometry.V_WQ_ref(1.2, duration) == 0.0)


# -- differential IK ------------------------------------------------------------------------


def _params(limit=1.0, lower=None, upper=None):
    inside = JOINT_POSITION_LIMITS - 0.0873
    return diffik_parameters(
        0.005,
        joint_speed_limit=limit,
        position_lower=-inside if lower is None else lower,
        position_upper=inside if upper is None else upper,
    )


def _error(V: np.ndarray, kv: float, kw: float) -> PoseError:
    """The pose error whose desired spatial vector (kw theta n; kv e) is V."""
    return PoseError(theta_n_W=V[:3] / kw, e_xyz_W=V[3:] / kv)


def test_diffik_without_active_limits_is_the_pseudo_inverse(iiwa):
    """A small V_des far from every limit: the QP's v is J^+ V_des (its null-space cost picks
    the least null-space motion). Tolerance 1e-5 of |v|: the QP solver's convergence."""
    plant, context = iiwa
    plant.SetPositions(context, Q_GRASP)
    J = _jacobian(plant, context)
    V = np.array([0.01, -0.02, 0.03, 0.02, 0.01, -0.01])
    out = diffik_law(_error(V, 100, 50), J, Q_GRASP, np.zeros(7), _params(), kv=100, kw=50)
    expected = pseudo_inverse_solve(J, V)
    assert out.solved and out.scale == pytest.approx(1.0, abs=1e-5)
    assert out.qdot == pytest.approx(expected, abs=1e-5 * np.linalg.norm(expected))


def test_zero_error_gives_zero_velocity(iiwa):
    plant, context = iiwa
    plant.SetPositions(context, Q_GRASP)
    J = _jacobian(plant, context)
    out = diffik_law(_error(np.zeros(6), 100, 50), J, Q_GRASP, np.zeros(7), _params(), kv=1, kw=1)
    assert out.solved and np.max(np.abs(out.qdot)) < 1e-9


def test_a_velocity_limit_scales_the_motion_keeping_its_direction(iiwa):
    """V_des too fast for 0.3 rad/s: the QP keeps every |v_i| within the limit and J v along
    V_des (scaled down), while the velocity plan's per-joint clip turns J v off it."""
    plant, context = iiwa
    plant.SetPositions(context, Q_GRASP)
    J = _jacobian(plant, context)
    V = np.array([0.3, -0.2, 0.5, 0.2, -0.15, 0.1])
    out = diffik_law(_error(V, 100, 50), J, Q_GRASP, np.zeros(7), _params(0.3), kv=100, kw=50)
    assert out.solved and 0.05 < out.scale < 0.99
    assert np.max(np.abs(out.qdot)) <= 0.3 + 1e-6
    achieved = J @ out.qdot
    cosine = achieved @ V / (np.linalg.norm(achieved) * np.linalg.norm(V))
    assert cosine == pytest.approx(1.0, abs=1e-6)
    clipped = J @ velocity_law(_error(V, 100, 50), J, kv=100, kw=50, joint_speed_limit=0.3)
    cosine_clip = clipped @ V / (np.linalg.norm(clipped) * np.linalg.norm(V))
    assert cosine_clip < 0.999


def test_a_position_limit_is_kept_one_step_ahead(iiwa):
    """Joint 4 a hair below its upper limit, V_des pulling it up: q + v dt stays within the
    limit (the clip knows no position limit and would cross it)."""
    plant, context = iiwa
    plant.SetPositions(context, Q_GRASP)
    J = _jacobian(plant, context)
    V = 0.2 * J[:, 3]  # the task velocity joint 4 alone makes: J^+ V moves it up
    upper = Q_GRASP + 0.3
    upper[3] = Q_GRASP[3] + 1e-4
    params = _params(1.0, lower=Q_GRASP - 0.3, upper=upper)
    out = diffik_law(_error(V, 100, 50), J, Q_GRASP, np.zeros(7), params, kv=100, kw=50)
    assert out.solved
    assert Q_GRASP[3] + out.qdot[3] * 0.005 <= upper[3] + 1e-9
    assert pseudo_inverse_solve(J, V)[3] * 0.005 > 1e-4  # unconstrained, it would cross


def test_diffik_plan_integrates_its_own_state():
    """q_ref = q_ref + v dt from the first tick's measured q on: the next command does not
    depend on the measured q (it tracks its own integrated state, as Drake's
    DifferentialInverseKinematicsIntegrator)."""
    geometry = default_door_geometry()
    plant = make_controller_plant()
    dt = 0.005
    commands = []
    for offset in (0.0, 0.05):
        plan = DiffIkPlan(geometry, 10.0, plant, DiffIkPlanConfig(), dt)
        zero = np.zeros(7)
        first = plan.command(0.0, ArmState(Q_GRASP, zero, zero))
        second = plan.command(dt, ArmState(Q_GRASP + offset, zero, zero))
        commands.append((first.q_ref, second.q_ref))
        log = plan.log_table()
        assert log["t"].tolist() == [0.0, dt] and log["solved"].tolist() == [1.0, 1.0]
    assert np.array_equal(commands[0][1], commands[1][1])
    assert np.linalg.norm(commands[0][1] - commands[0][0]) > 0  # it moves
