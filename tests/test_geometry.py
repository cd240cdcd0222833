"""Door geometry read from the cupboard model agrees with the problem set's constants."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydrake.math import RollPitchYaw
from pydrake.multibody.plant import MultibodyPlant

from doorlab.cell.frames import CUPBOARD_MODEL, LEFT_HANDLE_FRAME, LEFT_HINGE
from doorlab.cell.geometry import L7_PITCH, default_door_geometry
from doorlab.cell.station import add_cell

# Station facts §3-4. The facts give 4-7 significant digits, hence the tolerances.
P_W_HINGE = np.array([0.7557, 0.2840, 0.4148])
P_W_HANDLE = np.array([0.7147, 0.0200, 0.4148])
R_HANDLE = 0.2671647
THETA0 = 0.1540722
SWEEP = 0.7185924


@pytest.fixture(scope="module")
def geometry():
    return default_door_geometry()


def test_model_hinge_and_handle_match_the_station_facts(geometry):
    """Hinge axis and handle centre from the model's frames equal §3's world points (0.1 mm)."""
    np.testing.assert_allclose(geometry.p_W_hinge, P_W_HINGE, atol=1e-4)
    np.testing.assert_allclose(geometry.p_W_handle, P_W_HANDLE, atol=1e-4)


def test_derived_constants_match_the_problem_set(geometry):
    """r_handle, theta0 and the swept angle equal §4's constants to their printed digits."""
    assert geometry.r_handle == pytest.approx(R_HANDLE, abs=1e-6)
    assert geometry.theta0 == pytest.approx(THETA0, abs=1e-6)
    assert geometry.sweep == pytest.approx(SWEEP, abs=1e-6)
    assert math.degrees(geometry.sweep) == pytest.approx(41.17, abs=0.01)


def test_arc_starts_at_the_handle_and_stays_on_the_circle(geometry):
    """p_WQ_ref(0) is the handle; every arc point is r_handle from the hinge (zero radial error)."""
    np.testing.assert_allclose(geometry.p_WQ_ref(0.0), geometry.p_W_handle, atol=1e-12)
    points = geometry.arc_points(50)
    np.testing.assert_allclose(geometry.radial_error(points), 0.0, atol=1e-12)
    assert np.all(points[:, 2] == geometry.p_W_handle[2])


def test_arc_end_is_the_handle_of_the_door_opened_by_the_sweep(geometry):
    """Opening the left door by -sweep [rad] moves the handle to the arc's end point."""
    np.testing.assert_allclose(
        geometry.handle_position(-geometry.sweep), geometry.p_WQ_ref(1.0), atol=1e-12
    )


@pytest.mark.parametrize("angle", [-0.001, -0.3, -0.7186, -1.2])
def test_handle_position_matches_the_model_at_any_hinge_angle(geometry, angle):
    """handle_position(angle) equals the model's left_handle frame with the hinge at angle."""
    plant = MultibodyPlant(0.0)
    add_cell(plant)
    plant.Finalize()
    context = plant.CreateDefaultContext()
    cupboard = plant.GetModelInstanceByName(CUPBOARD_MODEL)
    plant.GetJointByName(LEFT_HINGE, cupboard).set_angle(context, angle)
    p = plant.GetFrameByName(LEFT_HANDLE_FRAME, cupboard).CalcPoseInWorld(context).translation()
    np.testing.assert_allclose(geometry.handle_position(angle), p, atol=1e-9)


def test_reference_orientation_yaws_with_the_door(geometry):
    """R_WL7_ref(0) = RPY(0, 3pi/4, 0); R_WL7_ref(1) is yawed by -sweep about W's z axis."""
    R0 = geometry.R_WL7_ref(0.0)
    expected = RollPitchYaw(0, L7_PITCH, 0).ToRotationMatrix().matrix()
    np.testing.assert_allclose(R0.matrix(), expected, atol=1e-12)
    R1 = geometry.R_WL7_ref(1.0)
    relative = (R1 @ R0.inverse()).ToAngleAxis()
    assert relative.angle() == pytest.approx(geometry.sweep, abs=1e-12)
    np.testing.assert_allclose(relative.axis(), [0, 0, -1], atol=1e-12)


def test_tau_is_clamped_outside_the_arc(geometry):
    """Before and after the arc the references hold their end values."""
    np.testing.assert_array_equal(geometry.p_WQ_ref(-0.5), geometry.p_WQ_ref(0.0))
    np.testing.assert_array_equal(geometry.p_WQ_ref(1.5), geometry.p_WQ_ref(1.0))


def test_radial_error_sign(geometry):
    """A point 1 mm outside the arc (farther from the hinge) has radial error +1 mm."""
    p = geometry.p_W_handle + 0.001 * (geometry.p_W_handle - geometry.p_W_hinge) / geometry.r_handle
    assert geometry.radial_error(p) == pytest.approx(0.001, abs=1e-12)


def test_moving_the_cupboard_moves_the_geometry_read_from_the_model():
    """station.cupboard_position shifts hinge and handle by the same vector (rotation fixed)."""
    shift = np.array([0.1, 0.1, 0.0])
    moved = default_door_geometry(p_WC=np.array([0.9057, 0.0, 0.4148]) + shift)
    np.testing.assert_allclose(moved.p_W_hinge, P_W_HINGE + shift, atol=1e-4)
    np.testing.assert_allclose(moved.p_W_handle, P_W_HANDLE + shift, atol=1e-4)
    assert moved.r_handle == pytest.approx(R_HANDLE, abs=1e-6)


@pytest.mark.parametrize("yaw_deg", [-15.0, -10.0, 5.0, 10.0])
def test_cupboard_yaw_error_turns_the_hinge_about_the_handle(geometry, yaw_deg):
    """The true door keeps the handle, moves the hinge by 2 r sin(yaw/2) (4.7 cm at 10 deg),
    shifts the closed-door angle by -yaw, sweeps the same angle and turns L7's reference by yaw."""
    yaw = math.radians(yaw_deg)
    true = default_door_geometry(yaw_error=yaw)
    np.testing.assert_allclose(true.p_W_handle, geometry.p_W_handle, atol=1e-9)
    moved = np.linalg.norm(true.p_W_hinge - geometry.p_W_hinge)
    assert moved == pytest.approx(2 * R_HANDLE * abs(math.sin(yaw / 2)), abs=1e-6)
    assert true.r_handle == pytest.approx(geometry.r_handle, abs=1e-9)
    assert true.theta0 == pytest.approx(geometry.theta0 - yaw, abs=1e-9)
    assert true.sweep == pytest.approx(geometry.sweep, abs=1e-12)
    turn = (true.R_WL7_ref(0.3) @ geometry.R_WL7_ref(0.3).inverse()).ToAngleAxis()
    assert turn.angle() == pytest.approx(abs(yaw), abs=1e-9)
    np.testing.assert_allclose(turn.axis() * math.copysign(1, yaw), [0, 0, 1], atol=1e-9)


def test_true_geometry_matches_the_turned_model_at_any_hinge_angle():
    """With a yaw error, handle_position(angle) of the true geometry equals the simulated
    model's left_handle frame (the plant built with the same yaw error) at that hinge angle."""
    yaw = math.radians(10.0)
    true = default_door_geometry(yaw_error=yaw)
    plant = MultibodyPlant(0.0)
    add_cell(plant, yaw_error=yaw)
    plant.Finalize()
    context = plant.CreateDefaultContext()
    cupboard = plant.GetModelInstanceByName(CUPBOARD_MODEL)
    for angle in (-0.001, -0.4, -0.72):
        plant.GetJointByName(LEFT_HINGE, cupboard).set_angle(context, angle)
        frame = plant.GetFrameByName(LEFT_HANDLE_FRAME, cupboard)
        np.testing.assert_allclose(
            true.handle_position(angle), frame.CalcPoseInWorld(context).translation(), atol=1e-9
        )


def test_a_position_error_moves_the_true_door_and_the_simulated_model():
    """station.cupboard_position_error: the true geometry's handle and hinge move by the error
    (with a yaw error too: the turn is about the moved handle), the plans' belief does not,
    and the simulated model's handle is the true geometry's at any hinge angle."""
    from doorlab.cell.geometry import scenario_door_geometry, true_door_geometry
    from doorlab.cell.station import build_station
    from doorlab.config import Scenario

    scenario = Scenario()
    scenario.station.cupboard_position_error = [0.004, -0.003, 0.002]
    scenario.station.cupboard_yaw_error = math.radians(3.0)
    believed, true = scenario_door_geometry(scenario), true_door_geometry(scenario)
    shift = np.array(scenario.station.cupboard_position_error)
    np.testing.assert_allclose(true.p_W_handle, believed.p_W_handle + shift, atol=1e-9)
    turned_only = default_door_geometry(yaw_error=math.radians(3.0))
    np.testing.assert_allclose(true.p_W_hinge, turned_only.p_W_hinge + shift, atol=1e-9)
    station = build_station(scenario.station)
    plant = station.plant
    context = plant.CreateDefaultContext()
    cupboard = plant.GetModelInstanceByName(CUPBOARD_MODEL)
    for angle in (-0.001, -0.5):
        plant.GetJointByName(LEFT_HINGE, cupboard).set_angle(context, angle)
        frame = plant.GetFrameByName(LEFT_HANDLE_FRAME, cupboard)
        np.testing.assert_allclose(
            true.handle_position(angle), frame.CalcPoseInWorld(context).translation(), atol=1e-9
        )
