"""Pointwise IK along a path: IK at knot points, each warm-started from the last (task 1's
reference solution; the problem set's students write their own ``InverseKinPointwise``, so
the grader keeps this module out of their process's sight: :mod:`doorlab.pset.rules.verdicts`).

The one-shot IK it solves at each knot is :func:`doorlab.control.ik.solve_ik` (see there for the
solver and the costs).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pydrake.math import RotationMatrix
from pydrake.multibody.plant import MultibodyPlant

from doorlab.control.ik import ik_solver, pose_residuals, solve_ik
from doorlab.errors import IkError


@dataclass(frozen=True)
class IkResult:
    """Pointwise IK along a path.

    Attributes:
        times: Knot times (n,) [s]. q_knots: Joint solutions (n, 7) [rad].
        position_residuals: |p_WQ(q) - p_WQ_ref| at each knot (n,) [m].
        orientation_residuals: Angle between R_WL7(q) and the reference (n,) [rad].
        solver: Name of the solver used.
    """

    times: np.ndarray
    q_knots: np.ndarray
    position_residuals: np.ndarray
    orientation_residuals: np.ndarray
    solver: str


def pointwise_ik(
    plant: MultibodyPlant,
    p_WQ_ref: Callable[[float], np.ndarray],
    R_WL7_ref: Callable[[float], RotationMatrix],
    *,
    duration: float,
    num_knots: int,
    q_guess: np.ndarray,
    position_tolerance: float,
    theta_bound: float,
    centered: bool = False,
) -> IkResult:
    """IK at knots tau = i / (num_knots - 1) along a path, each warm-started from the last.

    Args:
        plant: The controller plant.
        p_WQ_ref, R_WL7_ref: The path as functions of tau in [0, 1].
        duration: Time of the last knot [s].
        num_knots: Number of knots (>= 2).
        q_guess: Initial guess of the first knot (7,) [rad].
        position_tolerance: [m]. theta_bound: [rad].
        centered: See :func:`solve_ik`. The default (False) is the problem set's formulation.

    Raises:
        IkError: A knot has no solution.
    """
    if num_knots < 2:
        raise IkError(f"pointwise IK needs at least 2 knots, got {num_knots}")
    context = plant.CreateDefaultContext()
    taus = np.linspace(0.0, 1.0, num_knots)
    q_knots, pos_res, rot_res = [], [], []
    guess = np.asarray(q_guess, dtype=float)
    for i, tau in enumerate(taus):
        p_ref, R_ref = p_WQ_ref(tau), R_WL7_ref(tau)
        guess = solve_ik(
            plant,
            p_ref,
            R_ref,
            guess,
            position_tolerance=position_tolerance,
            theta_bound=theta_bound,
            centered=centered,
            knot=i,
        )
        position, orientation = pose_residuals(plant, context, guess, p_ref, R_ref)
        q_knots.append(guess)
        pos_res.append(position)
        rot_res.append(orientation)
    return IkResult(
        times=taus * duration,
        q_knots=np.array(q_knots),
        position_residuals=np.array(pos_res),
        orientation_residuals=np.array(rot_res),
        solver=ik_solver().solver_id().name(),
    )
