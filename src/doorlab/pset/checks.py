"""The grader's unit tests, on the trusted side.

Each test draws its inputs here, from the grading seed (printed; derived from the
assignment's random seed and the submission's files: a regrade draws the same inputs), asks
the student's process (:class:`~doorlab.pset.student.StudentProcess`) for the student's
outputs, validates them (:mod:`doorlab.pset.channel`) and compares them with doorlab's
reference, computed here. Nothing the student's process holds can see or change the
expected answers. Every function returns a JSON-ready ``{"passed", "output"}``.

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
from doorlab.cell.station import make_controller_plant
from doorlab.constants import JOINT_POSITION_LIMITS, Q_HOME
from doorlab.control.ik_pointwise import pointwise_ik
from doorlab.control.laws import orientation_error
from doorlab.pset.channel import ProtocolError, as_array
from doorlab.pset.episodes import trajectory_from_answer
from doorlab.pset.station_api import ArmKinematics
from doorlab.pset.student import StudentProcess

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


def _rng(seed: int | None, job: str) -> tuple[np.random.Generator, int]:
    """The random draws of ``job`` from the grading seed (None: a fresh one), and that seed."""
    from doorlab.pset.assignment import SEED_BITS, job_seed

    grading = seed if seed is not None else int(np.random.SeedSequence().entropy % 2**SEED_BITS)
    return np.random.default_rng(job_seed(grading, job)), grading


def _fmt(x) -> str:
    return np.array2string(np.asarray(x, dtype=float), precision=5, suppress_small=True)


def _result(passed: bool, lines: list[str]) -> dict:
    return {"passed": bool(passed), "output": "\n".join(lines)}


def _values(answer: dict, count: int) -> list:
    values = answer.get("values")
    if not isinstance(values, list) or len(values) != count:
        raise ProtocolError(f"{count} answers expected, got something else")
    return values


def _draw_taus(rng: np.random.Generator) -> np.ndarray:
    """0, 1 and five values of tau off any grid (an IK's knots, tenths)."""
    return np.concatenate([[0.0, 1.0], rng.uniform(0.02, 0.98, 5)])


def check_calc_p_Q(student: StudentProcess, seed: int | None = None) -> dict:
    """calc_p_Q(tau) = arc(tau) - handle at random tau in [0, 1] (and 0 at tau = 0)."""
    g = default_door_geometry()
    rng, seed = _rng(seed, "unit:calc_p_Q")
    taus = _draw_taus(rng)
    values = _values(student.call("p_Q", taus=taus.tolist()), len(taus))
    lines = [f"grading seed {seed}; tolerance {POSITION_ATOL:g} m"]
    ok = True
    for tau, value in zip(taus, values, strict=True):
        expected = g.p_WQ_ref(tau) - g.p_W_handle
        got = as_array(value, (3,), "calc_p_Q", finite=False)
        if not bool(np.all(np.abs(got - expected) <= POSITION_ATOL)):
            ok = False
            hint = ""
            if np.all(np.abs(got - g.p_WQ_ref(tau)) <= POSITION_ATOL):
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


def check_calc_R_WL7_ref(student: StudentProcess, seed: int | None = None) -> dict:
    """calc_R_WL7_ref(tau) = RollPitchYaw(0, 3 pi/4, -sweep tau) at random tau."""
    g = default_door_geometry()
    rng, seed = _rng(seed, "unit:calc_R_WL7_ref")
    taus = _draw_taus(rng)
    values = _values(student.call("R_WL7_ref", taus=taus.tolist()), len(taus))
    lines = [f"grading seed {seed}; tolerance {ROTATION_ATOL:g} rad"]
    ok = True
    for tau, value in zip(taus, values, strict=True):
        expected = g.R_WL7_ref(tau)
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


def _random_q(rng: np.random.Generator) -> np.ndarray:
    """An arm configuration near the task's (away from the straight-arm singularity)."""
    q = Q_HOME + rng.uniform(-0.4, 0.4, 7)
    q[3] = rng.uniform(-2.0, -1.0)  # elbow well bent
    return np.clip(q, -0.9 * JOINT_POSITION_LIMITS, 0.9 * JOINT_POSITION_LIMITS)


def _control_period(rng: np.random.Generator) -> float:
    """A control period in [1, 20] ms, at least 1 ms away from the runner's 5 ms."""
    while True:
        dt = float(rng.uniform(0.001, 0.02))
        if abs(dt - SEED_CONTROL_PERIOD) > 0.001:
            return dt


def _law_case(rng: np.random.Generator, kin: ArmKinematics) -> dict:
    """A random state, a reference a few mm and degrees away, and the plan's inputs, each
    argument distinct from the others (q_cmd != q, v != 0, tau_ext != 0, t_plan off 0)."""
    q = _random_q(rng)
    X_WL7 = kin.X_WL7(q)
    p_WQ = X_WL7 @ p_L7Q
    duration = float(rng.uniform(3.0, 15.0))
    t_plan = float(rng.uniform(0.05, 0.95) * duration)
    tau = t_plan / duration
    p_WQ_0 = p_WQ + rng.uniform(-0.02, 0.02, 3)
    delta = rng.uniform(-0.002, 0.002, 3)  # e_xyz = p_WQ_0 + p_Q(tau) - p_WQ, a few mm
    p_Q_end = (p_WQ + delta - p_WQ_0) / tau
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    R_ref_end = X_WL7.rotation() @ RotationMatrix(RollPitchYaw(*(axis * rng.uniform(0.002, 0.01))))
    e_xyz = p_WQ_0 + p_Q_end * tau - p_WQ
    theta_n_W = orientation_error(X_WL7.rotation(), R_ref_end)
    theta_n_L7 = X_WL7.rotation().inverse() @ theta_n_W
    case = {
        "q": q,
        "duration": duration,
        "t_plan": t_plan,
        "p_WQ_0": p_WQ_0,
        "p_Q_end": p_Q_end,
        "R_ref_end": R_ref_end.matrix(),
        "F": np.concatenate([50.0 * theta_n_W, 100.0 * e_xyz]),
        "F_L7": np.concatenate([50.0 * theta_n_L7, 100.0 * e_xyz]),
        "J": kin.Jv_V_WL7q(q, p_L7Q),
    }
    for name in ("q_cmd", "v", "tau_ext", "dt"):
        case[name] = _redraw(rng, case, name)
    return case


def _redraw(rng: np.random.Generator, c: dict, name: str):
    """Another value of argument ``name`` for the draw ``c``."""
    if name == "q_cmd":
        return c["q"] + rng.choice([-1.0, 1.0], 7) * rng.uniform(0.02, 0.08, 7)
    if name == "v":
        return rng.uniform(-0.3, 0.3, 7)
    if name == "tau_ext":
        return rng.uniform(-2.0, 2.0, 7)
    return _control_period(rng)


def _request(c: dict, **changes) -> dict:
    args = {k: changes.get(k, c[k]) for k in ("q", "q_cmd", "v", "tau_ext", "t_plan", "dt")}
    return {
        "p_Q_end": c["p_Q_end"].tolist(),
        "R_ref_end": c["R_ref_end"].tolist(),
        "duration": c["duration"],
        "p_L7Q": p_L7Q.tolist(),
        "p_WQ_0": c["p_WQ_0"].tolist(),
        "args": [
            np.asarray(args["q"]).tolist(),
            np.asarray(args["q_cmd"]).tolist(),
            np.asarray(args["v"]).tolist(),
            np.asarray(args["tau_ext"]).tolist(),
            float(args["t_plan"]),
            float(args["dt"]),
        ],
    }


_ARGUMENT_NAMES = {
    "q_cmd": "q_cmd (the last position command)",
    "v": "v_iiwa (the measured joint velocities)",
    "tau_ext": "tau_iiwa (the measured external torques)",
    "dt": "control_period",
}


def _expected(kind: str, c: dict) -> tuple[list[np.ndarray], list[tuple[str, np.ndarray]]]:
    """The accepted answers, and the answers of common mistakes (what each misuses)."""
    J_pinv = np.linalg.pinv(c["J"])
    if kind == "velocity":
        qdot = J_pinv @ c["F"]  # F holds V_des here: same gains, 1/s
        accepted = [c["q"] + qdot * c["dt"]]
        accepted.append(c["q"] + np.clip(qdot, -VELOCITY_CLIP, VELOCITY_CLIP) * c["dt"])
        mistakes = [
            (
                "q_cmd + J^+ V_des dt: q_ref must start from the measured q_iiwa, not from "
                "q_cmd (the last position command)",
                c["q_cmd"] + qdot * c["dt"],
            ),
            (
                f"a control period of {SEED_CONTROL_PERIOD} s: use the control_period argument "
                f"({c['dt']:.4f} s here)",
                c["q"] + qdot * SEED_CONTROL_PERIOD,
            ),
            ("q - J^+ V_des dt: the sign of V_des is flipped", c["q"] - qdot * c["dt"]),
            (
                "theta n expressed in L7: V_des's angular part must be expressed in W "
                "(self.R_WL7 @ axis)",
                c["q"] + J_pinv @ c["F_L7"] * c["dt"],
            ),
        ]
        return accepted, mistakes
    tau_ff = c["J"].T @ c["F"]
    accepted = [tau_ff, np.clip(tau_ff, -TORQUE_CLIP, TORQUE_CLIP)]
    mistakes = [
        ("-J^T F: the sign of F is flipped", -tau_ff),
        (
            "theta n expressed in L7: F's moment must be expressed in W (self.R_WL7 @ axis)",
            c["J"].T @ c["F_L7"],
        ),
        ("J^+ F: the impedance plan maps F through J's transpose", J_pinv @ c["F"]),
    ]
    return accepted, mistakes


def _close(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.all(np.abs(a - b) <= COMMAND_ATOL))


def _check_law(student: StudentProcess, kind: str, seed: int | None) -> dict:
    method = "CalcPositionCommand" if kind == "velocity" else "CalcTorqueCommand"
    cls = "IiwaTaskSpaceVelocityPlan" if kind == "velocity" else "IiwaTaskSpaceImpedancePlan"
    unit = "rad" if kind == "velocity" else "N m"
    ignored = ["q_cmd", "v", "tau_ext"] + ([] if kind == "velocity" else ["dt"])
    kin = ArmKinematics()
    rng, seed = _rng(seed, f"unit:{kind}")
    cases = [_law_case(rng, kin) for _ in range(UNIT_DRAWS)]
    # For each draw: its inputs, then the same with one argument the law must not read
    # drawn anew (one request: one round trip for the whole test).
    requests, base, probes = [], [], []
    for i, c in enumerate(cases):
        base.append(len(requests))
        requests.append(_request(c))
        for name in ignored:
            probes.append((i, name, len(requests)))
            requests.append(_request(c, **{name: _redraw(rng, c, name)}))
    answers = _values(student.call("law", kind=kind, cases=requests), len(requests))
    got = [as_array(a, (7,), method, finite=False) for a in answers]
    lines = [
        f"grading seed {seed}; {UNIT_DRAWS} random arm states (q_cmd != q_iiwa, v_iiwa and "
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
    for i, c in enumerate(cases):
        accepted, mistakes = _expected(kind, c)
        answer = got[base[i]]
        if not any(_close(answer, x) for x in accepted):
            wrong.append(
                f"draw {i} (t_plan = {c['t_plan']:.3f} s, control_period = {c['dt']:.4f} s): "
                f"expected {_fmt(accepted[0])} {unit}, got {_fmt(answer)}"
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


def check_velocity(student: StudentProcess, seed: int | None = None) -> dict:
    """IiwaTaskSpaceVelocityPlan.CalcPositionCommand = q + J^+ V_des dt at random states."""
    return _check_law(student, "velocity", seed=seed)


def check_impedance(student: StudentProcess, seed: int | None = None) -> dict:
    """IiwaTaskSpaceImpedancePlan.CalcTorqueCommand = J^T F at random states."""
    return _check_law(student, "impedance", seed=seed)


# Task 1 ------------------------------------------------------------------------------------


def _ik_case(rng: np.random.Generator) -> dict:
    """A path (a shifted piece of the arc), a knot count, a duration, tolerances below the
    function's defaults, a grasp point and an initial guess off doorlab's."""
    a = float(rng.uniform(0.0, 0.7))
    return {
        "num_knot_points": int(rng.integers(3, 8)),
        "duration": float(rng.uniform(3.0, 8.0)),
        "a": a,
        "b": float(rng.uniform(a + 0.3, 1.0)),
        "offset": [rng.uniform(-0.04, 0.0), rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03)],
        "position_tolerance": float(rng.uniform(0.0005, 0.002)),
        "theta_bound": float(rng.uniform(0.004, 0.01)),
        # 5-10 mm off doorlab's grasp point on every axis: an IK that aims that point
        # instead misses the drawn one by >= 5 mm on some world axis, more than any
        # tolerance drawn (<= 2 mm) plus its own error in the box (<= 2 mm).
        "p_L7Q": (p_L7Q + rng.choice([-1.0, 1.0], 3) * rng.uniform(0.005, 0.01, 3)).tolist(),
        "q_initial_guess": (Q_HOME + rng.uniform(-0.05, 0.05, 7)).tolist(),
    }


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


def check_ik(student: StudentProcess, seed: int | None = None) -> dict:
    """InverseKinPointwise on a path, knot count, duration, grasp point, guess and tolerances
    drawn at random: FK of every knot within the tolerances, the trajectory through the
    knots over [0, duration], zero end velocities, no branch flips."""
    g = default_door_geometry()
    kin = ArmKinematics()
    rng, seed = _rng(seed, "unit:ik")
    case = _ik_case(rng)
    n, duration = case["num_knot_points"], case["duration"]
    lines = [
        f"grading seed {seed}: num_knot_points {n}, duration {duration:.2f} s, arc tau from "
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
    a, b, offset = case["a"], case["b"], np.array(case["offset"])
    reference = pointwise_ik(
        make_controller_plant(),
        lambda tau: g.p_WQ_ref(a + (b - a) * tau) + offset,
        lambda tau: g.R_WL7_ref(a + (b - a) * tau),
        duration=duration,
        num_knots=n,
        q_guess=np.array(case["q_initial_guess"]),
        position_tolerance=case["position_tolerance"],
        theta_bound=case["theta_bound"],
    )
    steps = np.abs(np.diff(q_knots, axis=0)).max(axis=1)
    reference_steps = np.abs(np.diff(reference.q_knots, axis=0)).max(axis=1)
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
"""The unit tests by job name (``unit:<name>``)."""
