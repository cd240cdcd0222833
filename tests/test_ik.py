"""Inverse kinematics: one-shot and pointwise along the handle arc."""

from __future__ import annotations

import numpy as np
import pytest

from doorlab.cell.frames import L7_FRAME, p_L7Q
from doorlab.cell.geometry import default_door_geometry
from doorlab.cell.station import make_controller_plant
from doorlab.constants import JOINT_POSITION_LIMITS, Q_HOME
from doorlab.control.ik import solve_ik
from doorlab.control.ik_pointwise import pointwise_ik
from doorlab.errors import IkError

POSITION_TOLERANCE = 0.001  # [m] the problem set's box half-width
THETA_BOUND = 0.005 * np.pi  # [rad] the problem set's orientation bound


@pytest.fixture(scope="module")
def plant():
    return make_controller_plant()


@pytest.fixture(scope="module")
def geometry():
    return default_door_geometry()


def pose(plant, q):
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, q)
    return plant.GetFrameByName(L7_FRAME).CalcPoseInWorld(context)


@pytest.mark.parametrize("seed", range(4))
def test_fk_of_ik_reaches_a_reachable_pose(plant, seed):
    """FK(IK(X)) = X for poses made by FK of random configurations near q_home (seeded),
    solved from a guess 0.2 rad away on every joint (a local solver needs a nearby guess)."""
    rng = np.random.default_rng(seed)
    limits = 0.95 * JOINT_POSITION_LIMITS
    q_true = np.clip(Q_HOME + rng.uniform(-0.4, 0.4, 7), -limits, limits)
    q_guess = q_true + rng.choice([-0.2, 0.2], 7)
    X = pose(plant, q_true)
    q = solve_ik(plant, X @ p_L7Q, X.rotation(), q_guess, position_tolerance=1e-4, theta_bound=1e-3)
    X_ik = pose(plant, q)
    # Box of +-0.1 mm per axis: at most sqrt(3) x 0.1 mm away.
    assert np.linalg.norm(X_ik @ p_L7Q - X @ p_L7Q) <= np.sqrt(3) * 1e-4 + 1e-9
    assert (X_ik.rotation().inverse() @ X.rotation()).ToAngleAxis().angle() <= 1e-3 + 1e-9
    assert np.all(np.abs(q) <= JOINT_POSITION_LIMITS + 1e-9)


def test_centered_ik_puts_q_on_the_handle(plant, geometry):
    """The one-shot grasp IK (centered) lands Q on the handle within 0.01 mm."""
    q = solve_ik(
        plant,
        geometry.p_WQ_ref(0.0),
        geometry.R_WL7_ref(0.0),
        Q_HOME,
        position_tolerance=0.0005,
        theta_bound=THETA_BOUND,
    )
    assert np.linalg.norm(pose(plant, q) @ p_L7Q - geometry.p_W_handle) < 1e-5


@pytest.mark.parametrize("centered", [False, True])
def test_pointwise_ik_knots_respect_the_tolerances(plant, geometry, centered):
    """Every knot is within the problem set's tolerances, and knots form one smooth branch."""
    result = pointwise_ik(
        plant,
        geometry.p_WQ_ref,
        geometry.R_WL7_ref,
        duration=10.0,
        num_knots=10,
        q_guess=Q_HOME,
        position_tolerance=POSITION_TOLERANCE,
        theta_bound=THETA_BOUND,
        centered=centered,
    )
    assert result.q_knots.shape == (10, 7)
    np.testing.assert_allclose(result.times, np.linspace(0, 10, 10))
    # SNOPT's feasibility tolerance (1e-6) lets a knot sit a hair outside the box corner.
    assert np.all(result.position_residuals <= np.sqrt(3) * POSITION_TOLERANCE + 1e-6)
    assert np.all(result.orientation_residuals <= THETA_BOUND + 1e-6)
    # The arc turns L7 by 0.72 rad over 9 intervals; a branch switch would jump ~1 rad.
    assert np.max(np.abs(np.diff(result.q_knots, axis=0))) < 0.3
    if centered:
        assert np.max(result.position_residuals) < 1e-5


def test_unreachable_target_raises_a_domain_error_naming_the_knot(plant, geometry):
    """A hinge moved 2 m away: IK fails with IkError naming knot 0 and the residual."""
    far = lambda tau: geometry.p_WQ_ref(tau) + np.array([2.0, 0.0, 0.0])  # noqa: E731
    with pytest.raises(IkError, match="knot 0") as info:
        pointwise_ik(
            plant,
            far,
            geometry.R_WL7_ref,
            duration=10.0,
            num_knots=3,
            q_guess=Q_HOME,
            position_tolerance=POSITION_TOLERANCE,
            theta_bound=THETA_BOUND,
        )
    assert info.value.knot == 0
    assert info.value.residual > 0.5


def test_pointwise_ik_needs_two_knots(plant, geometry):
    """One knot cannot define a path."""
    with pytest.raises(IkError, match="at least 2 knots"):
        pointwise_ik(
            plant,
            geometry.p_WQ_ref,
            geometry.R_WL7_ref,
            duration=10.0,
            num_knots=1,
            q_guess=Q_HOME,
            position_tolerance=POSITION_TOLERANCE,
            theta_bound=THETA_BOUND,
        )


@pytest.mark.parametrize(
    "offset", [(0.0, 0.0, 0.0), (0.0005, -0.0005, 0.0005), (-0.002, 0.0, 0.003)]
)
def test_the_grasp_aims_q_at_the_handle_plus_ik_grasp_offset(plant, geometry, offset):
    """The one-shot IK of tasks 2-4 puts Q within the grasp tolerance box around the handle
    plus ``ik.grasp_offset`` (in W) and L7 within theta_bound of the arc's start orientation:
    the offset moves the grasp by itself, nothing else does."""
    from doorlab.config import Scenario
    from doorlab.episode.controllers import build_velocity_plan

    scenario = Scenario(controller="velocity")
    scenario.ik.grasp_offset = list(offset)
    q = build_velocity_plan(scenario, geometry, plant).q_start
    X_WL7 = pose(plant, q)
    p_WQ = X_WL7.multiply(p_L7Q).ravel()
    tolerance = scenario.ik.grasp_position_tolerance
    error = p_WQ - (geometry.p_W_handle + np.asarray(offset))
    assert np.all(np.abs(error) <= tolerance + 1e-9), error
    angle = (geometry.R_WL7_ref(0.0).inverse() @ X_WL7.rotation()).ToAngleAxis().angle()
    assert angle <= scenario.ik.theta_bound + 1e-9
