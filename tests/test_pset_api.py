"""The seed API's pieces and the grader's judgement, without simulating (fast).

The episodes themselves run in ``test_pset.py``.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from pydrake.trajectories import PiecewisePolynomial

from doorlab.cell.geometry import default_door_geometry
from doorlab.constants import Q_HOME
from doorlab.control.plans import ArmState
from doorlab.errors import ConfigError
from doorlab.pset.grading import grader
from doorlab.pset.handout import task_helpers
from doorlab.pset.handout.station_api import (
    ProblemSetJointSpacePlan,
    ProblemSetPlanAdapter,
    ProblemSetTaskSpacePlanBase,
    StationRun,
    StudentCodeError,
    VectorLogView,
)
from doorlab.pset.rules import verdicts

STATE = ArmState(Q_HOME.copy(), np.zeros(7), np.zeros(7))


class _Plan:
    duration = 1.0

    def __init__(self, q=None, tau=None):
        self.q, self.tau, self.seen_q_cmd = q, tau, []

    def CalcPositionCommand(self, q_iiwa, q_cmd, v_iiwa, tau_iiwa, t_plan, control_period):
        self.seen_q_cmd.append(np.array(q_cmd))
        return q_iiwa + 0.01 if self.q is None else self.q

    def CalcTorqueCommand(self, q_iiwa, q_cmd, v_iiwa, tau_iiwa, t_plan, control_period):
        return np.zeros(7) if self.tau is None else self.tau


def test_adapter_passes_the_last_command_as_q_cmd():
    plan = _Plan()
    adapter = ProblemSetPlanAdapter(plan, 0.005)
    first = adapter.command(0.0, STATE)
    adapter.command(0.005, STATE)
    np.testing.assert_array_equal(plan.seen_q_cmd[0], Q_HOME)  # nothing sent yet: measured q
    np.testing.assert_array_equal(plan.seen_q_cmd[1], first.q_ref)
    assert adapter.duration == 1.0 and adapter.name == "_Plan"


@pytest.mark.parametrize(
    ("q", "tau", "message"),
    [
        (np.full(7, np.nan), None, "CalcPositionCommand returned a non-finite"),
        (None, np.array([0, 0, np.inf, 0, 0, 0, 0]), "CalcTorqueCommand returned a non-finite"),
        (np.zeros(6), None, "shape (6,)"),
        (None, "torque", "expected a (7,) array"),
    ],
)
def test_adapter_rejects_what_the_robot_cannot_take(q, tau, message):
    with pytest.raises(StudentCodeError, match=message.replace("(", r"\(").replace(")", r"\)")):
        ProblemSetPlanAdapter(_Plan(q, tau), 0.005).command(0.3, STATE)


def test_joint_space_plan_replays_and_clamps_its_trajectory():
    knots = np.column_stack([Q_HOME, Q_HOME + 0.1])
    plan = ProblemSetJointSpacePlan(PiecewisePolynomial.FirstOrderHold([0.0, 2.0], knots))
    assert plan.duration == 2.0
    args = (Q_HOME, Q_HOME, np.zeros(7), np.zeros(7))
    np.testing.assert_allclose(plan.CalcPositionCommand(*args, 1.0, 0.005), Q_HOME + 0.05)
    np.testing.assert_allclose(plan.CalcPositionCommand(*args, 5.0, 0.005), Q_HOME + 0.1)
    np.testing.assert_array_equal(plan.CalcTorqueCommand(*args, 1.0, 0.005), np.zeros(7))


def test_run_simulation_needs_a_joint_space_first_plan():
    run = StationRun()
    task = ProblemSetTaskSpacePlanBase(lambda s: np.zeros(3), lambda s: None, 10.0, np.zeros(3))
    for plans in ([], [task]):
        with pytest.raises(ConfigError):
            run.run(
                Q_HOME,
                [0.0, 0.0],
                plans,
                [0.005] * len(plans),
                extra_time=0.0,
                real_time_rate=0.0,
                meshcat=None,
                gripper_setpoint_initial=0.025,
            )


def test_task_space_base_errors_follow_the_problem_sets_definitions():
    g = default_door_geometry()
    plan = ProblemSetTaskSpacePlanBase(
        lambda tau: g.p_WQ_ref(tau) - g.p_W_handle, g.R_WL7_ref, 10.0, np.array([0, 0, 0.214])
    )
    plan.CalcKinematics(Q_HOME, np.zeros(7))
    # p_WQ_0 is where Q was at the first call: at t = 0 the position error vanishes.
    np.testing.assert_allclose(plan.CalcPositionError(0.0), np.zeros(3), atol=1e-15)
    # Halfway, the error is the arc's displacement from the handle.
    np.testing.assert_allclose(
        plan.CalcPositionError(5.0), g.p_WQ_ref(0.5) - g.p_W_handle, atol=1e-12
    )
    R = plan.CalcOrientationError(10.0)
    expected = plan.R_WL7.inverse() @ g.R_WL7_ref(1.0)
    assert (R.inverse() @ expected).ToAngleAxis().angle() < 1e-12
    assert plan.Jv_WL7q.shape == (6, 7)


def test_task_helpers_agree_with_the_geometry():
    g = default_door_geometry()
    arc = task_helpers.handle_arc_points()
    assert arc.shape == (100, 3)
    np.testing.assert_allclose(task_helpers.radial_tracking_error(arc), 0.0, atol=1e-12)
    # The problem set's quarter circle: from the hinge's -y side (theta = 0) to its -x side
    # (90 deg).
    np.testing.assert_allclose(arc[0], g.p_W_hinge - [0, g.r_handle, 0], atol=1e-12)
    np.testing.assert_allclose(arc[-1], g.p_W_hinge - [g.r_handle, 0, 0], atol=1e-12)
    np.testing.assert_allclose(task_helpers.interpolate_arc(0.0), g.p_W_handle, atol=1e-12)
    constants = task_helpers.door_constants()
    assert constants["r_handle"] == pytest.approx(g.r_handle)
    assert constants["angle_end"] == pytest.approx(math.radians(50.0))


def test_l7_poses_slice_a_log_like_the_seed():
    t = np.arange(0.0, 0.1, 0.01)
    q = np.tile(Q_HOME, (len(t), 1)).T
    poses, times = task_helpers.l7_poses(VectorLogView(t, q), n_start=3, n_end=7)
    np.testing.assert_array_equal(times, t[3:7])
    assert len(poses) == 4
    p_WQ = task_helpers.q_positions(poses, np.array([0, 0, 0.214]))
    assert p_WQ.shape == (4, 3)
    angles = task_helpers.orientation_tracking_error(poses, times, 10.0)
    assert angles.shape == (4,) and np.all(angles >= 0)


def _figures(**overrides) -> dict:
    base = {
        "status": "ok",
        "max_radial_error_m": 0.001,
        "max_orientation_error_rad": 0.01,
        "q_end_angle_rad": 0.87,
        "door_opening_rad": 0.6,
        "door_opening_at_arc_end_rad": 0.55,
        "handle_held": True,
        "wall_time_s": 5.0,
    }
    return base | overrides


def test_episode_judges_apply_their_margins_relative_to_the_reference():
    ref = {"reference:ik": {"figures": _figures(max_radial_error_m=0.0012)}}
    bound = 0.0012 + grader.IK_RADIAL_MARGIN
    ok, _ = verdicts._judge_ik(
        ref | {"student:ik": {"figures": _figures(max_radial_error_m=bound)}}
    )
    assert ok
    ok, text = verdicts._judge_ik(
        ref | {"student:ik": {"figures": _figures(max_radial_error_m=bound + 1e-4)}}
    )
    assert not ok and "FAILED max radial error" in text
    # Velocity must beat the reference IK's radial error.
    refs = ref | {"reference:velocity": {"figures": _figures(max_radial_error_m=0.0003)}}
    ok, _ = verdicts._judge_velocity(
        refs | {"student:velocity": {"figures": _figures(max_radial_error_m=0.0011)}}
    )
    assert ok
    ok, text = verdicts._judge_velocity(
        refs | {"student:velocity": {"figures": _figures(max_radial_error_m=0.0013)}}
    )
    assert not ok and "below pointwise IK" in text
    # Impedance: held and within the door margin.
    refs = {"reference:impedance": {"figures": _figures()}}
    late = 0.55 - grader.DOOR_OPENING_MARGIN - 0.01
    for student, passes in [
        (_figures(), True),
        (_figures(handle_held=False), False),
        (_figures(door_opening_at_arc_end_rad=late), False),
    ]:
        ok, _ = verdicts._judge_impedance(refs | {"student:impedance": {"figures": student}})
        assert ok is passes
    # A job without figures fails the test and says whose it was.
    ok, text = verdicts._judge_impedance(refs | {"student:impedance": {"error": "boom"}})
    assert not ok and "your code" in text and "boom" in text


def test_pretty_format_summarizes_every_test(tmp_path):
    results = {
        "score": 2.0,
        "tests": [
            {"name": "a", "score": 2.0, "max_score": 2.0, "output": "fine"},
            {"name": "b", "score": 0.0, "max_score": 1.0, "output": "expected 1\ngot 2"},
        ],
    }
    path = tmp_path / "r.json"
    path.write_text(json.dumps(results))
    text = grader.pretty_format_json_results(path)
    assert "[PASS] a: 2 / 2" in text and "[FAIL] b: 0 / 1" in text
    assert "    got 2" in text and text.endswith("Total score: 2 / 3")
