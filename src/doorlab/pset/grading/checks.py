"""The grader's unit tests, on the trusted side.

Each test takes its inputs and expected answers from :mod:`doorlab.pset.grading.answer_key` (drawn
from the grading seed, printed; derived from the assignment's random seed and the
submission's files: a regrade draws the same inputs; or, in the students' doorlab, from the
handout's practice table), asks the student's process
(:class:`~doorlab.pset.isolation.handle.StudentProcess`) for the student's outputs, validates them
(:mod:`doorlab.pset.isolation.channel`) and compares them with what was expected. This module holds
no answer of its own (no reference solution, no equation of the problem set), so the students'
doorlab grades with it; nothing the student's process holds can see or change the expected
answers. Every function returns a JSON-ready ``{"passed", "output"}``.

The inputs tell the arguments apart: q_cmd is not q, v and tau_ext are not zero, t_plan
is off the knots, control_period, duration, p_L7Q, the tolerances and the initial guess
are drawn away from the values a function could hard-code. When an answer is wrong, the
test says which argument it looks like the code misused (it tries the common mistakes);
and for the plans it also changes, one at a time, each argument the law must not read.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.math import RollPitchYaw, RotationMatrix

from doorlab.cell.frames import p_L7Q
from doorlab.cell.geometry import default_door_geometry
from doorlab.pset.grading.episodes import trajectory_from_answer
from doorlab.pset.handout.station_api import ArmKinematics
from doorlab.pset.isolation.channel import ProtocolError, as_array
from doorlab.pset.isolation.handle import StudentProcess

POSITION_ATOL = 1e-6
"""Agreement of positions with the reference [m]: the same formula in double precision."""
ROTATION_ATOL = 1e-6
"""Agreement of rotations with the reference [rad]."""
COMMAND_ATOL = 1e-6
"""Agreement of q_ref [rad] and tau_ff [N m] with the reference (same formula, float64;
pinv and lstsq agree to ~1e-12 away from singular configurations, which the draws avoid)."""
IK_POSITION_SLACK = 1e-5
"""Slack on the IK's position tolerance [m]: solvers meet linear bounds to ~1e-6 m."""
IK_ANGLE_SLACK = 3e-4
"""Slack on theta_bound [rad]: Drake states the bound on cos(theta) (through the trace of the
rotation), which solvers meet to ~1e-6; near theta_bound >= 0.004 rad that is
~1e-6 / sin(theta_bound) <= 2.5e-4 rad of angle."""
IK_STEP_FACTOR = 1.5
IK_STEP_SLACK = 0.1
"""A knot-to-knot joint change may exceed the reference IK's (same path, same knots) by this
factor plus this slack [rad]: two valid solutions differ by millimetres at Q (~0.01 rad); a
jump to another branch of the arm's redundancy (a knot not started from the previous one)
moves joints by a large fraction of a radian."""
VELOCITY_CLIP = 1.0
"""The 2019 solution clipped q_dot at +-1 rad/s: a clipped answer is accepted too [rad/s]."""
TORQUE_CLIP = 20.0
"""The 2019 solution clipped tau_ff at +-20 N m: a clipped answer is accepted too [N m]."""
UNIT_DRAWS = 6
"""Random arm states per control-law test."""
SHOWN_DRAWS = 2
"""Wrong draws shown in full (the others are counted)."""
SHOWN_PROBLEMS = 6
"""Problems of an IK answer shown (the others are counted)."""
DEFAULT_POSITION_TOLERANCE = 0.005
DEFAULT_THETA_BOUND = 0.005 * math.pi
"""InverseKinPointwise's defaults: the drawn tolerances are below them, so code that ignores
the arguments is caught [m], [rad]."""
SEED_CONTROL_PERIOD = 0.005
"""The plan runner's period [s]: the drawn control periods avoid it."""


def _fmt(x) -> str:
    return np.array2string(np.asarray(x, dtype=float), precision=5, suppress_small=True)


def _result(passed: bool, lines: list[str]) -> dict:
    return {"passed": bool(passed), "output": "\n".join(lines)}


def _values(answer: dict, count: int) -> list:
    values = answer.get("values")
    if not isinstance(values, list) or len(values) != count:
        raise ProtocolError(f"{count} answers expected, got something else")
    return values


def check_calc_p_Q(student: StudentProcess, expect: dict) -> dict:
    """calc_p_Q(tau) = arc(tau) - handle at random tau in [0, 1] (and 0 at tau = 0)."""
    e = expect
    taus = e["taus"]
    values = _values(student.call("p_Q", taus=list(taus)), len(taus))
    lines = [f"grading seed {e['seed']}; tolerance {POSITION_ATOL:g} m"]
    ok = True
    for tau, value, point, arc in zip(taus, values, e["expected"], e["arc"], strict=True):
        expected, arc = np.array(point, dtype=float), np.array(arc, dtype=float)
        got = as_array(value, (3,), "calc_p_Q", finite=False)
        if not bool(np.all(np.abs(got - expected) <= POSITION_ATOL)):
            ok = False
            hint = ""
            if np.all(np.abs(got - arc) <= POSITION_ATOL):
                hint = " (that is the arc point itself: subtract where Q starts, the handle)"
            lines.append(f"tau = {tau:.4f}: expected {_fmt(expected)} m, got {_fmt(got)}{hint}")
    if ok:
        lines.append(f"calc_p_Q matches the arc at {len(taus)} values of tau")
    return _result(ok, lines)


def _rotation(value: dict) -> np.ndarray | str:
    """The student's rotation as a (3, 3) orthonormal matrix, or what was wrong with it."""
    if not isinstance(value, dict) or "matrix" not in value:
        kind = value.get("type") if isinstance(value, dict) else None
        return f"expected a RotationMatrix, got {kind if isinstance(kind, str) else '?'}"
    R = as_array(value["matrix"], (3, 3), "calc_R_WL7_ref")
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-9 or np.linalg.det(R) < 0:
        return "not a rotation (its matrix is not orthonormal with determinant 1)"
    return R


def check_calc_R_WL7_ref(student: StudentProcess, expect: dict) -> dict:
    """calc_R_WL7_ref(tau) = RollPitchYaw(0, 3 pi/4, -sweep tau) at random tau."""
    e = expect
    taus = e["taus"]
    values = _values(student.call("R_WL7_ref", taus=list(taus)), len(taus))
    lines = [f"grading seed {e['seed']}; tolerance {ROTATION_ATOL:g} rad"]
    ok = True
    for tau, value, matrix in zip(taus, values, e["expected"], strict=True):
        expected = RotationMatrix(np.array(matrix, dtype=float))
        R = _rotation(value)
        if isinstance(R, str):
            lines.append(f"tau = {tau:.4f}: {R}")
            ok = False
            continue
        got = RotationMatrix(R)
        angle = (got.inverse() @ expected).ToAngleAxis().angle()
        if not angle <= ROTATION_ATOL:
            ok = False
            lines.append(
                f"tau = {tau:.4f}: expected roll-pitch-yaw "
                f"{_fmt(RollPitchYaw(expected).vector())} rad, got "
                f"{_fmt(RollPitchYaw(got).vector())} ({angle:.4g} rad apart)"
            )
    if ok:
        lines.append(f"calc_R_WL7_ref matches the reference at {len(taus)} values of tau")
    return _result(ok, lines)


# The plans' laws ---------------------------------------------------------------------------


_ARGUMENT_NAMES = {
    "q_cmd": "q_cmd (the last position command)",
    "v": "v_iiwa (the measured joint velocities)",
    "tau_ext": "tau_iiwa (the measured external torques)",
    "dt": "control_period",
}


def _close(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.all(np.abs(a - b) <= COMMAND_ATOL))


def ignored_arguments(kind: str) -> list[str]:
    """The arguments plan ``kind``'s law must not read (each is changed alone)."""
    return ["q_cmd", "v", "tau_ext"] + ([] if kind == "velocity" else ["dt"])


def _check_law(student: StudentProcess, kind: str, expect: dict) -> dict:
    method = "CalcPositionCommand" if kind == "velocity" else "CalcTorqueCommand"
    cls = "IiwaTaskSpaceVelocityPlan" if kind == "velocity" else "IiwaTaskSpaceImpedancePlan"
    unit = "rad" if kind == "velocity" else "N m"
    ignored = ignored_arguments(kind)
    e = expect
    # For each draw: its inputs, then the same with one argument the law must not read
    # drawn anew (one request: one round trip for the whole test).
    requests, base, probes = e["requests"], e["base"], e["probes"]
    answers = _values(student.call("law", kind=kind, cases=requests), len(requests))
    got = [as_array(a, (7,), method, finite=False) for a in answers]
    lines = [
        f"grading seed {e['seed']}; {UNIT_DRAWS} random arm states (q_cmd != q_iiwa, v_iiwa and "
        f"tau_iiwa != 0, t_plan off the knots, control_period != {SEED_CONTROL_PERIOD} s); "
        f"tolerance {COMMAND_ATOL:g}"
    ]
    # Which argument the code misuses first (what a student needs), then the draws.
    for name in ignored:
        changes = [
            float(np.max(np.abs(got[k] - got[base[i]])))
            for i, n, k in probes
            if n == name and np.all(np.isfinite(got[base[i]]))
        ]
        if any(not c <= COMMAND_ATOL for c in changes):
            lines.append(
                f"your answer depends on {_ARGUMENT_NAMES[name]}: changing only it changed "
                f"the answer by up to {np.nanmax(changes):.3g} {unit}; {method} must not read it"
            )
    wrong, diagnoses = [], {}
    for i, draw in enumerate(e["draws"]):
        accepted = [np.array(x, dtype=float) for x in draw["accepted"]]
        mistakes = [(text, np.array(x, dtype=float)) for text, x in draw["mistakes"]]
        answer = got[base[i]]
        if not any(_close(answer, x) for x in accepted):
            wrong.append(
                f"draw {i} (t_plan = {draw['t_plan']:.3f} s, control_period = "
                f"{draw['dt']:.4f} s): expected {_fmt(accepted[0])} {unit}, got {_fmt(answer)}"
            )
            why = next((text for text, x in mistakes if _close(answer, x)), None)
            if why is not None:
                diagnoses[why] = diagnoses.get(why, 0) + 1
    for why, count in diagnoses.items():
        lines.append(f"on {count} of {UNIT_DRAWS} draws your answer is {why}")
    lines += wrong[:SHOWN_DRAWS]
    if len(wrong) > SHOWN_DRAWS:
        lines.append(f"... and {len(wrong) - SHOWN_DRAWS} more draws wrong")
    ok = len(lines) == 1
    if ok:
        lines.append(f"{cls}.{method} matches the problem set's equation on every draw")
    return _result(ok, lines)


def check_velocity(student: StudentProcess, expect: dict) -> dict:
    """IiwaTaskSpaceVelocityPlan.CalcPositionCommand = q + J^+ V_des dt at random states."""
    return _check_law(student, "velocity", expect)


def check_impedance(student: StudentProcess, expect: dict) -> dict:
    """IiwaTaskSpaceImpedancePlan.CalcTorqueCommand = J^T F at random states."""
    return _check_law(student, "impedance", expect)


# Task 1 ------------------------------------------------------------------------------------


def _knot_problems(case: dict, q_knots: np.ndarray, kin: ArmKinematics) -> list[str]:
    """Each knot's pose against the path and the tolerances, with what a miss looks like."""
    g = default_door_geometry()
    a, b, offset = case["a"], case["b"], np.array(case["offset"])
    n, tol, bound = len(q_knots), case["position_tolerance"], case["theta_bound"]
    p_Q = np.array(case["p_L7Q"])

    def position(tau):
        return g.p_WQ_ref(a + (b - a) * tau) + offset

    problems = []
    for i, q in enumerate(q_knots):
        tau = i / (n - 1)
        X = kin.X_WL7(q)
        err = np.abs(X @ p_Q - position(tau)).max()
        R_ref = g.R_WL7_ref(a + (b - a) * tau)
        ang = (X.rotation().inverse() @ R_ref).ToAngleAxis().angle()
        if err > tol + IK_POSITION_SLACK:
            if np.abs(X @ p_L7Q - position(tau)).max() <= tol + IK_POSITION_SLACK:
                hint = "; with doorlab's grasp point it would be in: use the p_L7Q argument"
            elif np.abs(X @ p_Q - position(i / n)).max() <= tol + IK_POSITION_SLACK:
                hint = "; it is at tau = i / num_knot_points: use i / (num_knot_points - 1)"
            elif np.abs(X @ p_Q - g.p_WQ_ref(tau)).max() <= tol + IK_POSITION_SLACK:
                hint = "; it follows the problem set's arc: use the InterpolatePosition argument"
            elif err <= DEFAULT_POSITION_TOLERANCE + IK_POSITION_SLACK:
                hint = "; within the default 5 mm: pass position_tolerance to the constraint"
            else:
                hint = ""
            problems.append(
                f"knot {i}: Q is {err * 1e3:.3f} mm off (position_tolerance "
                f"{tol * 1e3:.3f} mm){hint}"
            )
        if ang > bound + IK_ANGLE_SLACK:
            hint = (
                "; within the default theta_bound: pass theta_bound to the constraint"
                if ang <= DEFAULT_THETA_BOUND + IK_ANGLE_SLACK
                else ""
            )
            problems.append(f"knot {i}: L7 is {ang:.4f} rad off (theta_bound {bound:.4f}){hint}")
    return problems


def check_ik(student: StudentProcess, expect: dict) -> dict:
    """InverseKinPointwise on a path, knot count, duration, grasp point, guess and tolerances
    drawn at random: FK of every knot within the tolerances, the trajectory through the
    knots over [0, duration], zero end velocities, no branch flips."""
    kin = ArmKinematics()
    e = expect
    case = e["case"]
    n, duration = case["num_knot_points"], case["duration"]
    lines = [
        f"grading seed {e['seed']}: num_knot_points {n}, duration {duration:.2f} s, arc tau from "
        f"{case['a']:.2f} to {case['b']:.2f} shifted by {_fmt(case['offset'])} m, p_L7Q "
        f"{_fmt(case['p_L7Q'])} m, position_tolerance {case['position_tolerance'] * 1e3:.2f} "
        f"mm, theta_bound {case['theta_bound']:.4f} rad"
    ]
    answer = student.call("ik", **case)
    try:
        qtraj, q_knots = trajectory_from_answer(answer, n, duration)
    except ProtocolError as e:
        return _result(False, lines + [str(e)])
    problems = _knot_problems(case, q_knots, kin)
    for i, q in enumerate(q_knots):
        t_i = i / (n - 1) * duration
        if np.abs(qtraj.value(t_i).ravel() - q).max() > 1e-6:
            problems.append(f"qtraj({t_i:.3f} s) is not q_knots[{i}]")
    steps = np.abs(np.diff(q_knots, axis=0)).max(axis=1)
    reference_steps = np.array(e["reference_steps"], dtype=float)
    allowed = IK_STEP_FACTOR * reference_steps + IK_STEP_SLACK
    if np.any(steps > allowed):
        k = int(np.argmax(steps - allowed))
        problems.append(
            f"the arm jumps {steps[k]:.2f} rad between knots {k} and {k + 1} (the reference "
            f"IK moves {reference_steps[k]:.2f} rad; start each IK from the previous knot)"
        )
    qdot = qtraj.derivative(1)
    ends = max(np.abs(qdot.value(0.0)).max(), np.abs(qdot.value(duration)).max())
    if ends > 1e-6:
        problems.append(f"qtraj must start and end at rest; |q_dot| = {ends:.3g} rad/s")
    if problems:
        shown = problems[:SHOWN_PROBLEMS]
        if len(problems) > SHOWN_PROBLEMS:
            shown.append(f"... and {len(problems) - SHOWN_PROBLEMS} more problems")
        return _result(False, lines + shown)
    lines.append(f"all {n} knots within the tolerances; qtraj through them, at rest at both ends")
    return _result(True, lines)


UNIT_CHECKS = {
    "ik": check_ik,
    "calc_p_Q": check_calc_p_Q,
    "calc_R_WL7_ref": check_calc_R_WL7_ref,
    "velocity": check_velocity,
    "impedance": check_impedance,
}
"""The unit tests by job name (``unit:<name>``): each takes the student's process and what
the test expects (:data:`doorlab.pset.grading.answer_key.EXPECTATIONS`, or the practice table's)."""
