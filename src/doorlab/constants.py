"""Named constants with units and sources (station facts, KUKA data sheet, the problem set)."""

from __future__ import annotations

import numpy as np

NUM_JOINTS = 7

# KUKA LBR iiwa 7 R800 data sheet (station facts §1).
JOINT_POSITION_LIMITS = np.array([2.96706, 2.0944, 2.96706, 2.0944, 2.96706, 2.0944, 3.05433])
"""Symmetric joint position limits [rad]."""
JOINT_SPEED_LIMITS = np.deg2rad([98.0, 98.0, 100.0, 130.0, 140.0, 180.0, 180.0])
"""Data-sheet maximum joint speeds [rad/s]."""
JOINT_TORQUE_LIMITS = np.array([176.0, 176.0, 110.0, 110.0, 110.0, 40.0, 40.0])
"""Data-sheet maximum joint torques [N m]."""

# Poses of the problem set (station facts §4).
Q_HOME = np.array([0.0, -0.2136, 0.0, -2.094, 0.0, 0.463, 0.0])
"""Every task starts here [rad]."""
Q_GRASP = np.array([0.0525, 0.3043, -0.0165, -1.5161, -0.0437, 0.5366, 0.0670])
"""The problem set's grasp pose [rad]: the one-shot IK to the left handle of the shipped
cupboard (Q at the handle, L7 at the arc's initial orientation; tests/test_kuka.py solves it
again). KUKA's joint impedance is tuned for the joint inertia here (:mod:`doorlab.kuka`)."""
Q_STATION_DEFAULT = np.array([0.0, 0.6, 0.0, -1.75, 0.0, 1.0, 0.0])
"""The original station's default pose [rad]."""
ARC_END_DEG = 50.0
"""Handle angle about the hinge at the end of the problem set's arc [deg] (its ``angle_end``)."""
L7_PITCH = 3 * np.pi / 4
"""Pitch of L7's reference orientation [rad]: approach 45 deg downwards (station facts §4)."""

# Door initial conditions of the original (station facts §3): exactly 0 or 90 deg gave
# intermittent contact in the original, hence the 1 mrad offsets.
DOOR_ANGLES = {
    "open": (-(np.pi / 2 - 0.001), np.pi / 2 - 0.001),
    "closed": (-0.001, 0.001),
}
"""Initial (left, right) hinge angles [rad] by door state."""
