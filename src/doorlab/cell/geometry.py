"""Door geometry: the left hinge, the handle, the handle's arc and L7's reference along it.

The hinge and handle are read from the cupboard model (:mod:`doorlab.cell.door_model`, so model and
task constants cannot drift apart); the arc's end angle and L7's pitch are the problem set's
constants. Frames: see :mod:`doorlab.cell.frames`. The arc below is the reference of the problem
set's graded ``calc_p_Q`` and ``calc_R_WL7_ref``: the grader keeps this module out of the
student's sight (the folder's provided ``InterpolateArc`` is the handout's own, in
:mod:`doorlab.pset.handout.task_helpers`).

The handle arc, with tau = t / duration in [0, 1]::

    theta(tau) = theta0 + (angle_end - theta0) * tau
    p_WQ_ref(tau) = p_W_hinge - r_handle * (sin theta, cos theta, 0)
    R_WL7_ref(tau) = RollPitchYaw(0, 3 pi / 4, -(angle_end - theta0) * tau)

theta is the angle of the handle-to-hinge vector (sin theta, cos theta) measured from W's +y
axis towards +x; at theta0 the door is closed, and theta grows as the left door opens.

Believed and true geometry: with ``station.cupboard_yaw_error`` the simulated cupboard stands
turned about the handle's vertical axis, with ``station.cupboard_position_error`` moved. The
plans use :func:`scenario_door_geometry` (the believed cupboard, what the model says); metrics
use :func:`true_door_geometry` (where the handle really moves: the handle moved by the position
error, the hinge by both, L7's reference turned by the yaw error). With no error the two are
equal.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from pydrake.math import RollPitchYaw, RotationMatrix
from pydrake.multibody.plant import MultibodyPlant

from doorlab.cell.door_model import DoorConstants, door_points_from_plant, model_door_points
from doorlab.config import Scenario
from doorlab.constants import ARC_END_DEG, L7_PITCH


@dataclass(frozen=True)
class DoorGeometry(DoorConstants):
    """The left door's hinge and handle arc, in W (the door's constants:
    :class:`~doorlab.cell.door_model.DoorConstants`).

    Attributes:
        yaw_offset: Yaw of the cupboard about W's z axis relative to the believed one [rad];
            it turns L7's reference orientation (0 for the believed geometry).
    """

    yaw_offset: float = 0.0

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

    def V_WQ_ref(self, tau: float, duration: float) -> np.ndarray:
        """Spatial velocity of the reference (L7's orientation, Q's position) when the arc is
        run over ``duration`` [s]: (angular; translational) in W (6,) [rad/s, m/s]; zero
        outside tau in [0, 1]."""
        if not 0.0 <= tau <= 1.0:
            return np.zeros(6)
        theta = self.theta0 + self.sweep * float(tau)
        rate = self.sweep / duration  # [rad/s] theta_dot
        r = self.r_handle
        return np.array(
            [0.0, 0.0, -rate, -r * rate * math.cos(theta), r * rate * math.sin(theta), 0.0]
        )

    def A_WQ_ref(self, tau: float, duration: float) -> np.ndarray:
        """Spatial acceleration of the reference (:meth:`V_WQ_ref`'s derivative), (6,)
        [rad/s^2, m/s^2]: Q's centripetal acceleration towards the hinge; zero outside tau in
        [0, 1]."""
        if not 0.0 <= tau <= 1.0:
            return np.zeros(6)
        theta = self.theta0 + self.sweep * float(tau)
        rate = self.sweep / duration
        r = self.r_handle
        return np.array(
            [0.0, 0.0, 0.0, r * rate**2 * math.sin(theta), r * rate**2 * math.cos(theta), 0.0]
        )

    def arc_points(self, n: int = 100) -> np.ndarray:
        """n points along the handle arc from closed to the arc's end, shape (n, 3) [m]."""
        return np.array([self.p_WQ_ref(tau) for tau in np.linspace(0.0, 1.0, n)])


def door_geometry_from_plant(
    plant: MultibodyPlant, *, angle_end_deg: float = ARC_END_DEG
) -> DoorGeometry:
    """Reads the hinge and handle from a finalized plant holding the cupboard (doors closed).

    Args:
        plant: A plant with the ``cupboard`` model welded at X_WC.
        angle_end_deg: Handle angle at the arc's end [deg].
    """
    p_W_hinge, p_W_handle = door_points_from_plant(plant)
    return DoorGeometry(p_W_hinge, p_W_handle, math.radians(angle_end_deg))


def default_door_geometry(
    angle_end_deg: float = ARC_END_DEG,
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
    p_W_hinge, p_W_handle = model_door_points(key)
    believed = DoorGeometry(p_W_hinge.copy(), p_W_handle.copy(), math.radians(angle_end_deg))
    if not yaw_error:
        return believed
    p_W_hinge, p_W_handle = model_door_points(key, float(yaw_error))
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
    """The simulated door's geometry: :func:`scenario_door_geometry` moved by the position
    error and turned by the yaw error (``station.cupboard_position_error``,
    ``station.cupboard_yaw_error``)."""
    station = scenario.station
    error = station.cupboard_position_error
    return default_door_geometry(
        scenario.arc.angle_end_deg,
        p_WC=[p + e for p, e in zip(station.cupboard_position, error, strict=True)],
        yaw_error=station.cupboard_yaw_error,
    )
