"""Plots of logs and forward kinematics of L7 and Q (provided)."""

from doorlab.pset.handout import task_helpers


def CreateIiwaControllerPlant():
    """The arm model the controllers and IK use; returns (plant, frame indices of links 0-7)."""
    return task_helpers.controller_plant()


def PlotJointLog(iiwa_joint_log, legend, y_label):
    """Plots a 7-channel log (one subplot per joint) and shows it.

    Returns None, as in 2019: a returned figure, the value of a notebook cell, would be shown
    a second time.
    """
    task_helpers.plot_joint_log(iiwa_joint_log, legend, y_label)


def PlotIiwaPositionLog(iiwa_position_command_log, iiwa_position_measured_log):
    """Plots commanded and measured joint positions [deg] and shows them (returns None)."""
    task_helpers.plot_position_logs(iiwa_position_command_log, iiwa_position_measured_log)


def CalcL7PoseInWolrdFrame(iiwa_position_log, num_plot_points=None, n_start=0, n_end=None):
    """Poses of L7 (RigidTransform) for samples n_start..n_end-1 of a joint-position log, and
    their times [s]. (The 2019 spelling of the name is kept.)"""
    return task_helpers.l7_poses(iiwa_position_log, n_start, n_end, num_plot_points)


def CalcQPositionInWorldFrame(list_X_WL7, p_L7Q):
    """p_WQ for each pose of L7, shape (n, 3) [m]."""
    return task_helpers.q_positions(list_X_WL7, p_L7Q)
