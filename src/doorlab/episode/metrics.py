"""Tracking and door metrics of an episode, computed from its logs (no simulation re-run).

Tracking errors are taken over the arc window (the 10 s of the arc in the episode timeline):

- radial error of Q: horizontal distance from the hinge axis minus r_handle [m] (the problem set's
  ``CalcRadialTrackingError``), signed, positive outside the arc;
- orientation error of L7: the angle of R_WL7^T R_WL7_ref(tau) [rad], tau = (t - t0) / T;

both from the MEASURED joint positions (what the robot did) and, as the problem set's plots did,
from the COMMANDED ones (q_ref). Forward kinematics uses the controllers' model of the arm.

Door metrics (left door, opening measured from its angle at the arc's start, positive):

- at the arc's END, t = arc_window[1] (the primary figure: the problem set's arc takes 10 s, and a
  plan that trails it may still creep open in the hold afterwards);
- at the episode's end;
- the largest LAG of the door behind the arc plan during the arc, max over the arc window of
  (sweep * tau - opening(t)) [rad].
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

import numpy as np

from doorlab.cell.frames import L7_FRAME, p_L7Q
from doorlab.cell.geometry import DoorGeometry
from doorlab.cell.station import STIFFNESS_LOOPS, loop_gains, make_controller_plant
from doorlab.config import Scenario
from doorlab.constants import JOINT_SPEED_LIMITS, JOINT_TORQUE_LIMITS
from doorlab.episode.plugins import display_name
from doorlab.episode.result import EpisodeResult
from doorlab.errors import ConfigError

HANDLE_CAPTURE_RADIUS = 0.02
"""Q is "at the handle" while its horizontal distance to the handle axis is below this [m]:
the pads are 16 mm wide and 75 mm long, the handle 10 mm thick, so a handle between the pads
is within about 8 mm of Q across and 12-37 mm along the pads; 20 mm separates "between the
pads" from "lost" with margin both ways."""

CLOSED_DOOR_ANGLE = 0.1
"""A left door opened less than this at the start [rad] counts as closed (handle in reach)."""

STATUSES = ("ok", "slipped", "speed_limit", "diverged", "ik_failed")
"""Run statuses, best first (see the documentation's exit codes)."""


@dataclass(frozen=True)
class Tracking:
    """Per-sample tracking over the arc window.

    Attributes:
        t: Times (n,) [s]. tau: Arc parameter (n,) in [0, 1].
        p_WQ: Positions of Q (n, 3) [m].
        radial_error: Signed radial error of Q (n,) [m].
        orientation_error: Orientation error angle of L7 (n,) [rad].
    """

    t: np.ndarray
    tau: np.ndarray
    p_WQ: np.ndarray
    radial_error: np.ndarray
    orientation_error: np.ndarray


class Kinematics:
    """Forward kinematics of L7 and Q on the controllers' arm model."""

    def __init__(self) -> None:
        self._plant = make_controller_plant()
        self._context = self._plant.CreateDefaultContext()
        self._L7 = self._plant.GetFrameByName(L7_FRAME)

    def poses(self, q: np.ndarray):
        """X_WL7 for each row of q (n, 7) [rad]."""
        out = []
        for qi in np.atleast_2d(q):
            self._plant.SetPositions(self._context, qi)
            out.append(self._L7.CalcPoseInWorld(self._context))
        return out

    def contact_wrenches(self, q: np.ndarray, tau_external: np.ndarray) -> np.ndarray:
        """Least-squares contact wrench at Q, (torque; force) in W, for each row of q (n, 7)
        [rad] and tau_external (n, 7) [N m]: shape (n, 6) [N m, N] (see
        :func:`doorlab.control.hinge_estimation.estimate_contact_wrench`)."""
        from pydrake.multibody.tree import JacobianWrtVariable

        from doorlab.control.hinge_estimation import estimate_contact_wrench

        W = self._plant.world_frame()
        out = []
        for qi, tau in zip(np.atleast_2d(q), np.atleast_2d(tau_external), strict=True):
            self._plant.SetPositions(self._context, qi)
            J = self._plant.CalcJacobianSpatialVelocity(
                self._context, JacobianWrtVariable.kV, self._L7, p_L7Q, W, W
            )
            out.append(estimate_contact_wrench(J, tau).F_Q_W)
        return np.array(out).reshape(-1, 6)


def compute_tracking(
    result: EpisodeResult,
    geometry: DoorGeometry,
    *,
    source: Literal["measured", "commanded"] = "measured",
    kinematics: Kinematics | None = None,
) -> Tracking:
    """Radial and orientation errors over the arc window from q_measured or q_commanded."""
    kinematics = kinematics or Kinematics()
    t0, t1 = result.arc_window
    mask = result.window(t0, t1)
    q = (result.q_measured if source == "measured" else result.q_commanded)[mask]
    t = result.t[mask]
    tau = np.clip((t - t0) / (t1 - t0), 0.0, 1.0)
    poses = kinematics.poses(q)
    p_WQ = np.array([X @ p_L7Q for X in poses])
    orientation = np.array(
        [
            (X.rotation().inverse() @ geometry.R_WL7_ref(s)).ToAngleAxis().angle()
            for X, s in zip(poses, tau, strict=True)
        ]
    )
    return Tracking(t, tau, p_WQ, geometry.radial_error(p_WQ), orientation)


def handle_distance(
    result: EpisodeResult, geometry: DoorGeometry, kinematics: Kinematics
) -> np.ndarray:
    """Horizontal distance from Q to the (moving) handle axis at every sample (n,) [m]."""
    p_WQ = np.array([X @ p_L7Q for X in kinematics.poses(result.q_measured)])
    handles = np.array([geometry.handle_position(a) for a in result.door_angles[:, 0]])
    return np.hypot(*(p_WQ - handles)[:, :2].T)


@dataclass(frozen=True)
class DoorMetrics:
    """The figures of one run (SI units; the keys of ``metrics.json``).

    Tracking errors are over the arc window, from the measured joint positions unless the
    key says ``cmd`` (from q_ref, as the problem set's plots drew them).

    Attributes:
        controller: The controller that ran: a built-in's name (``Scenario.controller``),
            a plug-in's own name (:func:`doorlab.episode.plugins.display_name`).
        doors: ``open`` or ``closed`` (``Scenario.doors``).
        knots: IK knot points (``ik.knots``) for the ``ik`` controller, else None.
        status: One of :data:`STATUSES` (sets the exit code).
        max_radial_error_m: Largest |radial error| of Q off the handle's arc [m].
        rms_radial_error_m: RMS radial error of Q [m].
        max_orientation_error_rad: Largest orientation error of L7 [rad].
        rms_orientation_error_rad: RMS orientation error of L7 [rad].
        max_radial_error_cmd_m: Largest |radial error| of Q from the commanded q_ref [m].
        max_orientation_error_cmd_rad: Largest orientation error of L7 from q_ref [rad].
        handle_held: Whether Q is still at the handle at the episode's end (within
            :data:`HANDLE_CAPTURE_RADIUS`); None with the doors open (no handle to hold).
        handle_distance_m: Horizontal distance of Q from the handle axis at the end [m].
        slip_time_s: When Q left the handle (beyond :data:`HANDLE_CAPTURE_RADIUS`) during
            or after the arc [s]; None if it never did or the doors were open.
        peak_external_torque_Nm: Largest |external (contact) joint torque| over the episode
            [N m].
        peak_external_torque_arc_Nm: The same over the arc window [N m].
        max_joint_speed_rad_s: Largest measured |joint speed| [rad/s].
        speed_limit_exceeded: Whether a joint exceeded its data-sheet speed.
        sim_time_s: Simulated duration [s].
        wall_time_s: Wall-clock time of the simulation [s].
        realtime_factor: Simulated over wall-clock time [-].
    """

    controller: str
    doors: str
    knots: int | None
    status: str
    max_radial_error_m: float
    rms_radial_error_m: float
    max_orientation_error_rad: float
    rms_orientation_error_rad: float
    max_radial_error_cmd_m: float
    max_orientation_error_cmd_rad: float
    final_door_angle_rad: float  # left hinge angle at the episode's end (opening is negative)
    door_opening_arc_end_rad: float  # opened at the arc's end, t = arc_window[1] (primary)
    door_opening_rad: float  # opened at the episode's end
    # Largest lag of the door behind the arc plan during the arc; None with the doors open.
    door_lag_max_rad: float | None
    handle_held: bool | None  # None with the doors open: there is no handle to hold
    handle_distance_m: float
    slip_time_s: float | None
    peak_external_torque_Nm: float
    peak_external_torque_arc_Nm: float
    max_joint_speed_rad_s: float
    speed_limit_exceeded: bool
    peak_torque_ratio: float  # max over joints and time of |tau_commanded| / data-sheet limit
    sim_time_s: float
    wall_time_s: float
    realtime_factor: float
    # Peak |force| of the least-squares contact wrench at Q during the arc [N].
    peak_contact_force_arc_N: float = float("nan")
    # Plans that estimate the hinge (adaptive): horizontal distance of the final estimate
    # from the true hinge axis [m]; None for the others (or if no estimate was trusted).
    hinge_estimate_error_m: float | None = None

    def to_dict(self) -> dict:
        """JSON-ready dictionary."""
        return dataclasses.asdict(self)


def door_opening(result: EpisodeResult) -> np.ndarray:
    """Left door opening since the arc's start at every sample (n,) [rad] (positive = open)."""
    t0 = result.arc_window[0]
    i0 = int(np.argmin(np.abs(result.t - t0)))
    left = result.door_angles[:, 0]
    return left[i0] - left


def door_lag(result: EpisodeResult, geometry: DoorGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Lag of the left door behind the arc plan over the arc window.

    Returns:
        Times (n,) [s] and lags (n,) [rad]: the plan's opening sweep * tau minus the door's.
    """
    t0, t1 = result.arc_window
    mask = result.window(t0, t1)
    tau = np.clip((result.t[mask] - t0) / (t1 - t0), 0.0, 1.0)
    return result.t[mask], geometry.sweep * tau - door_opening(result)[mask]


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def compute_metrics(
    result: EpisodeResult,
    scenario: Scenario,
    geometry: DoorGeometry,
    *,
    kinematics: Kinematics | None = None,
) -> DoorMetrics:
    """All figures of one run, from its logs.

    Args:
        result: The episode's logs.
        scenario: The scenario that produced them (controller, doors, knots).
        geometry: The TRUE door geometry (:func:`doorlab.cell.geometry.true_door_geometry`): the
            arc the handle really follows; equal to the plans' with no cupboard yaw error.
        kinematics: Reusable forward kinematics (built if not given).
    """
    kinematics = kinematics or Kinematics()
    measured = compute_tracking(result, geometry, source="measured", kinematics=kinematics)
    commanded = compute_tracking(result, geometry, source="commanded", kinematics=kinematics)
    t0, t1 = result.arc_window
    left = result.door_angles[:, 0]
    opening = door_opening(result)
    i1 = int(np.argmin(np.abs(result.t - t1)))

    # The handle is within the gripper's reach only if the left door starts (nearly) closed.
    closed = scenario.initial_door_angles()[0] > -CLOSED_DOOR_ANGLE
    distance = handle_distance(result, geometry, kinematics)
    held = bool(distance[-1] < HANDLE_CAPTURE_RADIUS) if closed else None
    slip_time = None
    if closed:
        lost = np.flatnonzero((result.t >= t0) & (distance >= HANDLE_CAPTURE_RADIUS))
        if len(lost):
            slip_time = float(result.t[lost[0]])
    speed_ratio = np.abs(result.v_measured) / JOINT_SPEED_LIMITS
    speed_exceeded = bool(np.any(speed_ratio > 1.0))
    if closed and slip_time is not None:
        status = "slipped"
    elif speed_exceeded:
        status = "speed_limit"
    else:
        status = "ok"
    wall = float(result.wall_time_s)
    return DoorMetrics(
        controller=display_name(scenario.controller),
        doors=scenario.doors,
        knots=scenario.ik.knots if scenario.controller == "ik" else None,
        status=status,
        max_radial_error_m=float(np.max(np.abs(measured.radial_error))),
        rms_radial_error_m=_rms(measured.radial_error),
        max_orientation_error_rad=float(np.max(measured.orientation_error)),
        rms_orientation_error_rad=_rms(measured.orientation_error),
        max_radial_error_cmd_m=float(np.max(np.abs(commanded.radial_error))),
        max_orientation_error_cmd_rad=float(np.max(commanded.orientation_error)),
        final_door_angle_rad=float(left[-1]),
        door_opening_arc_end_rad=float(opening[i1]),
        door_opening_rad=float(opening[-1]),
        door_lag_max_rad=float(np.max(door_lag(result, geometry)[1])) if closed else None,
        handle_held=held,
        handle_distance_m=float(distance[-1]),
        slip_time_s=slip_time,
        peak_external_torque_Nm=float(np.max(np.abs(result.tau_external))),
        peak_external_torque_arc_Nm=float(
            np.max(np.abs(result.tau_external[result.window(*result.arc_window)]))
        ),
        max_joint_speed_rad_s=float(np.max(np.abs(result.v_measured))),
        speed_limit_exceeded=speed_exceeded,
        peak_torque_ratio=float(np.max(np.abs(result.tau_commanded) / JOINT_TORQUE_LIMITS)),
        sim_time_s=result.sim_time_s,
        wall_time_s=wall,
        realtime_factor=result.sim_time_s / wall if wall > 0 else float("inf"),
        peak_contact_force_arc_N=peak_contact_force(result, kinematics),
        hinge_estimate_error_m=final_hinge_estimate_error(result, geometry),
    )


def peak_contact_force(result: EpisodeResult, kinematics: Kinematics) -> float:
    """Peak |force| of the contact wrench at Q over the arc window [N] (0 if no contact)."""
    arc = result.window(*result.arc_window)
    if not np.any(result.tau_external[arc]):
        return 0.0
    F = kinematics.contact_wrenches(result.q_measured[arc], result.tau_external[arc])
    return float(np.max(np.linalg.norm(F[:, 3:], axis=1)))


def hinge_estimate_error(result: EpisodeResult, geometry: DoorGeometry) -> np.ndarray:
    """Horizontal distance [m] of the plan's running hinge estimate from the true hinge axis,
    per control tick of ``result.plan_log`` (n,) (nan before the estimate is trusted).

    Args:
        result: An episode whose arc plan logged ``hinge_x``/``hinge_y`` (the adaptive plan).
        geometry: The TRUE door geometry.

    Raises:
        ConfigError: The episode's plan logged no hinge estimate.
    """
    log = result.plan_log
    if "hinge_x" not in log:
        raise ConfigError(
            "this episode's plan logged no hinge estimate (only the adaptive plan does); "
            f"logged channels: {', '.join(log) or 'none'}"
        )
    return np.hypot(log["hinge_x"] - geometry.p_W_hinge[0], log["hinge_y"] - geometry.p_W_hinge[1])


def final_hinge_estimate_error(result: EpisodeResult, geometry: DoorGeometry) -> float | None:
    """The last trusted hinge estimate's error [m]; None without a (trusted) estimate."""
    if "hinge_x" not in result.plan_log:
        return None
    error = hinge_estimate_error(result, geometry)
    finite = error[np.isfinite(error)]
    return float(finite[-1]) if len(finite) else None


def joint_damping_ratios(scenario: Scenario, q: np.ndarray) -> np.ndarray | None:
    """Damping ratio of each joint's stiffness loop at configuration q, shape (7,) [-].

    zeta_i = Dq_i dq_scale / (2 sqrt(Kq_i M_ii(q))), with M(q) of the controllers' arm model
    (links, lumped gripper and the motors' reflected inertia), Kq and Dq of
    :func:`doorlab.cell.station.loop_gains`. None for the ``inverse_dynamics`` and ``implicit_pd``
    inner loops.
    """
    if scenario.station.inner_loop.kind not in STIFFNESS_LOOPS:
        return None
    plant = make_controller_plant()
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, np.asarray(q, dtype=float))
    inertia = np.diag(plant.CalcMassMatrix(context))
    kq, dq = loop_gains(scenario.station.inner_loop)
    return dq / (2.0 * np.sqrt(kq * inertia))
