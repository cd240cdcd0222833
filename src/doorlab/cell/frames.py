"""Frame glossary of doorlab and the model names behind it.

Quantities follow Drake's monogram notation: ``p_WQ`` is the position of point Q measured
from W's origin, expressed in W; ``X_WL7`` the pose of frame L7 in W; ``R_WL7`` its rotation;
``V_WQ`` a spatial velocity; ``Jv_V_WL7q`` the (6, 7) geometric Jacobian of frame L7's spatial
velocity, taken at point Q, with respect to the arm's joint velocities (rows: angular, then
translational, both expressed in W). Compositions pair their letters: ``X_WG = X_WL7 @ X_L7G``.

Frames and points (model names in brackets):

- **W**: world. x forward from the robot base, y to the robot's left, z up; the iiwa base
  (``iiwa_link_0``) sits at W's origin.
- **L7**: the arm's last link (``iiwa_link_7``). Its z axis is the gripper's approach direction.
- **G**: the gripper (WSG-50) body frame (``body`` of model ``wsg``), welded to L7 at ``X_L7G``;
  G's y axis is L7's z axis, the fingers slide along G's x axis (L7's y axis).
- **Q**: the grasp point, fixed in L7 at ``p_L7Q`` (between the finger pads).
- **C**: the cupboard (``cupboard_body`` of model ``cupboard``), welded to W at ``X_WC``.
- **L**: the cupboard's left door (``left_door``); the right door is ``right_door``.
- **hinge**: the left door's vertical hinge axis (joint ``left_door_hinge``); opening the left
  door is a NEGATIVE hinge angle.
- **handle**: the centre of the left door's handle (frame ``left_handle`` on ``left_door``).
"""

from __future__ import annotations

import numpy as np

from doorlab.cell.models import X_L7G, X_WC

__all__ = [
    "ARM_JOINTS",
    "CUPBOARD_MODEL",
    "FINGER_JOINTS",
    "GRIPPER_BODY",
    "GRIPPER_MODEL",
    "IIWA_MODEL",
    "L7_FRAME",
    "LEFT_HANDLE_FRAME",
    "LEFT_HINGE",
    "RIGHT_HINGE",
    "X_L7G",
    "X_WC",
    "p_L7Q",
]

IIWA_MODEL = "iiwa7"
GRIPPER_MODEL = "wsg"
CUPBOARD_MODEL = "cupboard"
L7_FRAME = "iiwa_link_7"
GRIPPER_BODY = "body"
LEFT_HINGE = "left_door_hinge"
RIGHT_HINGE = "right_door_hinge"
LEFT_HANDLE_FRAME = "left_handle"
ARM_JOINTS = tuple(f"iiwa_joint_{i}" for i in range(1, 8))
FINGER_JOINTS = ("left_finger_sliding_joint", "right_finger_sliding_joint")

p_L7Q = np.array([0.0, 0.0, 0.214])
"""Grasp point Q in L7 [m] (station facts §4)."""
