"""What the real cell does not measure, estimated from what it does, and named so.

The cell has no hinge sensor. While the gripper holds the handle, the door turns with Q, so
the left door's angle is estimated as its angle at the arc's start plus the angle Q has turned
about the believed hinge axis since then:

    door_angle_estimated(t) = a0 - (theta_Q(t) - theta_Q(t_arc))

with theta_Q the angle of the hinge-to-Q vector (the same angle :class:`DoorGeometry` uses for
the handle; the hinge angle decreases as the left door opens). The handle counts as held while
the fingers, told to close to the grasp setpoint, stay held apart by something: the measured
separation above the midpoint of the setpoint and the handle's 10 mm (about 7.5 mm; empty
fingers close to the 5 mm setpoint, on the handle they stop at 9.9-10 mm or are pushed wider).
From the arc's start until the first sample the fingers are not held apart; nan elsewhere.
"""

from __future__ import annotations

from functools import cache

import numpy as np
from pydrake.multibody.plant import MultibodyPlant

from doorlab.cell.frames import FINGER_JOINTS, LEFT_HINGE, RIGHT_HINGE, p_L7Q
from doorlab.cell.geometry import scenario_door_geometry
from doorlab.cell.station import add_cell
from doorlab.config import Scenario
from doorlab.episode.metrics import Kinematics

HANDLE_THICKNESS = 0.010
"""The handle's thickness between the finger pads [m] (the cupboard model's handle)."""


def held_width(scenario: Scenario) -> float:
    """The finger separation above which the handle counts as held [m]."""
    return 0.5 * (scenario.station.gripper.grasp_width + HANDLE_THICKNESS)


def handle_held(t: np.ndarray, wsg_width: np.ndarray, scenario: Scenario, arc_start: float):
    """Boolean mask (n,): from the arc's start until the fingers first close past the handle
    (always False with the doors open: there is no handle in reach)."""
    held = np.zeros(len(t), dtype=bool)
    if scenario.initial_door_angles()[0] < -0.1:  # open doors: the fingers hold nothing
        return held
    after = t >= arc_start - 1e-9
    lost = after & (wsg_width < held_width(scenario))
    end = int(np.argmax(lost)) if lost.any() else len(t)
    held[:end] = after[:end]
    return held


def door_angle_estimate(
    t: np.ndarray,
    q_measured: np.ndarray,
    wsg_width: np.ndarray,
    scenario: Scenario,
    *,
    arc_start: float,
) -> np.ndarray:
    """The left hinge angle estimated from Q's angle about the believed hinge while the handle
    is held (n,) [rad]; nan where it is not held (module docstring)."""
    held = handle_held(t, wsg_width, scenario, arc_start)
    estimate = np.full(len(t), np.nan)
    if not held.any():
        return estimate
    geometry = scenario_door_geometry(scenario)
    rows = np.flatnonzero(held)
    p_WQ = np.array([X @ p_L7Q for X in Kinematics().poses(q_measured[rows])])
    d = geometry.p_W_hinge[:2] - p_WQ[:, :2]
    theta = np.unwrap(np.arctan2(d[:, 0], d[:, 1]))
    estimate[rows] = scenario.initial_door_angles()[0] - (theta - theta[0])
    return estimate


@cache
def _cell_layout(arm_collision: bool) -> tuple[int, np.ndarray, list[int], int, int]:
    """The cell plant's positions: (nq, the arm's 7 columns, the fingers', left, right hinge)."""
    plant = MultibodyPlant(0.0)
    iiwa, wsg, cupboard = add_cell(plant, arm_collision=arm_collision)
    plant.Finalize()
    index = np.arange(plant.num_positions())
    arm = plant.GetPositionsFromArray(iiwa, index).astype(int)
    fingers = [plant.GetJointByName(name, wsg).position_start() for name in FINGER_JOINTS]
    left = plant.GetJointByName(LEFT_HINGE, cupboard).position_start()
    right = plant.GetJointByName(RIGHT_HINGE, cupboard).position_start()
    return plant.num_positions(), arm, fingers, left, right


def hardware_plant_positions(
    q_measured: np.ndarray,
    wsg_width: np.ndarray,
    door_angle: np.ndarray,
    scenario: Scenario,
) -> np.ndarray:
    """Positions of the cell's plant for the replay (n, nq): the measured arm and fingers; the
    left door at ``door_angle`` where it is finite, else where it was last estimated (at first
    its believed start angle), the right door at its believed start angle. The doors are not
    measured: the replay draws the estimate."""
    nq, arm, fingers, left, right = _cell_layout(scenario.station.arm_collision)
    n = len(q_measured)
    positions = np.zeros((n, nq))
    positions[:, arm] = q_measured
    positions[:, fingers[0]] = -0.5 * wsg_width
    positions[:, fingers[1]] = 0.5 * wsg_width
    left0, right0 = scenario.initial_door_angles()
    shown = np.where(np.isfinite(door_angle), door_angle, np.nan)
    last = left0
    for i in range(n):  # hold the last estimate where there is none
        last = shown[i] if np.isfinite(shown[i]) else last
        shown[i] = last
    positions[:, left] = shown
    positions[:, right] = right0
    return positions
