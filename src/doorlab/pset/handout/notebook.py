"""The notebook of the problem-set folder (``pset5_open_cabinet_door.ipynb``), in our words.

Same tasks, questions and API calls as the 2019 notebook; written as nbformat-4 JSON.
"""

from __future__ import annotations

import json

NOTEBOOK_NAME = "pset5_open_cabinet_door.ipynb"

_INTRO = """\
# Opening a cupboard door three ways

A KUKA iiwa 7 with a WSG-50 gripper holds the handle of a cupboard's left door and pulls it
open along the handle's arc. You will command it three ways and compare how well point Q
(between the finger pads, fixed in the arm's last link L7) follows the arc:

1. **Pointwise IK**: IK at knots along the arc, a cubic joint trajectory through them.
2. **Velocity mapping**: $\\dot q = J^+ V_{des}$ from the pose error,
   $q_{ref} = q + \\dot q\\,\\Delta t$.
3. **Force mapping (impedance)**: $\\tau_{ff} = J^T F$ from the pose error, $q_{ref} = q$.

The robot's own controller (the inner loop) turns your commands into motor torques:
$\\tau_m = K_q (q_{ref} - q) - D_q \\dot q + g(q) + \\tau_{ff}$.

$J = [{}^W J_v^{L7}_Q]_W$ (``Jv_WL7q``) is the 6x7 geometric Jacobian of frame L7 at Q in the
world frame W: rows 0-2 map $\\dot q$ to L7's angular velocity, rows 3-5 to Q's velocity.
Its transpose maps a moment on L7 and a force at Q (both in W) to joint torques.

Frames: W world, L the left door, L7 the arm's last link, Q the grasp point in L7. The
simulation runs on doorlab (Drake); see README.md for what differs from the 2019 original."""

_SETUP = """\
# Run first.
%matplotlib inline
import matplotlib.pyplot as plt
import numpy as np
from pydrake.math import RollPitchYaw, RotationMatrix
from pydrake.trajectories import PiecewisePolynomial

from manip_station_sim.plan_utils import PlotJointLog, PlotIiwaPositionLog

duration_arc = 10  # seconds along the arc"""

_MESHCAT = """\
# Drake's Meshcat viewer (prints a localhost URL; open it in a browser). RunSimulation draws
# there when is_visualizing=True.
from manip_station_sim.manipulation_station_simulator import StartMeshcat
vis = StartMeshcat()"""

_TASK1_MD = """\
## Task 1: follow the arc with pointwise IK

Complete `InverseKinPointwise` in `ik_utils.py`: IK at `num_knot_points` knots along a path
given by two functions of tau in [0, 1] (Q's position and L7's orientation), each IK started
from the previous knot, joined by a cubic trajectory (the 2019 code's
`PiecewisePolynomial.Cubic` is gone from Drake: use
`PiecewisePolynomial.CubicWithContinuousSecondDerivatives`, same arguments).
`open_left_door.py` provides the arc
(`InterpolateArc`) and L7's orientation along it (`InterpolateYawAngle`).
Switch `door_angles` to simulate with the doors closed."""

_TASK1 = """\
from manip_station_sim.manipulation_station_simulator import ManipulationStationSimulator
from manip_station_sim.robot_plans import JointSpacePlan
from open_left_door import InterpolateArc, InterpolateYawAngle, p_L7Q, q_home
from ik_utils import InverseKinPointwise

qtraj_arc, q_knots = InverseKinPointwise(
    InterpolatePosition=InterpolateArc,
    InterpolateOrientation=InterpolateYawAngle,
    p_L7Q=p_L7Q,
    duration=duration_arc,
    num_knot_points=10,
    q_initial_guess=q_home,
    position_tolerance=0.001)

# Hold the first knot for 1 s while the gripper closes on the handle.
qtraj_grasp = PiecewisePolynomial.ZeroOrderHold([0, 1], np.column_stack([q_knots[0], q_knots[0]]))
plan_list = [JointSpacePlan(qtraj_grasp), JointSpacePlan(qtraj_arc)]
gripper_setpoint_list = [0.005, 0.005]

door_angles = np.array([-(np.pi / 2 - 0.001), np.pi / 2 - 0.001])  # open
# door_angles = np.array([-0.001, 0.001])  # closed

sim = ManipulationStationSimulator()
(iiwa_position_command_log, iiwa_position_measured_log,
 iiwa_external_torque_log, iiwa_velocity_estimated_log,
 plant_state_log, t_plan) = sim.RunSimulation(
    q_home, door_angles, plan_list, gripper_setpoint_list, extra_time=2.0, real_time_rate=0.0)"""

_PLOTS_MD = """\
The next cell defines the tracking plots used after every task: Q's radial error (its
distance from the hinge axis minus the handle's radius), L7's orientation error, and Q's path
in the horizontal plane. The arc starts at t = 11 s (hold 2 s, move 7 s, grasp 2 s)."""

_PLOTS = """\
from manip_station_sim.plan_utils import CalcL7PoseInWolrdFrame, CalcQPositionInWorldFrame
from open_left_door import (CalcHandleArcPoints, CalcOrientationTrackingError,
                            CalcRadialTrackingError, p_WC_left_hinge)

def plot_arc_tracking(position_log, t_start=11.0):
    n_start = int(round(t_start / 0.01))
    n_end = int(round((t_start + duration_arc) / 0.01)) + 1
    poses, t = CalcL7PoseInWolrdFrame(position_log, n_start=n_start, n_end=n_end)
    p_WQ = CalcQPositionInWorldFrame(poses, p_L7Q)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    axes[0].plot(t, 1000 * CalcRadialTrackingError(p_WQ))
    axes[0].set(xlabel="t (s)", ylabel="radial error (mm)", title="radial tracking error")
    axes[1].plot(t, CalcOrientationTrackingError(poses, t, duration_arc))
    axes[1].set(xlabel="t (s)", ylabel="angle (rad)", title="orientation tracking error")
    arc = CalcHandleArcPoints()
    axes[2].plot(arc[:, 0], arc[:, 1], lw=2, label="handle arc")
    axes[2].plot(p_WQ[:, 0], p_WQ[:, 1], lw=1.5, label="Q")
    axes[2].plot(*p_WC_left_hinge[:2], "*", ms=15, label="hinge")
    axes[2].set(xlabel="x (m)", ylabel="y (m)", title="Q in the horizontal plane")
    axes[2].set_aspect("equal", "box")
    axes[2].legend()
    for ax in axes:
        ax.grid(True)
    fig.tight_layout()
    plt.show()

plot_arc_tracking(iiwa_position_command_log)"""

_Q1 = """\
**Questions (2 points; answer in your PDF with plots).**

1. With the doors open, plot the tracking errors for 2, 5 and 10 knots. How does the number
   of knots change the error?
2. Zoom into Q's path. Is the error the same all along the arc with the doors open? Why or
   why not? What changes with the doors closed?"""

_TASK2_MD = """\
## Task 2: follow the arc by mapping velocities

$$V_{des} = \\begin{pmatrix} K_\\omega\\, \\theta\\, n \\\\ K_v\\, e_{xyz} \\end{pmatrix},\\quad
\\dot q_{des} = J^+ V_{des},\\quad q_{ref} = q + \\dot q_{des}\\, \\Delta t,\\quad \\tau_{ff} = 0$$

$e_{xyz}$ is Q's position error, $\\theta$ and $n$ the angle and axis of L7's orientation error
$R_{L7 L7_r}$ (both errors are computed for you: `CalcPositionError`, `CalcOrientationError`;
the axis is expressed in L7, $V_{des}$ in W), $\\Delta t$ the `control_period`,
$K_v = 100$ and $K_\\omega = 50$ (1/s, on every axis).

Complete `calc_p_Q` and `calc_R_WL7_ref` in `open_left_door.py` and
`IiwaTaskSpaceVelocityPlan.CalcPositionCommand` in `manip_station_sim/robot_plans.py`."""

_TASK_SPACE = """\
from manip_station_sim.manipulation_station_simulator import ManipulationStationSimulator
from manip_station_sim.robot_plans import JointSpacePlan, {plan}
from ik_utils import SolveOneShotIk
from open_left_door import p_WC_handle, p_L7Q, q_home, calc_p_Q, calc_R_WL7_ref

# Where the arc starts: Q at the handle, L7 pitched 135 degrees.
q_start = SolveOneShotIk(
    p_WQ_ref=p_WC_handle,
    R_WL7_ref=RollPitchYaw(0, np.pi / 4 * 3, 0).ToRotationMatrix(),
    p_L7Q=p_L7Q,
    q_initial_guess=q_home,
    position_tolerance=0.0005)

qtraj_grasp = PiecewisePolynomial.ZeroOrderHold([0, 1], np.column_stack([q_start, q_start]))
arc_plan = {plan}(
    calc_p_Q=calc_p_Q, calc_R_WL7_ref=calc_R_WL7_ref, duration=duration_arc, p_L7Q=p_L7Q)
plan_list = [JointSpacePlan(qtraj_grasp), arc_plan]
gripper_setpoint_list = [0.005, 0.005]

{doors}

sim = ManipulationStationSimulator()
(iiwa_position_command_log, iiwa_position_measured_log,
 iiwa_external_torque_log, iiwa_velocity_estimated_log,
 plant_state_log, t_plan) = sim.RunSimulation(
    q_home, door_angles, plan_list, gripper_setpoint_list, extra_time=2.0, real_time_rate=0.0)
plot_arc_tracking(iiwa_position_command_log)"""

_OPEN = """\
door_angles = np.array([-(np.pi / 2 - 0.001), np.pi / 2 - 0.001])  # open
# door_angles = np.array([-0.001, 0.001])  # closed"""
_CLOSED = """\
# door_angles = np.array([-(np.pi / 2 - 0.001), np.pi / 2 - 0.001])  # open
door_angles = np.array([-0.001, 0.001])  # closed"""

_Q2 = """\
**Questions (2 points).**

1. With the doors open, how does the tracking error compare with pointwise IK's?
2. Is the error the same all along the arc with the doors open? Why or why not? What changes
   with the doors closed?"""

_TASK3_MD = """\
## Task 3: open the door by mapping forces

Send the measured position as the position command (the inner loop's stiffness then does
nothing) and a feedforward torque from a spatial force:

$$F = \\begin{pmatrix} K_\\omega\\, \\theta\\, n \\\\ K_v\\, e_{xyz} \\end{pmatrix},\\quad
\\tau_{ff} = J^T F,\\quad q_{ref} = q$$

with $K_v = 100$ N/m and $K_\\omega = 50$ N m/rad. Complete
`IiwaTaskSpaceImpedancePlan.CalcTorqueCommand` in `manip_station_sim/robot_plans.py`."""

_Q3 = """\
**Questions (2 points).**

1. With the doors open, how does the tracking error compare with the other two ways?
2. With the doors closed, how does the door change the tracking error?"""

_UTILS_MD = "## Logs of the last run"
_UTIL_CELLS = (
    'PlotJointLog(iiwa_velocity_estimated_log, legend="qDt", y_label="rad/s")',
    'PlotJointLog(iiwa_external_torque_log, legend="tau_ext", y_label="N*m")',
    "PlotIiwaPositionLog(iiwa_position_command_log, iiwa_position_measured_log)",
)
_GRADE_MD = """\
## Grade your code

The grader runs every test in its own process (about a minute) and prints a score per test."""
_GRADE = """\
import subprocess
import sys
subprocess.run([sys.executable, "test_pset_5a.py", "test_results.json"], check=False)

import test_pset_5a
print(test_pset_5a.pretty_format_json_results("test_results.json"))"""


def _cell(kind: str, source: str) -> dict:
    cell = {"cell_type": kind, "metadata": {}, "source": source.splitlines(keepends=True)}
    if kind == "code":
        cell.update(execution_count=None, outputs=[])
    return cell


def notebook_cells() -> list[tuple[str, str]]:
    """(kind, source) of every cell, in order."""
    velocity = _TASK_SPACE.format(plan="IiwaTaskSpaceVelocityPlan", doors=_OPEN)
    impedance = _TASK_SPACE.format(plan="IiwaTaskSpaceImpedancePlan", doors=_CLOSED)
    return [
        ("markdown", _INTRO),
        ("code", _SETUP),
        ("code", _MESHCAT),
        ("markdown", _TASK1_MD),
        ("code", _TASK1),
        ("markdown", _PLOTS_MD),
        ("code", _PLOTS),
        ("markdown", _Q1),
        ("markdown", _TASK2_MD),
        ("code", velocity),
        ("markdown", _Q2),
        ("markdown", _TASK3_MD),
        ("code", impedance),
        ("markdown", _Q3),
        ("markdown", _UTILS_MD),
        *(("code", c) for c in _UTIL_CELLS),
        ("markdown", _GRADE_MD),
        ("code", _GRADE),
    ]


def notebook_json() -> str:
    """The notebook as nbformat-4 JSON text."""
    nb = {
        "cells": [_cell(kind, source) for kind, source in notebook_cells()],
        "metadata": {
            "kernelspec": {"display_name": "Python 3", "language": "python", "name": "python3"},
            "language_info": {"name": "python"},
        },
        "nbformat": 4,
        "nbformat_minor": 5,
    }
    for i, cell in enumerate(nb["cells"]):
        cell["id"] = f"cell-{i}"
    return json.dumps(nb, indent=1) + "\n"
