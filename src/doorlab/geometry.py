"""Door geometry: the left hinge, the handle, the handle's arc and L7's reference along it.

The hinge and handle are read from the cupboard model (so model and task constants cannot
drift apart); the arc's end angle and L7's pitch are the problem set's constants. Frames:
see :mod:`doorlab.frames`.

The handle arc, with tau = t / duration in [0, 1]::

    theta(tau) = theta0 + (angle_end - theta0) * tau
    p_WQ_ref(tau) = p_W_hinge - r_handle * (sin theta, cos theta, 0)
    R_WL7_ref(tau) = RollPitchYaw(0, 3 pi / 4, -(angle_end - theta0) * tau)

theta is the angle of the handle-to-hinge vector (sin theta, cos theta) measured from W's +y
axis towards +x; at theta0 the door is closed, and theta grows as the left door opens.

Believed and true geometry: with ``station.cupboard_yaw_error`` the simulated cupboard stands
turned about the handle's vertical axis. The plans use :func:`scenario_door_geometry` (the
believed cupboard, what the model says); metrics use :func:`true_door_geometry` (where the
handle really moves: same handle, moved hinge, L7's reference turned by the yaw error). With no
yaw error the two are equal.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache, cached_property

import numpy as np
from pydrake.math import RollPitchYaw, RotationMatrix
from pydrake.multibody.plant import MultibodyPlant

from doorlab.config import Scenario
from doorlab.frames import CUPBOARD_MODEL, LEFT_HANDLE_FRAME, LEFT_HINGE

L7_PITCH = 3 * math.pi / 4
"""Pitch of L7's reference orientation [rad]: approach 45 deg downwards (station facts §4)."""


@dataclass(frozen=True)
class DoorGeometry:
    """The left door's hinge and handle arc, in W.

    Attributes:
        p_W_hinge: A point on the left hinge axis at handle height (3,) [m].
        p_W_handle: The handle centre with the door closed (3,) [m].
        angle_end: Handle angle theta at the arc's end [rad].
        yaw_offset: Yaw of the cupboard about W's z axis relative to the believed one [rad];
            it turns L7's reference orientation (0 for the believed geometry).
    """

    p_W_hinge: np.ndarray
    p_W_handle: np.ndarray
    angle_end: float
    yaw_offset: float = 0.0

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

    def p_WQ_ref(self, tau: float) -> np.ndarray:
        """Reference position of Q at tau in [0, 1] (clipped), shape (3,) [m]."""
        # Scalar math: this runs at every control tick of the task-space plans.
        theta = self.theta0 + self.sweep * min(max(float(tau), 0.0), 1.0)
        r = self.r_handle
        x, y, z = self.p_W_hinge
        return np.array([x - r * math.sin(theta), y - r * math.cos(theta), z])

    def R_WL7_ref(self, tau: float) -> RotationMatrix:
        """Reference orientation of L7 at tau in [0, 1] (clipped)."""
        yaw = self.sweep * min(max(float(tau), 0.0), 1.0)
        return RollPitchYaw(0.0, L7_PITCH, self.yaw_offset - yaw).ToRotationMatrix()

    def arc_points(self, n: int = 100) -> np.ndarray:
        """n points along the handle arc from closed to the arc's end, shape (n, 3) [m]."""
        return np.array([self.p_WQ_ref(tau) for tau in np.linspace(0.0, 1.0, n)])

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


def door_geometry_from_plant(plant: MultibodyPlant, *, angle_end_deg: float = 50.0) -> DoorGeometry:
    """Reads the hinge and handle from a finalized plant holding the cupboard (doors closed).

    Args:
        plant: A plant with the ``cupboard`` model welded at X_WC.
        angle_end_deg: Handle angle at the arc's end [deg].
    """
    context = plant.CreateDefaultContext()
    cupboard = plant.GetModelInstanceByName(CUPBOARD_MODEL)
    hinge = plant.GetJointByName(LEFT_HINGE, cupboard)
    hinge.set_angle(context, 0.0)
    X_W_hinge = hinge.frame_on_child().CalcPoseInWorld(context)
    X_W_handle = plant.GetFrameByName(LEFT_HANDLE_FRAME, cupboard).CalcPoseInWorld(context)
    p_W_hinge = X_W_hinge.translation().copy()
    p_W_handle = X_W_handle.translation().copy()
    p_W_hinge[2] = p_W_handle[2]
    return DoorGeometry(p_W_hinge, p_W_handle, math.radians(angle_end_deg))


@cache
def _model_geometry(
    p_WC: tuple[float, float, float] | None, yaw_error: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    from doorlab.station import add_cell  # local: the station module imports this one

    plant = MultibodyPlant(0.0)
    add_cell(plant, p_WC=p_WC, yaw_error=yaw_error)
    plant.Finalize()
    g = door_geometry_from_plant(plant)
    return g.p_W_hinge, g.p_W_handle


def default_door_geometry(
    angle_end_deg: float = 50.0,
    *,
    p_WC: Sequence[float] | None = None,
    yaw_error: float = 0.0,
) -> DoorGeometry:
    """The door geometry of the shipped cupboard model (cached).

    Args:
        angle_end_deg: Handle angle at the arc's end of the believed cupboard [deg].
        p_WC: Believed cupboard position in W (3,) [m]; default: the original placement.
        yaw_error: The cupboard turned by this angle [rad] about the left handle's vertical
            axis (``station.cupboard_yaw_error``): the true geometry, whose arc sweeps the
            same angle as the believed one from its own closed-door angle.
    """
    key = None if p_WC is None else tuple(float(v) for v in p_WC)
    p_W_hinge, p_W_handle = _model_geometry(key)
    believed = DoorGeometry(p_W_hinge.copy(), p_W_handle.copy(), math.radians(angle_end_deg))
    if not yaw_error:
        return believed
    p_W_hinge, p_W_handle = _model_geometry(key, float(yaw_error))
    turned = DoorGeometry(p_W_hinge.copy(), p_W_handle.copy(), 0.0, float(yaw_error))
    return DoorGeometry(
        turned.p_W_hinge, turned.p_W_handle, turned.theta0 + believed.sweep, float(yaw_error)
    )


def scenario_door_geometry(scenario: Scenario) -> DoorGeometry:
    """The door geometry the plans believe: the scenario's arc end and cupboard position."""
    return default_door_geometry(
        scenario.arc.angle_end_deg, p_WC=scenario.station.cupboard_position
    )


def true_door_geometry(scenario: Scenario) -> DoorGeometry:
    """The simulated door's geometry: :func:`scenario_door_geometry` turned by the yaw error."""
    return default_door_geometry(
        scenario.arc.angle_end_deg,
        p_WC=scenario.station.cupboard_position,
        yaw_error=scenario.station.cupboard_yaw_error,
    )
