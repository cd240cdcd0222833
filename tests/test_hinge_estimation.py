"""The hinge estimator and the contact-wrench estimate, without a simulator.

Noise levels: sigma = 0.2 mm per position sample is a few times the wobble of Q about the
true circle in a simulated opening (the handle's play between the pads); 200 Hz samples at
0.025 m/s are the adaptive plan's own rate and speed.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from doorlab.control.hinge_estimation import (
    HingeEstimator,
    center_error_std,
    estimate_contact_wrench,
    fit_circle,
    signed_angle,
)
from doorlab.errors import ConfigError

CENTER = np.array([0.7557, 0.2840])
RADIUS = 0.2672
SIGMA = 0.0002  # [m]


def arc(angles: np.ndarray) -> np.ndarray:
    """Points (n, 2) on the circle at the given angles [rad] (angle 0 along -y)."""
    return CENTER + RADIUS * np.column_stack([-np.sin(angles), -np.cos(angles)])


def center_error_components(center: np.ndarray, mid_angle: float) -> tuple[float, float]:
    """(tangential, radial) components of center - CENTER at the arc's middle."""
    radial = np.array([-math.sin(mid_angle), -math.cos(mid_angle)])
    tangential = np.array([radial[1], -radial[0]])
    error = center - CENTER
    return float(error @ tangential), float(error @ radial)


def test_fit_of_exact_points_is_exact():
    """Noise-free points on a 5 deg arc give the circle to rounding (1e-9 m)."""
    fit = fit_circle(arc(np.linspace(0.15, 0.15 + math.radians(5), 50)))
    assert np.allclose(fit.center, CENTER, atol=1e-9)
    assert fit.radius == pytest.approx(RADIUS, abs=1e-9)


def test_collinear_points_have_no_circle():
    with pytest.raises(ConfigError, match="collinear"):
        fit_circle(np.column_stack([np.linspace(0, 1, 10), np.zeros(10)]))


@pytest.mark.parametrize("arc_deg", [20.0, 41.2])
def test_fit_scatter_matches_the_derived_bound(arc_deg):
    """Over 300 noisy draws the center's scatter matches the first-order bound of
    center_error_std (within 20 %: the sample std of 300 draws is good to ~6 %, and the
    small-angle expansion to ~3 % at 41 deg), its mean is within 4 standard errors of the
    truth (no bias: a Kasa fit would be ~3 std off radially at 20 deg), and no draw is
    beyond 5 standard deviations."""
    rng = np.random.default_rng(11)
    n = 400
    phi = math.radians(arc_deg)
    angles = np.linspace(0.15, 0.15 + phi, n)
    std_t, std_r = center_error_std(SIGMA, n, phi)
    errors = []
    for _ in range(300):
        fit = fit_circle(arc(angles) + rng.normal(0.0, SIGMA, (n, 2)))
        errors.append(center_error_components(fit.center, 0.15 + phi / 2))
    errors = np.array(errors)
    assert np.std(errors[:, 0]) == pytest.approx(std_t, rel=0.2)
    assert np.std(errors[:, 1]) == pytest.approx(std_r, rel=0.2)
    for column, std in ((0, std_t), (1, std_r)):
        assert abs(np.mean(errors[:, column])) < 4 * std / math.sqrt(len(errors))
    assert np.all(np.abs(errors[:, 0]) < 5 * std_t)
    assert np.all(np.abs(errors[:, 1]) < 5 * std_r)


def simulate_opening(rng, *, sigma_p: float, sigma_v: float, sweep_deg: float = 41.2):
    """Feeds the estimator Q's samples of a door opened at 0.025 m/s, sampled at 200 Hz.

    Returns the estimator and the per-sample (angle, estimate) pairs.
    """
    dt, speed = 0.005, 0.025
    omega = speed / RADIUS
    n = int(math.radians(sweep_deg) / omega / dt)
    theta0 = 0.154
    true_tangent0 = np.array([-math.cos(theta0), math.sin(theta0)])
    # The initial guess is 20 deg off the true tangent (the worst case of the acceptance grid).
    c, s = math.cos(math.radians(20)), math.sin(math.radians(20))
    estimator = HingeEstimator(
        np.array([[c, -s], [s, c]]) @ true_tangent0,
        min_sagitta=0.001,
        velocity_time_constant=0.1,
        min_speed=0.005,
    )
    history = []
    for k in range(n):
        angle = theta0 + omega * k * dt
        p = arc(np.array([angle]))[0] + rng.normal(0.0, sigma_p, 2)
        v = speed * np.array([-math.cos(angle), math.sin(angle)]) + rng.normal(0.0, sigma_v, 2)
        history.append((angle, estimator.update(p, v, dt)))
    return estimator, history


def test_estimator_converges_within_the_bound_as_the_door_opens():
    """The hinge estimate's error shrinks as the arc grows and ends within 5 standard
    deviations of the first-order bound for the whole arc (about 0.3 mm here)."""
    rng = np.random.default_rng(3)
    _, history = simulate_opening(rng, sigma_p=SIGMA, sigma_v=0.002)
    theta0 = history[0][0]
    ready = [(a, e) for a, e in history if e.fit_ready]
    assert ready, "the fit never became trusted"
    errors = np.array([np.linalg.norm(e.center - CENTER) for _, e in ready])
    bounds = np.array(
        [
            np.hypot(*center_error_std(SIGMA, k + 1, a - theta0))
            for k, (a, e) in enumerate(history)
            if e.fit_ready
        ]
    )
    # The bound shrinks like Phi^-2 N^-1/2; the errors follow it.
    assert bounds[-1] < bounds[0] / 10
    assert errors[-1] < 5 * bounds[-1]
    assert np.median(errors[-50:]) < np.median(errors[:50])
    final = ready[-1][1]
    assert final.radius == pytest.approx(RADIUS, abs=5 * bounds[-1])
    # Door angle: the arc swept about the estimated center.
    assert abs(final.door_angle) == pytest.approx(ready[-1][0] - theta0, abs=math.radians(0.2))


def test_tangent_follows_the_measured_velocity():
    """From a 20 deg wrong guess the tangent turns onto the true one within 5 time constants
    and then trails it by the low-pass lag omega * tau (0.5 deg here) plus noise
    (sigma_v / v * sqrt(dt / (2 tau)) per axis: 0.9 deg at sigma_v = 2 mm/s, 5 x that)."""
    rng = np.random.default_rng(5)
    _, history = simulate_opening(rng, sigma_p=SIGMA, sigma_v=0.002, sweep_deg=10.0)
    lag = 0.025 / RADIUS * 0.1
    noise = 0.002 / 0.025 * math.sqrt(0.005 / 0.2)
    settled = history[int(5 * 0.1 / 0.005) :]
    for angle, estimate in settled:
        truth = np.array([-math.cos(angle), math.sin(angle)])
        assert abs(signed_angle(truth, estimate.tangent)) < lag + 5 * noise


def test_a_straight_path_never_trusts_the_fit():
    """A noisy straight pull (no door) bulges far less than min_sagitta: never ready."""
    rng = np.random.default_rng(9)
    estimator = HingeEstimator(
        [-1.0, 0.0], min_sagitta=0.001, velocity_time_constant=0.1, min_speed=0.005
    )
    for k in range(2000):
        p = np.array([0.7 - 0.025 * 0.005 * k, 0.02]) + rng.normal(0.0, SIGMA / 2, 2)
        assert not estimator.update(p, [-0.025, 0.0], 0.005).fit_ready


def test_invalid_estimator_settings_are_named():
    with pytest.raises(ConfigError, match="initial_tangent"):
        HingeEstimator([0.0, 0.0], min_sagitta=0.001, velocity_time_constant=0.1, min_speed=0)
    with pytest.raises(ConfigError, match="min_sagitta"):
        HingeEstimator([1.0, 0.0], min_sagitta=0.0, velocity_time_constant=0.1, min_speed=0)


@pytest.fixture(scope="module")
def jacobian_at_grasp():
    from pydrake.multibody.tree import JacobianWrtVariable

    from doorlab.cell.frames import L7_FRAME, p_L7Q
    from doorlab.cell.station import make_controller_plant

    plant = make_controller_plant()
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, np.array([0.05, 0.30, -0.02, -1.52, -0.04, 0.54, 0.07]))
    L7, W = plant.GetFrameByName(L7_FRAME), plant.world_frame()
    return plant.CalcJacobianSpatialVelocity(context, JacobianWrtVariable.kV, L7, p_L7Q, W, W)


def test_wrench_from_external_torques_is_exact_in_range(jacobian_at_grasp):
    """tau = J^T F for any wrench F at Q: least squares recovers F to rounding (rank-6 J
    makes J^T injective: all six components are observable) with zero residual."""
    J = jacobian_at_grasp
    F = np.array([0.3, -0.2, 0.1, 2.0, -1.0, 0.5])
    estimate = estimate_contact_wrench(J, J.T @ F)
    assert np.allclose(estimate.F_Q_W, F, atol=1e-9)
    assert estimate.residual < 1e-9
    assert estimate.min_singular_value > 0.05  # far from singular near the handle


def test_torque_outside_the_range_of_J_transpose_is_invisible(jacobian_at_grasp):
    """A torque along the arm's self-motion (null(J), orthogonal to range(J^T)), as a contact
    elsewhere on the arm could cause, changes no wrench component: it is the residual."""
    J = jacobian_at_grasp
    null = np.linalg.svd(J)[2][-1]
    assert np.allclose(J @ null, 0.0, atol=1e-12)
    F = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0])
    estimate = estimate_contact_wrench(J, J.T @ F + 0.7 * null)
    assert np.allclose(estimate.F_Q_W, F, atol=1e-9)
    assert estimate.residual == pytest.approx(0.7, rel=1e-9)


def test_no_contact_gives_no_wrench():
    J = np.eye(6, 7)
    assert np.all(estimate_contact_wrench(J, np.zeros(7)).F_Q_W == 0.0)
