"""What one benchmark episode measures, and success defined once.

**Success** (doorlab's): the run ended ``ok`` (no slip, no safety stop, no joint over its
data-sheet speed, no error), the handle is between the fingers at the episode's end, and the
door stands open at least the arc's angle less :data:`OPEN_TOLERANCE_DEG` at the episode's end
(the arc's angle: ``arc.angle_end_deg`` less the closed door's handle angle, 41.2 deg by
default). **robosuite's** definition (its Door task's ``_check_success``: hinge > 0.3 rad,
checked every step): the hinge exceeded :data:`ROBOSUITE_OPEN_RAD` at some logged instant of
the episode, whatever came after (a stopped run counts with its logs up to the stop).

A failure is one of :data:`FAILURE_KINDS`, the first that applies: ``error`` (no episode: IK
failed, the physics diverged, the controller raised, doorlab's worker failed), ``stop`` (a
safety stop, or a joint over its data-sheet speed: the arm's drives would stop), ``slip`` (the
handle left the fingers), ``short`` (the run ended with the handle held, the door short of the
angle).

Time to open: from the arc's start to the first logged instant the door is open the success
angle (None if it never is).
"""

from __future__ import annotations

import math
import time

import numpy as np

from doorlab.config import Scenario
from doorlab.episode.result import EpisodeResult

OPEN_TOLERANCE_DEG = 2.0
"""The door counts as open within this of the arc's angle [deg] (39.2 of 41.2 deg by default:
the acceptance's 39 deg; the problem set's IK plan reaches 40.3)."""
ROBOSUITE_OPEN_RAD = 0.3
"""robosuite's Door task: success when the hinge exceeds this [rad] (17.2 deg)."""
FAILURE_KINDS = ("slip", "stop", "short", "error")
"""How a benchmark episode fails (module docstring)."""
ERROR_STATUSES = ("ik_failed", "diverged", "controller_error", "error")
"""Statuses of runs that made no episode to judge (failure kind ``error``)."""
STOP_STATUSES = ("safety_stop", "speed_limit", "driver_lost")
"""Statuses of runs stopped for safety (failure kind ``stop``)."""

COLUMNS = {
    "open_threshold_rad": "float64",
    "hinge_max_rad": "float64",
    "time_to_open_s": "float64",
    "success": "boolean",
    "success_robosuite": "boolean",
    "failure": "string",
    "episode_cpu_s": "float64",
}
"""The columns a benchmark adds to the sweep's table, name -> pandas dtype."""


def open_threshold(scenario: Scenario) -> float:
    """The door opening that counts as open [rad]: the arc's sweep less the tolerance."""
    from doorlab.cell.geometry import true_door_geometry

    return true_door_geometry(scenario).sweep - math.radians(OPEN_TOLERANCE_DEG)


def episode_columns(result: EpisodeResult, scenario: Scenario, metrics=None) -> dict:
    """The benchmark's columns of one episode from its logs (a stopped run's too): the
    threshold, the hinge's largest opening [rad] and the time to open [s]."""
    threshold = open_threshold(scenario)
    opening = -result.door_angles[:, 0]  # the left hinge opens negative; closed is 0
    t0 = float(result.arc_window[0])
    reached = np.flatnonzero((result.t >= t0 - 1e-9) & (opening >= threshold))
    return {
        "open_threshold_rad": threshold,
        "hinge_max_rad": float(np.max(opening)) if len(opening) else float("nan"),
        "time_to_open_s": float(result.t[reached[0]] - t0) if len(reached) else None,
    }


def classify(row: dict) -> tuple[bool, bool, str | None]:
    """(success, success under robosuite's definition, failure kind or None) of a row of the
    benchmark's table (status, handle_held, door_opening_rad, the columns above)."""
    status = row.get("status")
    hinge = _number(row.get("hinge_max_rad"))
    robosuite = hinge is not None and hinge > ROBOSUITE_OPEN_RAD
    if status in ERROR_STATUSES or status is None:
        return False, robosuite, "error"
    if status in STOP_STATUSES:
        return False, robosuite, "stop"
    if status == "slipped" or row.get("handle_held") is not True:
        return False, robosuite, "slip"
    opening, threshold = (
        _number(row.get("door_opening_rad")),
        _number(row.get("open_threshold_rad")),
    )
    if status != "ok" or opening is None or threshold is None or opening < threshold:
        return False, robosuite, "short" if status == "ok" else "error"
    return True, robosuite, None


def _number(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)):
        return None
    return float(value) if math.isfinite(value) else None


def bench_episode(scenario: Scenario) -> dict:
    """Worker: one benchmark episode's row (:func:`doorlab.sweep.execution.run_one` with the
    benchmark's columns, its verdict, and ``episode_cpu_s``: the worker's CPU seconds on it,
    which other processes on the machine do not inflate as they do its wall time); never
    raises."""
    from doorlab.sweep.execution import run_one

    start = time.process_time()
    row = run_one(scenario, measure=episode_columns)
    success, robosuite, kind = classify(row)
    row.update(success=success, success_robosuite=robosuite, failure=kind)
    row["episode_cpu_s"] = time.process_time() - start
    return row
