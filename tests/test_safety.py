"""The command checks of doorlab.cell.safety: the pure checks, and the same checks in simulation
(``station.safety.enabled``), which stop a run before the plant steps with a bad command."""

from __future__ import annotations

import math

import numpy as np
import pytest

from doorlab.cell.safety import SafetyLimits, check_command
from doorlab.config import SafetyConfig, Scenario, validate
from doorlab.constants import (
    JOINT_POSITION_LIMITS,
    JOINT_SPEED_LIMITS,
    JOINT_TORQUE_LIMITS,
    Q_HOME,
)
from doorlab.errors import ConfigError, SafetyStop

PERIOD = 0.005
Q = np.array([0.1, 0.5, -0.2, -1.5, 0.3, 1.0, 0.2])


def check(limits, q_ref, tau_ff=None, q_measured=Q, previous=Q, dt=PERIOD):
    tau_ff = np.zeros(7) if tau_ff is None else tau_ff
    return check_command(
        limits,
        t=1.0,
        q_ref=q_ref,
        tau_ff=tau_ff,
        q_measured=q_measured,
        q_ref_previous=previous,
        dt=dt,
    )


@pytest.fixture
def limits():
    return SafetyLimits.from_config(SafetyConfig(), Q)


def test_a_command_at_the_measured_pose_passes(limits):
    assert check(limits, Q) is None


def test_each_limit_is_named_with_its_joint(limits):
    """Just over each bound, on one joint: that limit and that joint, with the bound's value."""
    config = SafetyConfig()
    gap = JOINT_SPEED_LIMITS[2] * config.gap_time
    v = check(limits, Q + np.eye(7)[2] * gap * 1.01, previous=Q + np.eye(7)[2] * gap)
    assert (v.limit, v.joint_name) == ("position_gap", "iiwa_joint_3")
    assert v.bound == pytest.approx(gap)
    step = JOINT_SPEED_LIMITS[4] * config.speed_fraction * PERIOD * 1.01
    v = check(limits, Q + np.eye(7)[4] * step, q_measured=Q + np.eye(7)[4] * step)
    assert (v.limit, v.joint_name) == ("joint_speed", "iiwa_joint_5")
    tau = np.eye(7)[6] * JOINT_TORQUE_LIMITS[6] * config.torque_fraction * 1.01
    v = check(limits, Q, tau_ff=tau)
    assert (v.limit, v.joint_name, v.bound) == ("feedforward_torque", "iiwa_joint_7", 10.0)
    edge = JOINT_POSITION_LIMITS[0] - config.joint_limit_margin
    near = Q.copy()
    near[0] = -(edge + 1e-3)
    v = check(limits, near, q_measured=near, previous=near)
    assert (v.limit, v.joint_name) == ("joint_position", "iiwa_joint_1")
    assert v.bound == pytest.approx(edge)
    assert "iiwa_joint_1" in v.message() and "t = 1.000 s" in v.message()


def test_a_non_finite_command_is_a_violation(limits):
    v = check(limits, Q, tau_ff=np.array([0, 0, np.nan, 0, 0, 0, 0.0]))
    assert (v.limit, v.joint_name) == ("finite", "iiwa_joint_3")
    assert v.to_dict()["value"] is None


def test_a_joint_that_starts_in_the_margin_may_stay_but_not_go_further():
    """q_home has joint 4 at -2.094 rad, 0.4 mrad inside its limit: holding it is allowed,
    going further out is not."""
    limits = SafetyLimits.from_config(SafetyConfig(), Q_HOME)
    assert check(limits, Q_HOME, q_measured=Q_HOME, previous=Q_HOME) is None
    further = Q_HOME - np.eye(7)[3] * 1e-4
    v = check(limits, further, q_measured=Q_HOME, previous=Q_HOME)
    assert (v.limit, v.joint_name) == ("joint_position", "iiwa_joint_4")
    assert limits.q_max[3] == pytest.approx(abs(Q_HOME[3]))


@pytest.mark.parametrize(
    "key, value",
    [
        ("joint_limit_margin", -0.1),
        ("gap_time", 0.0),
        ("speed_fraction", 1.5),
        ("torque_fraction", 0),
    ],
)
def test_bad_safety_settings_are_config_errors(key, value):
    scenario = Scenario()
    setattr(scenario.station.safety, key, value)
    with pytest.raises(ConfigError, match=f"station.safety.{key}"):
        validate(scenario)


def short(controller: str) -> Scenario:
    scenario = Scenario(controller=controller, doors="closed")
    t = scenario.timeline
    t.hold_duration, t.approach_duration, t.grasp_duration = 0.2, 2.0, 0.5
    t.arc_duration, t.extra_time = 2.0, 0.2
    return validate(scenario)


def test_the_checks_in_simulation_pass_the_shipped_plan_and_change_nothing():
    """With the default limits the velocity plan runs to its end, bit for bit as without the
    checks (the monitor only reads)."""
    from doorlab.episode.controllers import run_controller

    scenario = short("velocity")
    unchecked, _ = run_controller(scenario)
    scenario.station.safety.enabled = True
    checked, _ = run_controller(scenario)
    np.testing.assert_array_equal(checked.q_measured, unchecked.q_measured)
    np.testing.assert_array_equal(checked.q_commanded, unchecked.q_commanded)


def test_a_simulated_run_stops_at_the_first_command_over_a_limit():
    """A torque fraction the impedance plan's first J^T F exceeds: the run stops at that tick
    (the first tick whose tau_ff breaks the bound in an unchecked run logged every tick), and
    the logs up to the stop are the unchecked run's."""
    from doorlab.episode.controllers import run_controller

    scenario = short("impedance")
    scenario.timeline.log_period = scenario.timeline.control_period
    unchecked, _ = run_controller(scenario)
    scenario.station.safety.enabled = True
    scenario.station.safety.torque_fraction = 0.02
    with pytest.raises(SafetyStop) as stop:
        run_controller(scenario)
    violation = stop.value.violation
    assert violation.limit == "feedforward_torque"
    bound = 0.02 * JOINT_TORQUE_LIMITS
    # The log at t shows the command in force at t: the tick at t_k's command from t_k + period.
    over = np.flatnonzero(np.any(np.abs(unchecked.tau_feedforward) > bound, axis=1))[0]
    t_tick = unchecked.t[over] - scenario.timeline.control_period
    assert violation.t == pytest.approx(t_tick, abs=1e-9)
    assert violation.bound == pytest.approx(bound[violation.joint])
    partial = stop.value.result
    n = len(partial.t)
    assert partial.t[-1] <= violation.t + 1e-9
    np.testing.assert_array_equal(partial.q_measured, unchecked.q_measured[:n])
    assert not np.any(np.abs(partial.tau_feedforward) > bound)
    assert math.isclose(partial.arc_window[0], unchecked.arc_window[0])


def test_doorlab_run_reports_a_safety_stop_with_exit_8(tmp_path):
    """The CLI: exit 8, metrics.json names the limit, the joint and the time; the logs up to
    the stop are in log.npz."""
    import json

    from doorlab.cli.parser import main
    from doorlab.episode.result import EpisodeResult

    out = tmp_path / "run"
    sets = [
        "timeline.hold_duration=0.2",
        "timeline.approach_duration=2.0",
        "timeline.grasp_duration=0.5",
        "timeline.arc_duration=2.0",
        "station.safety.enabled=true",
        "station.safety.torque_fraction=0.02",
    ]
    args = ["run", "--controller", "impedance", "--out", str(out), "--no-replay"]
    code = main([*args, *(a for s in sets for a in ("--set", s))])
    assert code == 8
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["status"] == "safety_stop"
    violation = metrics["violation"]
    assert violation["limit"] == "feedforward_torque"
    assert violation["joint"].startswith("iiwa_joint_")
    log = EpisodeResult.load(out / "log.npz")
    arc_start = log.plan_starts[3]  # hold 0.2 + 1 s, move 2 + 1 s, grasp 0.5 + 1 s: 5.7 s
    assert arc_start == pytest.approx(5.7)
    assert arc_start <= violation["t"] < arc_start + 0.5  # the impedance plan's J^T F
    assert log.t[-1] <= violation["t"]
