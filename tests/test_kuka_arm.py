"""The lab arm in one process (``station.driver.timing: kuka_driver``, KUKA's joint impedance,
``examples/kuka_arm.yaml``): kuka_driver's filter and cycle, KUKA's damping, the external-torque
stop, the preset's file and command lines.

Physics runs are short (the arc only where a property needs it): the full episodes on the
preset are test_hardware_wiring.py's (through the simulated driver) and the report's.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from doorlab.config import Scenario, arm_preset, load_scenario, validate
from doorlab.constants import Q_GRASP
from doorlab.errors import SafetyStop
from doorlab.kuka import (
    EXTERNAL_TORQUE_SCALE,
    external_torque_limits,
    filter_alpha,
    filtered_velocity,
    kuka_damping,
)

PRESET = Path(__file__).resolve().parents[1] / "examples" / "kuka_arm.yaml"


def reference_filter(q: np.ndarray, dt: float = 0.005, cutoff: float = 40.0) -> np.ndarray:
    """kuka_driver's velocity estimate written from its published constants
    (kuka-driver/low_pass_filter.h: val = alpha val + (1 - alpha) input, alpha = 1 - dt / (dt +
    RC), RC = 1 / (2 pi f); the input (q_k - q_{k-1}) / dt; kuka_driver.cc skips the first
    packet, whose dt is 0)."""
    rc = 1.0 / (2.0 * math.pi * cutoff)
    alpha = 1.0 - dt / (dt + rc)
    out = np.zeros_like(q)
    value = np.zeros(q.shape[1])
    for k in range(1, len(q)):
        value = alpha * value + (1.0 - alpha) * (q[k] - q[k - 1]) / dt
        out[k] = value
    return out


def short_arm(controller: str = "velocity", **timeline: float) -> Scenario:
    scenario = arm_preset(Scenario(controller=controller, doors="closed"))
    scenario.timeline.hold_duration, scenario.timeline.approach_duration = 0.2, 4.0
    scenario.timeline.grasp_duration, scenario.timeline.extra_time = 0.5, 0.0
    for key, value in timeline.items():
        setattr(scenario.timeline, key, value)
    return validate(scenario)


@pytest.fixture(scope="module")
def arm_run():
    """The velocity plan on the preset, the arc cut to 1 s (its first second is what the
    filter and timing tests need), with its per-cycle status log."""
    from doorlab.episode.controllers import run_controller

    result, _ = run_controller(short_arm(arc_duration=1.0))
    return result


def test_the_filter_constants():
    """alpha at 40 Hz and 5 ms is 1 - 5 / (5 + 3.979) = 0.443; the module's filter is the
    reference's; the limits are 60 N m x kuka_driver's scale."""
    assert filter_alpha(40.0) == pytest.approx(1.0 - 0.005 / (0.005 + 1 / (80 * math.pi)))
    assert filter_alpha(40.0) == pytest.approx(0.4431, abs=1e-4)
    q = np.cumsum(np.random.default_rng(1).normal(size=(50, 7)), axis=0) * 1e-3
    np.testing.assert_allclose(filtered_velocity(q), reference_filter(q), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(external_torque_limits(), [60, 60, 60, 30, 12, 12, 6])
    assert external_torque_limits(10.0) == pytest.approx(10.0 * EXTERNAL_TORQUE_SCALE)


def test_the_status_velocity_is_kuka_drivers_filter(arm_run):
    """Each cycle's status velocity (what the plans read) equals the reference filter of the
    status positions, to round-off (the C++ gain sums the same terms in another order); it
    differs from the plant's exact velocity by the filter's lag."""
    cycles = arm_run.cycle_log
    reference = reference_filter(cycles["q_measured"])
    np.testing.assert_allclose(cycles["v_estimated"], reference, rtol=0, atol=1e-12)
    assert np.abs(cycles["v_estimated"]).max() > 0.05  # the arm moved
    lag = np.abs(cycles["v_estimated"] - cycles["v_measured"]).max()
    assert lag > 1e-3


def test_a_command_acts_one_cycle_after_its_status(arm_run):
    """The arm stands still (exactly) through the first cycle, whose command is none; the
    command computed from status k is the one the arm tracks from cycle k + 1, reported by
    status k + 2 (commanded up to it): the clamped prefix samples one cycle apart."""
    from doorlab.kuka import clamp_command

    cycles = arm_run.cycle_log
    q_home = cycles["q_measured"][0]
    np.testing.assert_array_equal(cycles["q_measured"][:2], [q_home, q_home])
    assert np.all(cycles["v_measured"][:2] == 0)
    # Status 0 and 1 report the start pose as commanded (no command before cycle 1).
    np.testing.assert_array_equal(cycles["q_commanded"][:2], [q_home, q_home])
    # Status 2 reports the command of status 0, the hold at the start pose, clamped.
    np.testing.assert_array_equal(cycles["q_commanded"][2], clamp_command(q_home))
    assert clamp_command(q_home)[3] != q_home[3]  # joint 4 is within 1 deg of its limit


def test_kukas_damping_in_n_m_s_per_rad():
    """kuka_joint_impedance: Kq = KUKA's stiffness, Dq = 2 d sqrt(K M_ii) with M_ii at
    Q_GRASP, the problem set's grasp pose, which the one-shot IK finds again (within 1 mrad)."""
    from doorlab.cell.geometry import scenario_door_geometry
    from doorlab.cell.station import loop_gains, make_controller_plant
    from doorlab.episode.controllers import get_controller

    scenario = Scenario(controller="velocity")
    plant = make_controller_plant()
    grasp = get_controller("velocity").build(scenario, scenario_door_geometry(scenario), plant)
    np.testing.assert_allclose(grasp.q_start, Q_GRASP, atol=1e-3)
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, Q_GRASP)
    inertia = np.diag(plant.CalcMassMatrix(context))
    loop = arm_preset().station.inner_loop
    kq, dq = loop_gains(loop)
    np.testing.assert_array_equal(kq, [1000, 1000, 1000, 500, 500, 500, 500])
    np.testing.assert_allclose(dq, 2.0 * np.sqrt(kq * inertia), rtol=1e-12)
    assert dq == pytest.approx(kuka_damping(kq, [0.5] * 7, inertia) * 2)
    doorlab = loop_gains(Scenario().station.inner_loop)[1]
    assert np.all(dq / doorlab > 4.0)  # damping 1.0 is 5-10x doorlab's zeta = 0.1


@pytest.mark.slow
def test_the_external_torque_stop_in_one_process():
    """The door's hinge damped at 1e5 N m s/rad, the gripper squeezing hard (kp 4000 N/m, up
    to 80 N: the default grip slips at about a newton), the IK plan drags the handle along
    the arc. The simulated grip still gives way at single-digit torques (the physical stop
    is the simulated driver's test, tests/test_sim_driver.py), so kuka_driver's
    --ext_trq_limit is lowered to 10 N m (2 N m on joints 5-6, 1 N m on joint 7): the run
    stops at the first cycle over a joint's limit (safety_stop, limit external_torque, the
    joint and the torque), as the driver exits; with the default 60 N m it runs through,
    and every status before the stop was within the lowered limits."""
    from doorlab.episode.controllers import run_controller

    scenario = short_arm("ik", arc_duration=2.0)
    scenario.station.safety.enabled = False  # the fast arc's gaps: not what is tested
    scenario.station.hinge_damping = 1e5
    scenario.station.gripper.kp, scenario.station.gripper.force_limit = 4000.0, 80.0
    through, _ = run_controller(validate(scenario))
    peak = np.abs(through.cycle_log["tau_external"]).max(axis=0)
    assert np.all(peak < external_torque_limits())
    scenario.station.driver.external_torque_limit = 10.0
    limits = external_torque_limits(10.0)
    assert np.any(peak > limits)  # the premise
    with pytest.raises(SafetyStop) as stopped:
        run_controller(validate(scenario))
    violation = stopped.value.violation
    assert violation.limit == "external_torque"
    assert violation.value > violation.bound == limits[violation.joint]
    assert "external_torque limit broken on iiwa_joint_" in str(stopped.value)
    cycles = stopped.value.result.cycle_log
    before = cycles["t"] < violation.t - 1e-9
    assert np.all(np.abs(cycles["tau_external"][before]) <= limits)
    assert cycles["t"][-1] < violation.t  # the stopping cycle's status never went out


def test_the_preset_file_is_the_preset():
    """examples/kuka_arm.yaml sets the same fields as arm_preset() (KUKA's gains written out)."""
    assert load_scenario(PRESET) == arm_preset()
    preset = arm_preset()
    assert preset.station.driver.timing == "kuka_driver"
    assert preset.station.inner_loop.kind == "kuka_joint_impedance"


@pytest.mark.parametrize(
    "argv",
    [
        ["run", "--set", "timeline.arc_duration=-1"],
        ["run", "--hardware", "--set", "timeline.arc_duration=-1"],
        ["sim-driver", "--set", "timeline.arc_duration=-1"],
        ["report", "--set", "timeline.arc_duration=-1"],
    ],
    ids=["run", "run --hardware", "sim-driver", "report"],
)
def test_every_command_takes_the_preset(argv, tmp_path, capsys):
    """--config examples/kuka_arm.yaml is read by every command that takes a scenario (a
    --set after it that breaks the timeline shows the config was read and merged: exit 2
    naming the field, nothing run); sweeps take it as a SPEC's base (the shipped
    sweep_kuka_*.yaml, tests/test_sweep.py)."""
    from doorlab.cli.parser import main

    code = main([*argv[:-2], "--config", str(PRESET), *argv[-2:], "--out", str(tmp_path / "o")])
    assert code == 2
    err = capsys.readouterr().err
    assert "timeline.arc_duration" in err and "\n" not in err.strip()


@pytest.mark.slow
def test_a_preset_run_from_the_command_line(tmp_path):
    """``doorlab run --config examples/kuka_arm.yaml`` runs the arm in one process and writes
    its folder (the arc cut short)."""
    out = tmp_path / "run"
    sets = ["timeline.hold_duration=0.2", "timeline.approach_duration=4.0"]
    sets += ["timeline.arc_duration=1.0", "timeline.extra_time=0.0"]
    command = [sys.executable, "-m", "doorlab.cli", "run", "--config", str(PRESET), "--out"]
    command += [str(out), "--no-replay", *(a for s in sets for a in ("--set", s))]
    done = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    written = load_scenario(out / "scenario.yaml")
    assert written.station.driver.timing == "kuka_driver"
    assert written.station.inner_loop.kind == "kuka_joint_impedance"
