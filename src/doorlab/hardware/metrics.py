"""The figures of a run on the real cell: those of a simulated run that the cell can measure,
the estimated door angle (named so), the link's statistics and how the run ended.

Absent, because the cell cannot measure them: the hinge angles (``final_door_angle_rad``,
``door_opening_*``, ``door_lag_max_rad``), Q's distance from the true handle
(``handle_held``, ``handle_distance_m``) and anything of the true cupboard. In their place:
``door_opening_arc_end_estimated_rad`` and ``door_opening_estimated_rad``
(:mod:`doorlab.hardware.estimates`) and ``fingers_on_handle`` (the gripper's measured
separation). With the doors closed a run whose fingers close past the handle during the arc
has status ``slipped``, from the gripper's measurement.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from doorlab.cell.geometry import scenario_door_geometry
from doorlab.config import Scenario
from doorlab.constants import JOINT_SPEED_LIMITS, JOINT_TORQUE_LIMITS
from doorlab.episode.metrics import Kinematics, compute_tracking
from doorlab.episode.plugins import display_name
from doorlab.episode.result import EpisodeResult
from doorlab.hardware.episode import HardwareOutcome, describe_latency
from doorlab.hardware.estimates import held_width


@dataclass(frozen=True)
class HardwareMetrics:
    """The keys of a hardware run's ``metrics.json`` (SI units; nan: nothing logged)."""

    controller: str
    doors: str
    knots: int | None
    status: str
    cell: str
    max_radial_error_m: float
    rms_radial_error_m: float
    max_orientation_error_rad: float
    rms_orientation_error_rad: float
    max_radial_error_cmd_m: float
    max_orientation_error_cmd_rad: float
    # The left door opened, estimated from Q (None when not held there, or doors open).
    door_opening_arc_end_estimated_rad: float | None
    door_opening_estimated_rad: float | None
    fingers_on_handle: bool | None  # at the end; None with the doors open
    slip_time_s: float | None  # first time in the arc the fingers closed past the handle
    peak_external_torque_Nm: float
    peak_external_torque_arc_Nm: float
    max_joint_speed_rad_s: float
    speed_limit_exceeded: bool
    peak_torque_ratio: float
    duration_s: float  # episode time logged [s]
    wall_time_s: float
    lcm_url: str
    link: dict
    safety_limits: dict
    stop: dict | None  # how a stopped run ended: reason, t, and the violation's details

    def to_dict(self) -> dict:
        """JSON-ready dictionary."""
        return dataclasses.asdict(self)


def _max(x: np.ndarray) -> float:
    return float(np.max(x)) if np.size(x) else math.nan


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if np.size(x) else math.nan


def _opening(result: EpisodeResult, t: float) -> float | None:
    """The estimated left door opening since the arc's start at time t, or None."""
    estimate = result.door_angle_estimated
    i = int(np.argmin(np.abs(result.t - t))) if len(result.t) else 0
    if estimate is None or not len(result.t) or abs(result.t[i] - t) > 1e-6:
        return None
    valid = np.flatnonzero(np.isfinite(estimate))
    if not len(valid) or not np.isfinite(estimate[i]):
        return None
    return float(estimate[valid[0]] - estimate[i])


def compute_hardware_metrics(
    outcome: HardwareOutcome, scenario: Scenario, *, lcm_url: str
) -> HardwareMetrics:
    """The figures of a run on the real cell, from its logs and its link record."""
    result = outcome.result
    kinematics = Kinematics()
    geometry = scenario_door_geometry(scenario)  # the real cupboard is the believed one
    closed = scenario.initial_door_angles()[0] > -0.1
    t0, t1 = result.arc_window
    radial, orientation = {}, {}
    for source in ("measured", "commanded"):
        if result.window(t0, t1).any():  # a run stopped before the arc has no tracking
            tracking = compute_tracking(result, geometry, source=source, kinematics=kinematics)
            radial[source], orientation[source] = (
                np.abs(tracking.radial_error),
                tracking.orientation_error,
            )
        else:
            radial[source] = orientation[source] = np.zeros(0)
    width_ok = result.wsg_width >= held_width(scenario)
    slip = np.flatnonzero((result.t >= t0) & ~width_ok) if closed else []
    slip_time = float(result.t[slip[0]]) if len(slip) else None
    speed_exceeded = bool(np.any(np.abs(result.v_measured) > JOINT_SPEED_LIMITS))
    status = outcome.status
    if status == "ok":
        status = "slipped" if slip_time is not None else "speed_limit" if speed_exceeded else "ok"
    stop = None
    if outcome.status != "ok":
        stop = {
            "reason": outcome.status,
            "message": outcome.message,
            "t": outcome.t_stop,
            "last_status_to_stop_s": outcome.last_status_to_stop,
        }
        if outcome.violation is not None:
            stop["violation"] = outcome.violation.to_dict()
    arc = result.window(t0, t1)
    return HardwareMetrics(
        controller=display_name(scenario.controller),
        doors=scenario.doors,
        knots=scenario.ik.knots if scenario.controller == "ik" else None,
        status=status,
        cell="hardware",
        max_radial_error_m=_max(radial["measured"]),
        rms_radial_error_m=_rms(radial["measured"]),
        max_orientation_error_rad=_max(orientation["measured"]),
        rms_orientation_error_rad=_rms(orientation["measured"]),
        max_radial_error_cmd_m=_max(radial["commanded"]),
        max_orientation_error_cmd_rad=_max(orientation["commanded"]),
        door_opening_arc_end_estimated_rad=_opening(result, t1) if closed else None,
        door_opening_estimated_rad=_opening(result, result.t[-1]) if closed else None,
        fingers_on_handle=bool(width_ok[-1]) if closed and len(width_ok) else None,
        slip_time_s=slip_time,
        peak_external_torque_Nm=_max(np.abs(result.tau_external)),
        peak_external_torque_arc_Nm=_max(np.abs(result.tau_external[arc])),
        max_joint_speed_rad_s=_max(np.abs(result.v_measured)),
        speed_limit_exceeded=speed_exceeded,
        peak_torque_ratio=_max(np.abs(result.tau_commanded) / JOINT_TORQUE_LIMITS),
        duration_s=result.sim_time_s,
        wall_time_s=float(result.wall_time_s),
        lcm_url=lcm_url,
        link=describe_latency(outcome.record),
        safety_limits=outcome.limits.to_dict(),
        stop=stop,
    )
