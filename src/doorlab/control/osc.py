"""Operational-space impedance (Khatib 1987) along the handle's arc: the ``osc`` controller.

The law (:func:`osc_law`, pure: matrices in, torques out) and its plan
(:class:`OperationalSpacePlan`: the controller plant's M(q), J, C(q, v) v and J_dot v at each
tick, q_ref = q).

With q_ref = q the inner loop leaves the arm with M q_ddot + C q_dot = tau_ff - D q_dot +
tau_ext (it cancels gravity, its spring acts on nothing, its damping D stays). The task
acceleration at Q is x_ddot = J q_ddot + J_dot q_dot, so tau_ff = J^T F with::

    F = Lambda (a* - J_dot q_dot) + J_bar^T (C q_dot + c D q_dot),
    a* = a_ref + Kp e + Kd e_dot,    Lambda = (J M^-1 J^T)^-1,    J_bar^T = Lambda J M^-1

makes the error obey e_ddot + Kd e_dot + Kp e = -J M^-1 tau_ext (c = 1): a second-order
system with the same natural frequency and damping in every task direction and every
configuration, pushed only by contact. The problem set's impedance plan (tau_ff = J^T F,
F = K e) has neither Lambda nor the damping term: its spring drags the arm's inertia and the
inner loop's damping D, so its error depends on the direction, the configuration and D.

Spatial vectors are (angular; translational), as Drake's; e = (theta n; p_WQ_ref - p_WQ) in W.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import JacobianWrtVariable

from doorlab.cell.frames import p_L7Q
from doorlab.cell.geometry import DoorGeometry
from doorlab.config import OscPlanConfig
from doorlab.control.laws import PoseError
from doorlab.control.plans import ArmState, Command, _TaskSpacePlan

_KV = JacobianWrtVariable.kV


def _spd_solve(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A^-1 B for a symmetric positive definite A (Cholesky); the pseudo-inverse if A is
    singular (a singular arm: the directions it cannot move in get no force)."""
    try:
        L = np.linalg.cholesky(A)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(A, hermitian=True) @ B
    return np.linalg.solve(L.T, np.linalg.solve(L, B))


def task_space_inertia(J: np.ndarray, M: np.ndarray) -> np.ndarray:
    """Lambda = (J M^-1 J^T)^-1, the inertia the arm shows at the task point (m, m).

    Args:
        J: Task Jacobian (m, n), m <= n, full row rank away from singularities.
        M: Joint-space mass matrix (n, n), symmetric positive definite [kg m^2].

    Returns:
        Lambda (m, m) [kg, kg m, kg m^2 by block]; the pseudo-inverse of J M^-1 J^T at a
        singularity.
    """
    J = np.asarray(J, dtype=float)
    inverse = J @ _spd_solve(np.asarray(M, dtype=float), J.T)
    return _spd_solve(inverse, np.eye(J.shape[0]))


class OscCommand(NamedTuple):
    """Output of :func:`osc_law`.

    Attributes:
        tau_ff: Feedforward joint torques (n,) [N m], clipped to the torque limit.
        F: The task-space force before J^T (m,) [N m; N]. Lambda: The task-space inertia (m, m).
    """

    tau_ff: np.ndarray
    F: np.ndarray
    Lambda: np.ndarray


def osc_law(
    error: np.ndarray,
    error_rate: np.ndarray,
    J: np.ndarray,
    M: np.ndarray,
    *,
    kp: np.ndarray,
    kd: np.ndarray,
    torque_limit: float,
    a_ref: np.ndarray | None = None,
    Jdot_v: np.ndarray | None = None,
    Cv: np.ndarray | None = None,
    damping_torque: np.ndarray | None = None,
) -> OscCommand:
    """Operational-space impedance: tau_ff = J^T F (module docstring).

    F = Lambda (a_ref + kp e + kd e_dot - Jdot_v) + J_bar^T (Cv + damping_torque), with
    J_bar^T = Lambda J M^-1 the dynamically consistent generalized inverse's transpose.

    Args:
        error: Task error e (m,): (theta n [rad]; position [m]) for the pose task.
        error_rate: Its rate e_dot (m,): V_ref - J v [rad/s; m/s].
        J: Task Jacobian (m, n). M: Mass matrix (n, n) [kg m^2].
        kp: Stiffness per task row (m,) or a scalar [1/s^2] (acceleration per unit error).
        kd: Damping per task row (m,) or a scalar [1/s].
        torque_limit: Symmetric clip on each joint torque [N m].
        a_ref: The reference's task acceleration (m,) [rad/s^2; m/s^2] (default 0).
        Jdot_v: The task's bias acceleration J_dot v (m,) (default 0).
        Cv: The Coriolis and centripetal torques C(q, v) v (n,) [N m] (default 0).
        damping_torque: Joint torques the inner loop's damping takes out of the motion, to be
            put back in the task's directions only: c D v (n,) [N m] (default 0).

    Returns:
        tau_ff, F and Lambda.
    """
    J = np.asarray(J, dtype=float)
    M = np.asarray(M, dtype=float)
    m, n = J.shape
    Lambda = task_space_inertia(J, M)
    a = np.multiply(kp, error) + np.multiply(kd, error_rate)
    if a_ref is not None:
        a = a + a_ref
    if Jdot_v is not None:
        a = a - Jdot_v
    F = Lambda @ a
    joint = np.zeros(n)
    if Cv is not None:
        joint = joint + Cv
    if damping_torque is not None:
        joint = joint + damping_torque
    if np.any(joint):
        F = F + Lambda @ (J @ _spd_solve(M, joint))  # J_bar^T = Lambda J M^-1
    tau = J.T @ F
    return OscCommand(np.minimum(np.maximum(tau, -torque_limit), torque_limit), F, Lambda)


def osc_gains(config: OscPlanConfig) -> tuple[np.ndarray, np.ndarray]:
    """(Kp, Kd) per task row (6,) [1/s^2, 1/s] from the natural frequencies and damping."""
    wn = np.array([config.wn_rotation] * 3 + [config.wn_translation] * 3)
    return wn**2, 2.0 * config.zeta * wn


class OperationalSpacePlan(_TaskSpacePlan):
    """``osc``: operational-space impedance along the arc, q_ref = measured q.

    Args:
        geometry: The (believed) door. duration: The arc's duration [s].
        controller_plant: The controllers' arm model (its own context: M, J, C v, J_dot v).
        config: Gains. joint_damping: The inner loop's joint damping D (7,) [N m s/rad]
            (:func:`doorlab.cell.station.joint_damping`; zeros for a loop without one).
    """

    def __init__(
        self,
        geometry: DoorGeometry,
        duration: float,
        controller_plant: MultibodyPlant,
        config: OscPlanConfig,
        joint_damping: np.ndarray,
    ):
        super().__init__(geometry, duration, controller_plant, "osc")
        self.config = config
        self.kp, self.kd = osc_gains(config)
        self.damping = config.damping_compensation * np.asarray(joint_damping, dtype=float)

    def command(self, t: float, state: ArmState) -> Command:
        """tau_ff from the pose error, its rate and the arm's dynamics at the measured state."""
        error, J = self.error_and_jacobian(t, state.q)
        plant, context = self._plant, self._context
        v = np.asarray(state.v, dtype=float)
        plant.SetVelocities(context, v)
        M = plant.CalcMassMatrix(context)
        Cv = plant.CalcBiasTerm(context)
        Jdot_v = plant.CalcBiasSpatialAcceleration(
            context, _KV, self._L7, p_L7Q, self._W, self._W
        ).get_coeffs()
        tau = t / self.duration
        command = osc_law(
            _stacked(error),
            self.geometry.V_WQ_ref(tau, self.duration) - J @ v,
            J,
            M,
            kp=self.kp,
            kd=self.kd,
            torque_limit=self.config.torque_limit,
            a_ref=self.geometry.A_WQ_ref(tau, self.duration),
            Jdot_v=Jdot_v,
            Cv=Cv,
            damping_torque=self.damping * v,
        )
        return Command(np.array(state.q, dtype=float), command.tau_ff)


def _stacked(error: PoseError) -> np.ndarray:
    return np.concatenate((error.theta_n_W, error.e_xyz_W))
