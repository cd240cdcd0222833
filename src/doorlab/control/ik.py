"""Inverse kinematics: one-shot IK of Q and L7 (the problem set's ``SolveOneShotIk``).

Pointwise IK along a path (task 1's reference solution) is :mod:`doorlab.control.ik_pointwise`, a
module of its own that the grader keeps out of the student's sight.

Solver: SNOPT (shipped in the drake wheel), a sparse SQP that handles the nonlinear position
and orientation constraints directly and converges in a few milliseconds from a warm start;
IPOPT is the fallback if SNOPT is not available. Each knot is warm-started from the previous
solution and a small quadratic cost keeps it near that solution, so the knots form a
continuous branch of the arm's redundancy (no elbow flips between knots). The problem set's
tolerances are hard constraints. Optionally (``centered``) costs on the position and
orientation error pick the exact pose inside them, so a knot's own error becomes negligible
next to the interpolation between knots; the problem set's formulation (and the default along
the arc) accepts any pose within the tolerances.
"""

from __future__ import annotations

import numpy as np
from pydrake.math import RotationMatrix
from pydrake.multibody.inverse_kinematics import InverseKinematics
from pydrake.multibody.plant import MultibodyPlant
from pydrake.solvers import IpoptSolver, SnoptSolver, SolverInterface

from doorlab.cell.frames import L7_FRAME, p_L7Q
from doorlab.constants import NUM_JOINTS
from doorlab.errors import IkError

POSITION_COST_WEIGHT = 1e4
"""Weight of |p_WQ - p_WQ_ref|^2 [1/m^2]: 1 mm off costs 1e-2."""
ORIENTATION_COST_WEIGHT = 1e2
"""Weight of (1 - cos theta) of L7's orientation error: 0.01 rad off costs 5e-3."""
JOINT_COST_WEIGHT = 1e-2
"""Weight of |q - q_guess|^2 [1/rad^2]: breaks the arm's redundancy towards the guess."""


def ik_solver() -> SolverInterface:
    """SNOPT if this drake has it enabled, else IPOPT."""
    snopt = SnoptSolver()
    if snopt.available() and snopt.enabled():
        return snopt
    return IpoptSolver()


def pose_residuals(
    plant: MultibodyPlant, context, q: np.ndarray, p_WQ_ref: np.ndarray, R_WL7_ref: RotationMatrix
) -> tuple[float, float]:
    """(|p_WQ(q) - p_WQ_ref| [m], angle between R_WL7(q) and R_WL7_ref [rad])."""
    plant.SetPositions(context, q)
    X_WL7 = plant.GetFrameByName(L7_FRAME).CalcPoseInWorld(context)
    position = float(np.linalg.norm(X_WL7 @ p_L7Q - p_WQ_ref))
    orientation = float((X_WL7.rotation().inverse() @ R_WL7_ref).ToAngleAxis().angle())
    return position, orientation


def solve_ik(
    plant: MultibodyPlant,
    p_WQ_ref: np.ndarray,
    R_WL7_ref: RotationMatrix,
    q_guess: np.ndarray,
    *,
    position_tolerance: float,
    theta_bound: float,
    centered: bool = True,
    knot: int | None = None,
) -> np.ndarray:
    """One IK: Q within a box of +-position_tolerance around p_WQ_ref, L7 within theta_bound.

    Args:
        plant: The controller plant (7 positions).
        p_WQ_ref: Target for Q (3,) [m]. R_WL7_ref: Target orientation of L7.
        q_guess: Initial guess and the configuration the cost pulls towards (7,) [rad].
        position_tolerance: Half-width of the position box [m].
        theta_bound: Orientation bound [rad].
        centered: Also minimize the pose error inside the tolerances. False solves the
            problem set's feasibility problem: any pose inside them (the solver stops near the
            guess, typically on the tolerance boundary).
        knot: Knot index, for the error message.

    Returns:
        The solution (7,) [rad].

    Raises:
        IkError: No feasible solution (names the knot and the residual).
    """
    L7 = plant.GetFrameByName(L7_FRAME)
    W = plant.world_frame()
    ik = InverseKinematics(plant)
    q = ik.q()
    tol = np.full(3, position_tolerance)
    ik.AddPositionConstraint(L7, p_L7Q, W, p_WQ_ref - tol, p_WQ_ref + tol)
    ik.AddOrientationConstraint(L7, RotationMatrix(), W, R_WL7_ref, theta_bound)
    if centered:
        # Inside the tolerances, prefer the exact pose: the knot then carries no error of
        # its own, and what remains along a path is interpolation between knots.
        ik.AddPositionCost(W, p_WQ_ref, L7, p_L7Q, POSITION_COST_WEIGHT * np.eye(3))
        ik.AddOrientationCost(W, R_WL7_ref, L7, RotationMatrix(), ORIENTATION_COST_WEIGHT)
    prog = ik.get_mutable_prog()
    prog.AddQuadraticErrorCost(JOINT_COST_WEIGHT * np.eye(NUM_JOINTS), q_guess, q)
    result = ik_solver().Solve(prog, q_guess)
    q_sol = result.GetSolution(q)
    if not result.is_success():
        context = plant.CreateDefaultContext()
        position, _ = pose_residuals(plant, context, q_sol, p_WQ_ref, R_WL7_ref)
        where = "one-shot IK" if knot is None else f"IK at knot {knot}"
        raise IkError(
            f"{where} failed ({result.get_solution_result().name}): Q is {1000 * position:.1f} mm "
            f"from the target {np.round(p_WQ_ref, 4).tolist()} m",
            knot=knot,
            residual=position,
        )
    return q_sol
