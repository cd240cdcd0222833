"""The problem set's helper functions (``open_left_door`` and ``plan_utils`` of the 2019 files)
on doorlab's door model, kinematics and plots.

Every constant is read from doorlab's cupboard model
(:func:`doorlab.cell.door_model.default_door_constants`), so the folder's numbers and the
simulated cell cannot drift apart. The handle's arc and L7's orientation along it
(``InterpolateArc``, ``InterpolateYawAngle``) are the handout's: the 2019 folder provided
them, with their formulas in their docstrings, and so does this one. They are written here
from those formulas, apart from doorlab's own arc (:mod:`doorlab.cell.geometry`, the reference the
grader checks ``calc_p_Q`` and ``calc_R_WL7_ref`` against, which the student's process does
not see); a test checks that the two agree.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.multibody.plant import MultibodyPlant

from doorlab.cell.door_model import default_door_constants
from doorlab.cell.frames import L7_FRAME
from doorlab.cell.station import make_controller_plant
from doorlab.constants import L7_PITCH

if TYPE_CHECKING:
    from matplotlib.figure import Figure


class _Pyplot:
    """``matplotlib.pyplot``, imported on first use: the grader's student process imports
    this module for the door constants and never plots (pyplot costs 0.7 s to import)."""

    def __getattr__(self, name: str):
        return getattr(importlib.import_module("matplotlib.pyplot"), name)


plt = _Pyplot()

ARC_PLOT_POINTS = 100
"""Points of the drawn handle arc."""
MAX_PLOT_POINTS = 1000
"""The joint plots draw at most this many samples per curve."""


def door_constants() -> dict:
    """The problem set's door constants from the model: hinge and handle (3,) [m], radius [m],
    initial handle angle and arc-end angle [rad]."""
    g = default_door_constants()
    return {
        "p_WC_left_hinge": g.p_W_hinge.copy(),
        "p_WC_handle": g.p_W_handle.copy(),
        "r_handle": g.r_handle,
        "theta0_hinge": g.theta0,
        "angle_end": g.angle_end,
    }


def interpolate_arc(tau: float) -> np.ndarray:
    """Q on the handle arc at tau in [0, 1] (clipped), shape (3,) [m]:
    theta = theta0_hinge + (angle_end - theta0_hinge) tau,
    p_WQ = p_WC_left_hinge - r_handle (sin theta, cos theta, 0)."""
    g = default_door_constants()
    theta = g.theta0 + g.sweep * min(max(float(tau), 0.0), 1.0)
    return g.p_W_hinge - g.r_handle * np.array([math.sin(theta), math.cos(theta), 0.0])


def interpolate_yaw(tau: float) -> RotationMatrix:
    """L7's orientation at tau in [0, 1] (clipped):
    RollPitchYaw(0, 3 pi / 4, -(angle_end - theta0_hinge) tau)."""
    yaw = -default_door_constants().sweep * min(max(float(tau), 0.0), 1.0)
    return RollPitchYaw(0.0, L7_PITCH, yaw).ToRotationMatrix()


def handle_arc_points(n: int = ARC_PLOT_POINTS) -> np.ndarray:
    """n points of the handle's circle about the hinge, door closed to 90 deg open (n, 3) [m]."""
    g = default_door_constants()
    theta = np.linspace(0.0, math.pi / 2, n)
    offsets = np.column_stack([np.sin(theta), np.cos(theta), np.zeros(n)])
    return g.p_W_hinge - g.r_handle * offsets


def radial_tracking_error(p_WQ: np.ndarray) -> np.ndarray:
    """Horizontal distance of Q from the hinge axis minus the handle radius (n,) [m]."""
    return default_door_constants().radial_error(np.asarray(p_WQ, dtype=float))


def orientation_tracking_error(
    list_X_WL7: Sequence[RigidTransform], t: np.ndarray, duration: float
) -> np.ndarray:
    """Angle between R_WL7 and its reference at tau = (t - t[0]) / duration, (n,) [rad]."""
    t = np.asarray(t, dtype=float)
    out = np.empty(len(list_X_WL7))
    for i, X_WL7 in enumerate(list_X_WL7):
        R_ref = interpolate_yaw((t[i] - t[0]) / duration)
        out[i] = (X_WL7.rotation().inverse() @ R_ref).ToAngleAxis().angle()
    return out


def controller_plant() -> tuple[MultibodyPlant, list]:
    """The controllers' arm model and the indices of its frames iiwa_link_0..7."""
    plant = make_controller_plant()
    return plant, [plant.GetFrameByName(f"iiwa_link_{i}").index() for i in range(8)]


def l7_poses(log, n_start: int = 0, n_end: int | None = None, num_plot_points=None):
    """X_WL7 at each sample n_start..n_end-1 of a joint-position log, and the sample times.

    Args:
        log: A VectorLog-like log of joint positions (7 channels) [rad].
        n_start, n_end: Sample range (Python slice semantics).
        num_plot_points: Subsample to about this many samples (None: all).
    """
    plant = make_controller_plant()
    context = plant.CreateDefaultContext()
    L7 = plant.GetFrameByName(L7_FRAME)
    t = log.sample_times()[n_start:n_end]
    q = log.data().T[n_start:n_end]
    if num_plot_points is not None:
        idx = _subsample(len(t), num_plot_points)
        t, q = t[idx], q[idx]
    poses = []
    for qi in q:
        plant.SetPositions(context, qi)
        poses.append(L7.CalcPoseInWorld(context))
    return poses, t


def q_positions(list_X_WL7: Sequence[RigidTransform], p_L7Q: np.ndarray) -> np.ndarray:
    """p_WQ for each pose of L7, shape (n, 3) [m]."""
    return np.array([X @ np.asarray(p_L7Q, dtype=float) for X in list_X_WL7]).reshape(-1, 3)


def _subsample(n: int, count: int) -> np.ndarray:
    if n <= count:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, count).round().astype(int))


def plot_joint_log(log, legend: str, y_label: str) -> Figure:
    """One subplot per joint of a 7-channel log against time."""
    t = log.sample_times()
    idx = _subsample(len(t), MAX_PLOT_POINTS)
    data = log.data()
    fig, axes = plt.subplots(len(data), 1, figsize=(8, 14), dpi=100, sharex=True)
    for i, (ax, signal) in enumerate(zip(np.atleast_1d(axes), data, strict=True)):
        ax.plot(t[idx], signal[idx], label=f"{legend}{i + 1}")
    return _show_joint_figure(fig, axes, y_label)


def plot_position_logs(command_log, measured_log) -> Figure:
    """Commanded and measured joint positions [deg], one subplot per joint."""
    t = command_log.sample_times()
    idx = _subsample(len(t), MAX_PLOT_POINTS)
    q_cmd, q = np.degrees(command_log.data()), np.degrees(measured_log.data())
    fig, axes = plt.subplots(len(q_cmd), 1, figsize=(8, 14), dpi=100, sharex=True)
    for i, ax in enumerate(np.atleast_1d(axes)):
        ax.plot(t[idx], q_cmd[i][idx], label=f"q_cmd@{i + 1}")
        ax.plot(t[idx], q[i][idx], label=f"q@{i + 1}")
    return _show_joint_figure(fig, axes, "degrees")


def _show_joint_figure(fig: Figure, axes, y_label: str) -> Figure:
    """Labels, legends and grids the per-joint subplots, then shows the figure once."""
    for ax in np.atleast_1d(axes):
        ax.set_ylabel(y_label)
        ax.legend(loc="upper right")
        ax.grid(True)
    np.atleast_1d(axes)[-1].set_xlabel("t (s)")
    fig.tight_layout()
    plt.show()
    return fig
