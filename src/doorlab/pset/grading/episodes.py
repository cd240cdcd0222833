"""The grader's episodes, simulated on the trusted side.

A student episode is the problem set's task cell for one controller, but the simulation runs
here: for task 1 the student's process only returns its IK (knots and trajectory, as
numbers); for tasks 2 and 3 the student's plan lives in the student's process and is asked
for its command at every control tick (:class:`RemotePlan`, one round trip of
:mod:`doorlab.pset.isolation.channel` per tick), so the logs and the figures the verdict rests on
come from this process only. Reference episodes run doorlab's own controllers
(:mod:`doorlab.pset.grading.answer_key`, with everything else that computes an answer: this module
holds none).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from pydrake.math import RollPitchYaw
from pydrake.polynomial import Polynomial
from pydrake.trajectories import PiecewisePolynomial

from doorlab.cell.frames import p_L7Q
from doorlab.cell.geometry import default_door_geometry
from doorlab.config import Scenario
from doorlab.constants import NUM_JOINTS, Q_HOME
from doorlab.pset.isolation.channel import MAX_DEGREE, MAX_SEGMENTS, ProtocolError, as_array
from doorlab.pset.isolation.handle import StudentProcess

DOOR_OPEN = math.pi / 2 - 0.001
"""The problem set's open-door hinge angle [rad]."""
DOOR_CLOSED = 0.001
"""The problem set's closed-door hinge angle [rad]."""
ARC_DURATION = 10.0
"""The problem set's arc plans' duration [s]."""
GRIPPER_WIDTH = 0.005
"""The problem set's finger setpoint while the plans run [m]."""
SERIES_PERIOD_S = 0.05
"""Sampling of the episode series kept for the feedback figures [s] (every 5th log sample:
201 values over the 10 s arc; a plot needs no more, and each results file stays small)."""
SERIES_DECIMALS = 3
"""Decimals kept of each series value (mm and deg: 1 um and 0.001 deg, below any plot's
resolution)."""
HELPER_KNOTS = 1001
"""Values of tau at which the reference calc_p_Q and calc_R_WL7_ref are sent to the
student's process, which interpolates between them
(:func:`doorlab.pset.grading.answer_key.reference_helper_table`)."""


def trajectory_from_answer(
    answer: dict, num_knots: int, duration: float | None = None
) -> tuple[PiecewisePolynomial, np.ndarray]:
    """The student's (qtraj, q_knots) rebuilt from its numbers, checked.

    Raises:
        ProtocolError: Wrong shapes, non-finite values, breaks not increasing, or (with
            ``duration``) a span other than [0, duration]; the message says which.
    """
    q_knots = answer.get("q_knots")
    shape = np.shape(q_knots) if isinstance(q_knots, list) else "?"
    try:
        knots = as_array(q_knots, (num_knots, NUM_JOINTS), "q_knots")
    except ProtocolError as e:
        if "shape" in str(e):
            raise ProtocolError(
                f"q_knots must have shape ({num_knots}, {NUM_JOINTS}) (num_knot_points = "
                f"{num_knots}), got {shape}"
            ) from None
        raise
    traj = answer.get("qtraj")
    if not isinstance(traj, dict):
        raise ProtocolError("qtraj is missing")
    breaks = traj.get("breaks")
    if not isinstance(breaks, list) or not 2 <= len(breaks) <= MAX_SEGMENTS + 1:
        raise ProtocolError("qtraj: not a trajectory with 1 to 1000 segments")
    t = as_array(breaks, (len(breaks),), "qtraj's breaks")
    if np.any(np.diff(t) <= 0):
        raise ProtocolError("qtraj's breaks are not increasing")
    coefficients = traj.get("coefficients")
    if not isinstance(coefficients, list) or len(coefficients) != len(t) - 1:
        raise ProtocolError("qtraj: one coefficient table per segment expected")
    matrices = []
    for i, segment in enumerate(coefficients):
        rows = segment[0] if isinstance(segment, list) and segment else []
        order = len(rows) if isinstance(rows, list) else 0
        if not 1 <= order <= MAX_DEGREE + 1:
            raise ProtocolError(f"qtraj's segment {i}: degree outside 0..{MAX_DEGREE}")
        c = as_array(segment, (NUM_JOINTS, order), f"qtraj's segment {i}")
        m = np.empty((NUM_JOINTS, 1), dtype=object)
        for r in range(NUM_JOINTS):
            m[r, 0] = Polynomial(c[r])
        matrices.append(m)
    qtraj = PiecewisePolynomial(matrices, t.tolist())
    if duration is not None and (abs(t[0]) > 1e-9 or abs(t[-1] - duration) > 1e-9):
        raise ProtocolError(
            f"qtraj must span [0, {duration:.3f}] s (duration = {duration:.3f}), spans "
            f"[{t[0]:.3f}, {t[-1]:.3f}] s"
        )
    return qtraj, knots


class RemotePlan:
    """A doorlab plan whose commands come from the student's plan, in the student's process,
    one round trip per control tick.

    ``q_cmd`` (the notebook's "last position command") is the q_ref sent at the previous tick
    (the measured q at the first), as in
    :class:`doorlab.pset.handout.station_api.ProblemSetPlanAdapter`. Every answer is checked: 14
    finite values.
    """

    def __init__(self, student: StudentProcess, duration: float, control_period: float, name: str):
        self.student = student
        self.name = name
        self.duration = duration
        self.control_period = control_period
        self._q_cmd: np.ndarray | None = None
        self.ticks = 0

    def command(self, t: float, state):
        """The student's q_ref (7,) [rad] and tau_ff (7,) [N m] at t [s]."""
        from doorlab.control.plan_base import Command
        from doorlab.pset.handout.station_api import StudentCodeError

        q_cmd = state.q if self._q_cmd is None else self._q_cmd
        request = np.concatenate(
            [state.q, q_cmd, state.v, state.tau_external, [t, self.control_period]]
        )
        answer = self.student.tick(request)
        self.ticks += 1
        for what, part in (("CalcPositionCommand", answer[:7]), ("CalcTorqueCommand", answer[7:])):
            if not np.all(np.isfinite(part)):
                raise StudentCodeError(
                    f"{what} returned a non-finite value {part.tolist()} (t_plan = {t:.3f} s)"
                )
        self._q_cmd = answer[:7].copy()
        return Command(answer[:7].copy(), answer[7:].copy())


def episode_series(result, tracking) -> dict:
    """The arc window's series, compact (what the feedback figures draw): time from the
    arc's start [s], the door's opening from its angle there [deg], Q's signed radial error
    [mm] and L7's orientation error [deg], every :data:`SERIES_PERIOD_S`."""
    step = max(1, round(SERIES_PERIOD_S / float(np.median(np.diff(result.t)))))
    t0 = result.arc_window[0]
    i0 = int(np.argmin(np.abs(result.t - t0)))
    left = np.interp(tracking.t, result.t, result.door_angles[:, 0])

    def kept(values: np.ndarray) -> list[float]:
        return np.round(values[::step], SERIES_DECIMALS).tolist()

    return {
        "t_s": kept(tracking.t - t0),
        "door_opening_deg": kept(np.degrees(result.door_angles[i0, 0] - left)),
        "radial_error_mm": kept(tracking.radial_error * 1e3),
        "orientation_error_deg": kept(np.degrees(tracking.orientation_error)),
    }


def episode_figures(result, scenario: Scenario) -> dict:
    """The figures a verdict rests on, of one simulated episode (the student's or the
    reference's)."""
    from doorlab.episode.metrics import compute_metrics, compute_tracking

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
        "theta0_rad": g.theta0,
        "door_opening_rad": m.door_opening_rad,
        "door_opening_at_arc_end_rad": float(left[i0] - left[i1]),
        "handle_held": m.handle_held,
        "wall_time_s": m.wall_time_s,
        "series": episode_series(result, tracking),
    }


def grasp_configuration() -> np.ndarray:
    """Where the task cell's plans 2 and 3 start: the 2019 notebook's ``SolveOneShotIk`` at the
    handle, L7 pitched by 3 pi / 4, from q_home (7,) [rad] (computed here, not by the
    student's copy; once per process, a fresh copy each call)."""
    return _grasp_configuration().copy()


@functools.cache
def _grasp_configuration() -> np.ndarray:
    from doorlab.cell.station import make_controller_plant
    from doorlab.control.ik import solve_ik

    return solve_ik(
        make_controller_plant(),
        default_door_geometry().p_W_handle,
        RollPitchYaw(0, np.pi / 4 * 3, 0).ToRotationMatrix(),
        Q_HOME,
        position_tolerance=0.0005,
        theta_bound=0.005,
    )


def student_episode(
    student: StudentProcess,
    controller: str,
    *,
    helpers: str = "reference",
    table: dict | None = None,
) -> dict:
    """The problem set's task cell for one controller with the student's functions, simulated here:
    hold 2 s, move 7 s to the start, hold 1 (+1) s, the arc plan (10 + 1 s), 2 s more.

    ``helpers`` (the velocity and impedance plans): ``reference`` runs the plan on doorlab's
    calc_p_Q and calc_R_WL7_ref (:func:`reference_helper_table`), so the episode grades the
    plan alone; ``student`` on the student's. ``table``: the reference helpers' table
    (:func:`doorlab.pset.grading.answer_key.reference_helper_table`, or the handout's practice
    table's), needed with ``reference``."""
    from dataclasses import replace

    from doorlab.control.plan_base import JointSpacePlan
    from doorlab.episode.simulation import run_episode
    from doorlab.pset.handout.station_api import problem_set_scenario

    doors = "closed" if controller == "impedance" else "open"
    angle = DOOR_CLOSED if controller == "impedance" else DOOR_OPEN
    scenario = problem_set_scenario(
        Scenario(), [-angle, angle], extra_time=2.0, gripper_setpoint_initial=0.025
    )
    period = scenario.timeline.control_period
    if controller == "ik":
        answer = student.call(
            "ik",
            a=0.0,
            b=1.0,
            offset=[0.0, 0.0, 0.0],
            p_L7Q=p_L7Q.tolist(),
            duration=ARC_DURATION,
            num_knot_points=10,
            q_initial_guess=Q_HOME.tolist(),
            position_tolerance=0.001,
            theta_bound=None,
        )
        try:
            qtraj, q_knots = trajectory_from_answer(answer, 10)
        except ProtocolError as e:
            from doorlab.pset.isolation.handle import StudentFailure

            raise StudentFailure(f"InverseKinPointwise: {e}") from None
        student.close()  # the rest is doorlab's
        q_start = q_knots[0]
        arc = JointSpacePlan(qtraj, name="student_ik")
    else:
        q_start = grasp_configuration()
        if helpers != "reference":
            table = None
        elif table is None:
            raise ValueError("an episode on the reference helpers needs their table")
        student.call(
            "plan",
            kind=controller,
            duration=ARC_DURATION,
            p_L7Q=p_L7Q.tolist(),
            q_start=q_start.tolist(),
            reference_helpers=table,
        )
        arc = RemotePlan(student, ARC_DURATION, period, name=f"student_{controller}")
    hold = JointSpacePlan(
        PiecewisePolynomial.ZeroOrderHold([0, 1], np.column_stack([q_start, q_start])),
        name="hold",
    )
    result = run_episode(
        scenario,
        [hold, arc],
        [GRIPPER_WIDTH, GRIPPER_WIDTH],
        q_start=q_start,
        q_initial=Q_HOME,
    )
    return episode_figures(result, replace(scenario, controller=controller, doors=doors))
