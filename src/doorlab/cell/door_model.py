"""The left door as the cupboard model has it: hinge, handle, and what follows from them.

The problem set's door constants (``open_left_door.py``: ``p_WC_left_hinge``, ``p_WC_handle``,
``r_handle``, ``theta0_hinge``) and its tracking-error helpers are read from here, in the
student's process too. The handle's reference arc and L7's reference orientation along it
(the reference of the graded ``calc_p_Q`` and ``calc_R_WL7_ref``) are not:
:class:`doorlab.cell.geometry.DoorGeometry` adds them, in a module the grader keeps out of the
student's sight (:mod:`doorlab.pset.rules.verdicts`).

theta is the angle of the handle-to-hinge vector (sin theta, cos theta) measured from W's +y
axis towards +x; at theta0 the door is closed, and theta grows as the left door opens.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache, cached_property

import numpy as np
from pydrake.multibody.plant import MultibodyPlant

from doorlab.cell.frames import CUPBOARD_MODEL, LEFT_HANDLE_FRAME, LEFT_HINGE
from doorlab.constants import ARC_END_DEG


@dataclass(frozen=True)
class DoorConstants:
    """The left door's hinge and handle, in W.

    Attributes:
        p_W_hinge: A point on the left hinge axis at handle height (3,) [m].
        p_W_handle: The handle centre with the door closed (3,) [m].
        angle_end: Handle angle theta at the arc's end [rad].
    """

    p_W_hinge: np.ndarray
    p_W_handle: np.ndarray
    angle_end: float

    @cached_property
    def r_handle(self) -> float:
        """Horizontal distance from hinge axis to handle [m]."""
        return float(np.hypot(*(self.p_W_handle - self.p_W_hinge)[:2]))

    @cached_property
    def theta0(self) -> float:
        """Handle angle with the door closed [rad]."""
        d = self.p_W_hinge - self.p_W_handle
        return math.atan2(d[0], d[1])

    @cached_property
    def sweep(self) -> float:
        """Door rotation over the arc, angle_end - theta0 [rad] (positive)."""
        return self.angle_end - self.theta0

    def radial_error(self, p_WQ: np.ndarray) -> np.ndarray:
        """Horizontal distance of Q from the hinge axis minus r_handle [m].

        Args:
            p_WQ: Positions of Q, shape (3,) or (n, 3) [m].

        Returns:
            Signed radial errors, shape () or (n,) [m]: positive outside the arc.
        """
        d = np.asarray(p_WQ)[..., :2] - self.p_W_hinge[:2]
        return np.hypot(d[..., 0], d[..., 1]) - self.r_handle

    def handle_position(self, hinge_angle: float) -> np.ndarray:
        """Handle centre for a left hinge angle [rad] (negative = open), shape (3,) [m]."""
        theta = self.theta0 - hinge_angle
        return self.p_W_hinge - self.r_handle * np.array([math.sin(theta), math.cos(theta), 0.0])


def door_points_from_plant(plant: MultibodyPlant) -> tuple[np.ndarray, np.ndarray]:
    """(hinge axis point at handle height, handle centre) (3,) each [m], in W, read from a
    finalized plant holding the cupboard (doors closed)."""
    context = plant.CreateDefaultContext()
    cupboard = plant.GetModelInstanceByName(CUPBOARD_MODEL)
    hinge = plant.GetJointByName(LEFT_HINGE, cupboard)
    hinge.set_angle(context, 0.0)
    X_W_hinge = hinge.frame_on_child().CalcPoseInWorld(context)
    X_W_handle = plant.GetFrameByName(LEFT_HANDLE_FRAME, cupboard).CalcPoseInWorld(context)
    p_W_hinge = X_W_hinge.translation().copy()
    p_W_handle = X_W_handle.translation().copy()
    p_W_hinge[2] = p_W_handle[2]
    return p_W_hinge, p_W_handle


@cache
def model_door_points(
    p_WC: tuple[float, float, float] | None = None, yaw_error: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`door_points_from_plant` of the shipped cupboard model (cached; do not modify
    the arrays).

    Args:
        p_WC: The cupboard's position in W (3,) [m]; None: the original placement.
        yaw_error: The cupboard turned by this angle [rad] about the left handle's vertical
            axis (``station.cupboard_yaw_error``).
    """
    from doorlab.cell.station import add_cell  # local: the station module is heavy

    plant = MultibodyPlant(0.0)
    add_cell(plant, p_WC=p_WC, yaw_error=yaw_error)
    plant.Finalize()
    return door_points_from_plant(plant)


@cache
def default_door_constants(angle_end_deg: float = ARC_END_DEG) -> DoorConstants:
    """The shipped cupboard's door, the arc ending at ``angle_end_deg`` [deg]."""
    p_W_hinge, p_W_handle = model_door_points()
    return DoorConstants(p_W_hinge.copy(), p_W_handle.copy(), math.radians(angle_end_deg))
