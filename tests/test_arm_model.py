"""The arm's uncertain parameters as physics (``station.arm``, :mod:`doorlab.cell.arm_model`):
KUKA's external-torque estimate and the freeze judged on it, its noise, the damping mappings,
and KUKA's loop without the simulator's h Kq.

The freeze test is the issue's load-data mismatch: with no load data entered KUKA's model
leaves out the gripper, so at rest its estimate of the external torque is minus the gripper's
gravity torque (computed here from the model, independently of the cell), and a freeze limit
below it stops the driver at the first cycle; with exact load data the same limit does not.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from doorlab.config import load_scenario, update_scenario
from doorlab.constants import Q_HOME

PRESET = Path(__file__).resolve().parents[1] / "examples" / "kuka_arm.yaml"


def gripper_gravity(q: np.ndarray) -> np.ndarray:
    """The holding torque of the gripper alone at q (7,) [N m], from the controller plants."""
    from doorlab.cell.station import make_controller_plant

    torques = []
    for mass in (None, 0.0):
        plant = make_controller_plant(mass)
        context = plant.CreateDefaultContext()
        plant.SetPositions(context, q)
        torques.append(-plant.CalcGravityGeneralizedForces(context))
    return torques[0] - torques[1]


def at_rest(yaml: str, duration: float = 0.2):
    """The simulated driver with no client for ``duration`` (the arm holds q_home): its
    outcome and every cycle's status."""
    from doorlab.hardware.sim_driver import SimDriver

    scenario = update_scenario(load_scenario(PRESET), yaml)
    driver = SimDriver(scenario, lcm_url="memq://", record=True)
    outcome = driver.run(duration=duration, realtime_rate=0.0, guard=0.0)
    return outcome, driver.systems.cycle_log(driver.simulator.get_context())


def test_the_freeze_fires_on_the_estimated_external_torque_of_missing_load_data():
    """Limit 0.8 x the gripper's gravity torque on its largest joint: no load data -> the
    driver stops at the first cycle, naming that joint and that torque; exact load data ->
    it runs on (the arm touches nothing)."""
    from doorlab.cell.frames import ARM_JOINTS
    from doorlab.kuka import EXTERNAL_TORQUE_SCALE

    g = gripper_gravity(Q_HOME)
    ratio = np.abs(g) / EXTERNAL_TORQUE_SCALE
    joint = int(np.argmax(ratio))
    limit = 0.8 * float(ratio[joint])
    stop = f"station: {{driver: {{external_torque_limit: {limit}}}, arm: {{load_mass: 0.0}}}}"
    outcome, log = at_rest(stop)
    assert outcome.status == "aborted" and "external torque" in outcome.message
    assert ARM_JOINTS[joint] in outcome.message
    shown = float(outcome.message.split("= ")[1].split(" N m")[0])
    assert shown == pytest.approx(abs(g[joint]), rel=1e-2)  # 3 digits printed
    assert outcome.sim_time_s < 0.02  # the first cycles
    fine, log = at_rest(f"station: {{driver: {{external_torque_limit: {limit}}}}}")
    assert fine.status == "stopped", fine.message
    assert np.max(np.abs(log["tau_external"])) < 1e-9  # exact model, no contact: zero


def test_without_load_data_the_status_carries_minus_the_grippers_gravity():
    """At rest, load data 0: every status's external torque is -g_gripper(q) at the arm's q
    (the joints sag a little under the weight KUKA does not hold), to 1e-6 N m."""
    outcome, log = at_rest("station: {arm: {load_mass: 0.0}}", duration=0.1)
    assert outcome.status == "stopped"
    for q, tau in zip(log["q_measured"][2:], log["tau_external"][2:], strict=True):
        np.testing.assert_allclose(tau, -gripper_gravity(q), atol=1e-6)


def test_the_estimates_noise_has_its_deviation_and_repeats_with_its_seed():
    """Noise 0.2 N m: the statuses' external torque at rest has that standard deviation (400
    samples: within 15 %, 4 standard errors of a deviation); the same seed gives the same
    draws, another seed others."""
    noise = "station: {arm: {external_torque_noise: [0.2, 0.2, 0.2, 0.2, 0.2, 0.2, 0.2]}}"
    _, first = at_rest(noise, duration=2.0)
    tau = first["tau_external"]
    assert len(tau) >= 400
    np.testing.assert_allclose(tau.std(axis=0), 0.2, rtol=0.15)
    _, again = at_rest(noise, duration=2.0)
    np.testing.assert_array_equal(again["tau_external"], tau)
    _, other = at_rest(noise.replace("]}}", "], seed: 1}}"), duration=2.0)
    assert np.max(np.abs(other["tau_external"] - tau)) > 0.1


def test_the_damping_mappings():
    """rotor_link: 2 d sqrt(K M_ii) with the rotors (the issue's 115/167/129/74/53/54/53),
    link: the link-side M_ii (its ratios 0.669 ... sqrt(M_link / M_ii)), driver_kd:
    kuka_driver's 50/35, values: as given."""
    from doorlab.cell.station import grasp_pose_inertia, kuka_joint_damping
    from doorlab.config import InnerLoopConfig

    def damping(**fields):
        return kuka_joint_damping(InnerLoopConfig(kind="kuka_joint_impedance", **fields))

    rotor = damping()
    np.testing.assert_allclose(rotor, [115.3, 166.6, 129.1, 73.9, 53.3, 54.0, 52.8], atol=0.1)
    ratio = damping(kuka_damping_model="link") / rotor
    np.testing.assert_allclose(ratio, np.sqrt(grasp_pose_inertia(False) / grasp_pose_inertia()))
    np.testing.assert_allclose(ratio[:4], [0.669, 0.599, 0.471, 0.579], atol=1e-3)
    assert list(damping(kuka_damping_model="driver_kd")) == [50, 50, 50, 50, 35, 35, 35]
    values = [10.0, 20.0, 30.0, 40.0, 5.0, 6.0, 7.0]
    assert list(damping(kuka_damping_model="values", kuka_damping_values=values)) == values


def _spectral_radius(M: np.ndarray, K: np.ndarray, D: np.ndarray, h: float) -> float:
    """One plant step of the linearized arm, explicit spring, implicit damping:
    (M + h D) v+ = M v - h K q, q+ = q + h v+."""
    n = len(M)
    B = np.linalg.inv(M + h * D)
    A_vv, A_vq = B @ M, -h * B @ K
    A = np.block([[np.eye(n) + h * A_vq, h * A_vv], [A_vq, A_vv]])
    return float(np.max(np.abs(np.linalg.eigvals(A))))


@pytest.mark.parametrize("model", ["rotor_link", "link", "driver_kd"])
def test_kukas_loop_is_stable_without_h_kq(model):
    """KUKA's loop now damps with Dq alone (no h Kq, so the step does not change its physics);
    the explicit spring stays stable at the preset's 2.5 ms and at 4x that (spectral radius
    below 1 at the grasp pose, the arm's inertia with the rotors), while doorlab's own loop
    keeps h Kq."""
    from doorlab.cell.station import joint_damping, loop_gains, make_controller_plant
    from doorlab.config import Scenario
    from doorlab.constants import Q_GRASP

    arm = update_scenario(
        load_scenario(PRESET), f"station: {{inner_loop: {{kuka_damping_model: {model}}}}}"
    )
    K, D = loop_gains(arm.station.inner_loop)
    np.testing.assert_array_equal(joint_damping(arm.station), D)
    cell = Scenario().station
    kq, dq = loop_gains(cell.inner_loop)
    np.testing.assert_allclose(joint_damping(cell), dq + cell.time_step * kq)
    plant = make_controller_plant()
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, Q_GRASP)
    M = plant.CalcMassMatrix(context)
    for h in (arm.station.time_step, 4 * arm.station.time_step):
        assert _spectral_radius(M, np.diag(K), np.diag(D), h) < 1.0
