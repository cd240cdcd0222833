"""The grader's tests, run one per process by :mod:`doorlab.pset.worker`.

Unit tests compare each student function with doorlab's reference on random inputs drawn at
grading time (the seed is printed, so a result can be reproduced); episode jobs simulate the
student's plans (or doorlab's reference controllers) and return measured figures, which
:mod:`doorlab.pset.grader` compares. Every function returns a JSON-ready dict.
"""

from __future__ import annotations

import importlib
import math
import sys
from pathlib import Path

import numpy as np
from pydrake.math import RollPitchYaw, RotationMatrix
from pydrake.trajectories import PiecewisePolynomial

from doorlab.config import Scenario
from doorlab.constants import JOINT_POSITION_LIMITS, Q_HOME
from doorlab.frames import p_L7Q
from doorlab.geometry import default_door_geometry
from doorlab.ik import pointwise_ik
from doorlab.laws import orientation_error
from doorlab.pset.seedapi import ArmKinematics
from doorlab.station import make_controller_plant

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
rotation), which solvers meet to ~1e-6; near theta_bound >= 0.005 rad that is
~1e-6 / sin(theta_bound) <= 2e-4 rad of angle."""
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


def _import(folder: Path, module: str):
    if str(folder) not in sys.path:
        sys.path.insert(0, str(folder))
    return importlib.import_module(module)


def _rng() -> tuple[np.random.Generator, int]:
    seed = int(np.random.SeedSequence().entropy % (2**32))
    return np.random.default_rng(seed), seed


def _fmt(x) -> str:
    return np.array2string(np.asarray(x, dtype=float), precision=5, suppress_small=True)


def _result(passed: bool, lines: list[str]) -> dict:
    return {"passed": bool(passed), "output": "\n".join(lines)}


def check_calc_p_Q(folder: Path) -> dict:
    """calc_p_Q(tau) = arc(tau) - handle at random tau in [0, 1] (and 0 at tau = 0)."""
    old = _import(folder, "open_left_door")
    g = default_door_geometry()
    rng, seed = _rng()
    taus = np.concatenate([[0.0, 1.0], rng.uniform(0.0, 1.0, 5)])
    lines = [f"random seed {seed}; tolerance {POSITION_ATOL:g} m"]
    ok = True
    for tau in taus:
        expected = g.p_WQ_ref(tau) - g.p_W_handle
        got = np.asarray(old.calc_p_Q(float(tau)), dtype=float).reshape(-1)
        good = got.shape == (3,) and bool(np.all(np.abs(got - expected) <= POSITION_ATOL))
        ok &= good
        if not good:
            lines.append(f"tau = {tau:.4f}: expected {_fmt(expected)} m, got {_fmt(got)}")
    if ok:
        lines.append(f"calc_p_Q matches the arc at {len(taus)} values of tau")
    return _result(ok, lines)


def check_calc_R_WL7_ref(folder: Path) -> dict:
    """calc_R_WL7_ref(tau) = RollPitchYaw(0, 3 pi/4, -sweep tau) at random tau."""
    old = _import(folder, "open_left_door")
    g = default_door_geometry()
    rng, seed = _rng()
    taus = np.concatenate([[0.0, 1.0], rng.uniform(0.0, 1.0, 5)])
    lines = [f"random seed {seed}; tolerance {ROTATION_ATOL:g} rad"]
    ok = True
    for tau in taus:
        expected = g.R_WL7_ref(tau)
        got = old.calc_R_WL7_ref(float(tau))
        if not isinstance(got, RotationMatrix):
            lines.append(f"tau = {tau:.4f}: expected a RotationMatrix, got {type(got).__name__}")
            ok = False
            continue
        angle = (got.inverse() @ expected).ToAngleAxis().angle()
        if not angle <= ROTATION_ATOL:
            ok = False
            rpy = RollPitchYaw(got).vector()
            lines.append(
                f"tau = {tau:.4f}: expected roll-pitch-yaw "
                f"{_fmt(RollPitchYaw(expected).vector())} rad, got {_fmt(rpy)} "
                f"({angle:.4g} rad apart)"
            )
    if ok:
        lines.append(f"calc_R_WL7_ref matches the reference at {len(taus)} values of tau")
    return _result(ok, lines)


def _random_q(rng: np.random.Generator) -> np.ndarray:
    """An arm configuration near the task's (away from the straight-arm singularity)."""
    q = Q_HOME + rng.uniform(-0.4, 0.4, 7)
    q[3] = rng.uniform(-2.0, -1.0)  # elbow well bent
    return np.clip(q, -0.9 * JOINT_POSITION_LIMITS, 0.9 * JOINT_POSITION_LIMITS)


def _law_case(rng: np.random.Generator, kin: ArmKinematics):
    """A random state, a random reference a few mm and degrees away, and the plan inputs."""
    q = _random_q(rng)
    X_WL7 = kin.X_WL7(q)
    p_WQ = X_WL7 @ p_L7Q
    duration = float(rng.uniform(3.0, 15.0))
    t_plan = float(rng.uniform(0.0, 0.95 * duration))
    tau = t_plan / duration
    p_WQ_0 = p_WQ + rng.uniform(-0.02, 0.02, 3)
    delta = rng.uniform(-0.002, 0.002, 3)  # e_xyz = p_WQ_0 + p_Q(tau) - p_WQ, a few mm
    p_Q_end = (p_WQ + delta - p_WQ_0) / tau if tau > 1e-6 else np.zeros(3)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    R_ref_end = X_WL7.rotation() @ RotationMatrix(RollPitchYaw(*(axis * rng.uniform(0.002, 0.01))))

    def calc_p_Q(s):
        return p_Q_end * s

    def calc_R_WL7_ref(s):
        return R_ref_end

    e_xyz = p_WQ_0 + calc_p_Q(tau) - p_WQ
    theta_n_W = orientation_error(X_WL7.rotation(), R_ref_end)
    J = kin.Jv_V_WL7q(q, p_L7Q)
    return {
        "q": q,
        "v": rng.uniform(-0.3, 0.3, 7),
        "tau_ext": rng.uniform(-2.0, 2.0, 7),
        "duration": duration,
        "t_plan": t_plan,
        "dt": float(rng.choice([0.002, 0.005, 0.01])),
        "p_WQ_0": p_WQ_0,
        "calc_p_Q": calc_p_Q,
        "calc_R_WL7_ref": calc_R_WL7_ref,
        "F": np.concatenate([50.0 * theta_n_W, 100.0 * e_xyz]),
        "J": J,
    }


def _check_law(folder: Path, kind: str) -> dict:
    plans = _import(folder, "manip_station_sim.robot_plans")
    cls = {
        "velocity": plans.IiwaTaskSpaceVelocityPlan,
        "impedance": plans.IiwaTaskSpaceImpedancePlan,
    }[kind]
    method = "CalcPositionCommand" if kind == "velocity" else "CalcTorqueCommand"
    kin = ArmKinematics()
    rng, seed = _rng()
    lines = [f"random seed {seed}; {UNIT_DRAWS} random arm states; tolerance {COMMAND_ATOL:g}"]
    ok = True
    for i in range(UNIT_DRAWS):
        c = _law_case(rng, kin)
        plan = cls(
            calc_p_Q=c["calc_p_Q"],
            calc_R_WL7_ref=c["calc_R_WL7_ref"],
            duration=c["duration"],
            p_L7Q=p_L7Q,
        )
        plan.UpdatePwq0(c["p_WQ_0"])
        args = (c["q"], c["q"].copy(), c["v"], c["tau_ext"], c["t_plan"], c["dt"])
        got = np.asarray(getattr(plan, method)(*args), dtype=float).reshape(-1)
        if kind == "velocity":
            qdot = np.linalg.pinv(c["J"]) @ c["F"]  # F holds V_des here: same gains, 1/s
            candidates = [c["q"] + qdot * c["dt"]]
            candidates.append(c["q"] + np.clip(qdot, -VELOCITY_CLIP, VELOCITY_CLIP) * c["dt"])
            unit = "rad"
        else:
            tau_ff = c["J"].T @ c["F"]
            candidates = [tau_ff, np.clip(tau_ff, -TORQUE_CLIP, TORQUE_CLIP)]
            unit = "N m"
        good = got.shape == (7,) and any(
            bool(np.all(np.abs(got - x) <= COMMAND_ATOL)) for x in candidates
        )
        if not good:
            ok = False
            lines.append(
                f"draw {i} (t_plan = {c['t_plan']:.3f} s, control_period = {c['dt']} s): "
                f"expected {_fmt(candidates[0])} {unit}, got {_fmt(got)}"
            )
    if ok:
        lines.append(f"{cls.__name__}.{method} matches the seed's equation on every draw")
    return _result(ok, lines)


def check_velocity(folder: Path) -> dict:
    """IiwaTaskSpaceVelocityPlan.CalcPositionCommand = q + J^+ V_des dt at random states."""
    return _check_law(folder, "velocity")


def check_impedance(folder: Path) -> dict:
    """IiwaTaskSpaceImpedancePlan.CalcTorqueCommand = J^T F at random states."""
    return _check_law(folder, "impedance")


def check_ik(folder: Path) -> dict:
    """InverseKinPointwise on a path, knot count, duration and tolerances drawn at random:
    FK of every knot within the tolerances, the trajectory through the knots, zero end
    velocities, no branch flips."""
    ik_utils = _import(folder, "ik_utils")
    g = default_door_geometry()
    kin = ArmKinematics()
    rng, seed = _rng()
    n = int(rng.integers(3, 8))
    duration = float(rng.uniform(3.0, 12.0))
    a = float(rng.uniform(0.0, 0.7))
    b = float(rng.uniform(a + 0.3, 1.0))
    offset = np.array([rng.uniform(-0.04, 0.0), rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03)])
    tol = float(rng.uniform(0.001, 0.003))
    theta_bound = float(rng.uniform(0.005, 0.02))

    def position(tau):
        return g.p_WQ_ref(a + (b - a) * tau) + offset

    def orientation(tau):
        return g.R_WL7_ref(a + (b - a) * tau)

    lines = [
        f"random seed {seed}: {n} knots, duration {duration:.2f} s, arc tau from {a:.2f} to "
        f"{b:.2f} shifted by {_fmt(offset)} m, position_tolerance {tol * 1e3:.2f} mm, "
        f"theta_bound {theta_bound:.4f} rad"
    ]
    qtraj, q_knots = ik_utils.InverseKinPointwise(
        InterpolatePosition=position,
        InterpolateOrientation=orientation,
        p_L7Q=p_L7Q,
        duration=duration,
        num_knot_points=n,
        q_initial_guess=Q_HOME,
        position_tolerance=tol,
        theta_bound=theta_bound,
    )
    q_knots = np.asarray(q_knots, dtype=float)
    problems = []
    if not isinstance(qtraj, PiecewisePolynomial) or qtraj.rows() != 7:
        problems.append(f"qtraj must be a 7-row PiecewisePolynomial, got {type(qtraj).__name__}")
    if q_knots.shape != (n, 7):
        problems.append(f"q_knots must have shape ({n}, 7), got {q_knots.shape}")
    if problems:
        return _result(False, lines + problems)
    if abs(qtraj.start_time()) > 1e-9 or abs(qtraj.end_time() - duration) > 1e-9:
        problems.append(
            f"qtraj must span [0, {duration:.3f}] s, spans "
            f"[{qtraj.start_time():.3f}, {qtraj.end_time():.3f}] s"
        )
    for i, q in enumerate(q_knots):
        tau = i / (n - 1)
        X = kin.X_WL7(q)
        err = np.abs(X @ p_L7Q - position(tau)).max()
        ang = (X.rotation().inverse() @ orientation(tau)).ToAngleAxis().angle()
        if err > tol + IK_POSITION_SLACK:
            problems.append(f"knot {i}: Q is {err * 1e3:.3f} mm off (tolerance {tol * 1e3:.3f})")
        if ang > theta_bound + IK_ANGLE_SLACK:
            problems.append(f"knot {i}: L7 is {ang:.4f} rad off (theta_bound {theta_bound:.4f})")
        t_i = tau * duration
        if np.abs(qtraj.value(t_i).ravel() - q).max() > 1e-6:
            problems.append(f"qtraj({t_i:.3f} s) is not q_knots[{i}]")
    reference = pointwise_ik(
        make_controller_plant(),
        position,
        orientation,
        duration=duration,
        num_knots=n,
        q_guess=Q_HOME,
        position_tolerance=tol,
        theta_bound=theta_bound,
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
        return _result(False, lines + problems)
    lines.append(f"all {n} knots within the tolerances; qtraj through them, at rest at both ends")
    return _result(True, lines)


# Episodes --------------------------------------------------------------------------------

DOOR_OPEN = math.pi / 2 - 0.001
"""The seed's open-door hinge angle [rad]."""
DOOR_CLOSED = 0.001
"""The seed's closed-door hinge angle [rad]."""


def _episode_figures(result, scenario: Scenario) -> dict:
    from doorlab.metrics import compute_metrics, compute_tracking

    g = default_door_geometry()
    m = compute_metrics(result, scenario, g)
    tracking = compute_tracking(result, g)
    d = g.p_W_hinge - tracking.p_WQ[-1]
    left = result.door_angles[:, 0]
    i0, i1 = (int(np.argmin(np.abs(result.t - t))) for t in result.arc_window)
    return {
        "status": m.status,
        "max_radial_error_m": m.max_radial_error_m,
        "max_orientation_error_rad": m.max_orientation_error_rad,
        "q_end_angle_rad": math.atan2(d[0], d[1]),
        "door_opening_rad": m.door_opening_rad,
        "door_opening_at_arc_end_rad": float(left[i0] - left[i1]),
        "handle_held": m.handle_held,
        "wall_time_s": m.wall_time_s,
    }


def reference_episode(controller: str) -> dict:
    """doorlab's reference solution: IK 10 knots and velocity with the doors open, impedance
    with them closed."""
    from doorlab.controllers import run_controller

    doors = "closed" if controller == "impedance" else "open"
    scenario = Scenario(controller=controller, doors=doors)
    result, _ = run_controller(scenario)
    return _episode_figures(result, scenario)


def student_episode(folder: Path, controller: str) -> dict:
    """The seed's task cell for one controller, with the student's functions."""
    old = _import(folder, "open_left_door")
    ik_utils = _import(folder, "ik_utils")
    plans = _import(folder, "manip_station_sim.robot_plans")
    sim_module = _import(folder, "manip_station_sim.manipulation_station_simulator")
    duration = 10.0
    if controller == "ik":
        qtraj, q_knots = ik_utils.InverseKinPointwise(
            InterpolatePosition=old.InterpolateArc,
            InterpolateOrientation=old.InterpolateYawAngle,
            p_L7Q=old.p_L7Q,
            duration=duration,
            num_knot_points=10,
            q_initial_guess=old.q_home,
            position_tolerance=0.001,
        )
        q_start = np.asarray(q_knots)[0]
        arc = plans.JointSpacePlan(qtraj)
    else:
        q_start = ik_utils.SolveOneShotIk(
            p_WQ_ref=old.p_WC_handle,
            R_WL7_ref=RollPitchYaw(0, np.pi / 4 * 3, 0).ToRotationMatrix(),
            p_L7Q=old.p_L7Q,
            q_initial_guess=old.q_home,
            position_tolerance=0.0005,
        )
        cls = (
            plans.IiwaTaskSpaceVelocityPlan
            if controller == "velocity"
            else (plans.IiwaTaskSpaceImpedancePlan)
        )
        make = lambda: cls(  # noqa: E731
            calc_p_Q=old.calc_p_Q,
            calc_R_WL7_ref=old.calc_R_WL7_ref,
            duration=duration,
            p_L7Q=old.p_L7Q,
        )
        # Fail fast (before 11 s of simulation) if the student's code cannot run at all.
        probe = make()
        args = (q_start, q_start, np.zeros(7), np.zeros(7), 0.5, 0.005)
        probe.CalcPositionCommand(*args)
        probe.CalcTorqueCommand(*args)
        arc = make()
    hold = PiecewisePolynomial.ZeroOrderHold([0, 1], np.column_stack([q_start, q_start]))
    angle = DOOR_CLOSED if controller == "impedance" else DOOR_OPEN
    sim = sim_module.ManipulationStationSimulator()
    sim.RunSimulation(
        old.q_home,
        np.array([-angle, angle]),
        [plans.JointSpacePlan(hold), arc],
        [0.005, 0.005],
        extra_time=2.0,
        real_time_rate=0.0,
        is_visualizing=False,
    )
    scenario = sim._run.last_scenario
    scenario.controller = controller
    scenario.doors = "closed" if controller == "impedance" else "open"
    return _episode_figures(sim.result, scenario)
