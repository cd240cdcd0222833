"""What the lab's iiwa does between a command and the joints: kuka_driver's cycle and filter,
its external-torque freeze, and KUKA's joint impedance (pure functions and constants).

Read from RobotLocomotion/drake-iiwa-driver (no code of it is copied here):

- ``kuka-driver/kuka_driver.cc``: one loop per FRI packet, every ``--time_step`` (5 ms, the
  Java application's send period). On each packet it first handles the LCM commands that have
  arrived (the subscription keeps one: the newest counts), then in ``command()`` reads the
  robot state of this cycle, checks the external torques, hands FRI the newest command
  (``joint_position`` clamped to the joint limits less 1 deg, ``joint_torque`` in torque
  mode) and only then publishes ``IIWA_STATUS`` with this cycle's state. The command that
  answers status k therefore reaches the arm at cycle k + 1, one period after the state it
  was computed from. ``joint_velocity_estimated`` is a low-pass (``--velocity_filter_cutoff``,
  40 Hz) of the finite difference of the measured positions over the step. If any
  |joint_torque_external| exceeds ``--ext_trq_limit`` (60 N m) times (1, 1, 1, 0.5, 0.2, 0.2,
  0.1), it prints the robot state and throws ("Robot0 is in an unsafe state."): the process
  ends.
- ``kuka-driver/low_pass_filter.h``: ``DiscreteTimeLowPassFilter``, val = alpha val +
  (1 - alpha) input with alpha = 1 - dt / (dt + RC), RC = 1 / (2 pi f_cutoff).
- ``kuka-driver/sunrise_1.14/DrakeFRITorqueDriver.java``: the arm runs KUKA's
  ``JointImpedanceControlMode(1000, 1000, 1000, 500, 500, 500, 500)`` [N m/rad] with
  ``setDampingForAllJoints(1.0)`` (KUKA's dimensionless damping, 0.1-1.0) and a 5 ms send
  period.

KUKA's damping in N m s/rad: KUKA does not publish how its controller turns the dimensionless
value into a joint damping. doorlab takes the standard second-order form D_i = 2 d_i
sqrt(K_i M_ii), with M_ii the model's joint inertia (links, the lumped gripper and the motors'
reflected inertia) at the problem set's grasp pose (:func:`kuka_damping`); the real arm's guide
(docs/guides/real-arm.md, the arm preset) says how much the results move if M_ii follows the
arm instead.
"""

from __future__ import annotations

import math

import numpy as np

from doorlab.constants import NUM_JOINTS

CYCLE_PERIOD = 0.005
"""kuka_driver's cycle [s]: one FRI packet, one command applied, one IIWA_STATUS
(``--time_step``; ``DrakeFRITorqueDriver``'s ``setSendPeriodMilliSec(5)``)."""
WSG_COMMAND_PERIOD = 0.05
"""A hardware client's ``SCHUNK_WSG_COMMAND`` period [s] (20 Hz, schunk_driver's rate)."""
VELOCITY_FILTER_CUTOFF = 40.0
"""kuka_driver's ``--velocity_filter_cutoff`` [Hz]."""
EXTERNAL_TORQUE_LIMIT = 60.0
"""kuka_driver's ``--ext_trq_limit`` [N m]."""
EXTERNAL_TORQUE_SCALE = np.array([1.0, 1.0, 1.0, 0.5, 0.2, 0.2, 0.1])
"""kuka_driver's per-joint scale of ``--ext_trq_limit`` (``kJointTorqueSafetyMarginScale``)."""
DRIVER_JOINT_LIMITS = np.deg2rad([170.0, 120.0, 170.0, 120.0, 170.0, 120.0, 175.0])
"""The joint limits kuka_driver clamps commands to, before the margin [rad]."""
JOINT_LIMIT_MARGIN = np.deg2rad(1.0)
"""kuka_driver clamps ``joint_position`` to the joint limits less this [rad]."""
KUKA_STIFFNESS = (1000.0, 1000.0, 1000.0, 500.0, 500.0, 500.0, 500.0)
"""``DrakeFRITorqueDriver``'s joint stiffness [N m/rad]."""
KUKA_DAMPING = (1.0,) * NUM_JOINTS
"""``DrakeFRITorqueDriver``'s damping (KUKA's dimensionless value, ``setDampingForAllJoints``)."""
DRIVER_HOLD_DAMPING = (50.0, 50.0, 50.0, 50.0, 35.0, 35.0, 35.0)
"""kuka_driver's ``kTorqueOnlyKd`` [N m s/rad]: the damping of its own joint hold in
torque-only mode (with ``kTorqueOnlyKp``, KUKA's stiffness), the one damping in N m s/rad that
drake-iiwa-driver writes down (``station.inner_loop.kuka_damping_model: driver_kd``)."""
STRIBECK_VELOCITY = 0.01
"""Where the joints' friction falls from stiction to Coulomb friction [rad/s] (the Stribeck
curve's velocity, ``station.arm``); an assumption, as no source gives the iiwa's."""
STRIBECK_ONSET = 3.0
"""The Stribeck decay starts at this many v_eps (the regularizing tanh's width): there tanh is
0.995, so the friction's largest value is the stiction."""
MAX_LATENCY = 0.004
"""Largest ``station.arm.latency`` [s]: with its jitter a command must act within the cycle
(5 ms) that follows the one that received it."""


def external_torque_limits(ext_trq_limit: float = EXTERNAL_TORQUE_LIMIT) -> np.ndarray:
    """|external torque| per joint above which kuka_driver stops (7,) [N m]."""
    return ext_trq_limit * EXTERNAL_TORQUE_SCALE


def filter_alpha(cutoff_hz: float, dt: float = CYCLE_PERIOD) -> float:
    """The weight of the previous value in kuka_driver's low-pass [-] (0 < alpha < 1).

    Args:
        cutoff_hz: Cut-off frequency [Hz] (> 0). dt: Step [s].
    """
    rc = 1.0 / (2.0 * math.pi * cutoff_hz)
    return 1.0 - dt / (dt + rc)


def filtered_velocity(
    q: np.ndarray, *, cutoff_hz: float = VELOCITY_FILTER_CUTOFF, dt: float = CYCLE_PERIOD
) -> np.ndarray:
    """kuka_driver's ``joint_velocity_estimated`` for measured positions q (n, 7), one row per
    cycle [rad/s]: the first row 0 (no previous packet), then v_k = alpha v_{k-1} + (1 - alpha)
    (q_k - q_{k-1}) / dt."""
    q = np.asarray(q, float)
    alpha = filter_alpha(cutoff_hz, dt)
    v = np.zeros_like(q)
    for k in range(1, len(q)):
        v[k] = alpha * v[k - 1] + (1.0 - alpha) * (q[k] - q[k - 1]) / dt
    return v


def filter_gain(cutoff_hz: float, dt: float = CYCLE_PERIOD) -> np.ndarray:
    """The filter as one matrix (7, 21): v_k = G [q_k; q_{k-1}; v_{k-1}] (for a C++ gain)."""
    alpha = filter_alpha(cutoff_hz, dt)
    eye = np.eye(NUM_JOINTS)
    slope = (1.0 - alpha) / dt
    return np.hstack([slope * eye, -slope * eye, alpha * eye])


def clamp_command(q: np.ndarray) -> np.ndarray:
    """kuka_driver's clamp of ``joint_position``: within the joint limits less 1 deg [rad]."""
    limit = DRIVER_JOINT_LIMITS - JOINT_LIMIT_MARGIN
    return np.clip(np.asarray(q, float), -limit, limit)


def stribeck_friction(
    v: np.ndarray,
    coulomb: np.ndarray,
    stiction: np.ndarray,
    v_eps: np.ndarray,
    compensation: np.ndarray | float = 0.0,
) -> np.ndarray:
    """The joints' friction torque at joint speeds v [N m] (same shape as v): -(1 - w) (Fc +
    (Fs - Fc) exp(-(max(|v| - 3 v_eps, 0)/vs)^2)) tanh(v / v_eps), vs =
    :data:`STRIBECK_VELOCITY` (:data:`STRIBECK_ONSET`).

    The tanh regularizes the sign at rest over ``v_eps`` (the simulator evaluates the torque
    at the step's start, so its slope Fs / v_eps must stay below M_ii / h:
    :func:`doorlab.cell.station.friction_regularization`).

    Args:
        v: Joint speeds [rad/s]. coulomb, stiction: Fc, Fs [N m]. v_eps: [rad/s] (> 0).
        compensation: w in [0, 1], the share KUKA's friction observer cancels.
    """
    v = np.asarray(v, float)
    fc, fs = np.asarray(coulomb, float), np.asarray(stiction, float)
    eps = np.asarray(v_eps, float)
    slide = np.maximum(np.abs(v) - STRIBECK_ONSET * eps, 0.0) / STRIBECK_VELOCITY
    level = fc + (fs - fc) * np.exp(-(slide**2))
    return -(1.0 - np.asarray(compensation, float)) * level * np.tanh(v / eps)


def kuka_damping(
    stiffness: np.ndarray, damping_ratio: np.ndarray, inertia: np.ndarray
) -> np.ndarray:
    """KUKA's dimensionless damping as N m s/rad: D_i = 2 d_i sqrt(K_i M_ii) (7,).

    Args:
        stiffness: K [N m/rad] (7,). damping_ratio: KUKA's d (7,) [-].
        inertia: The joint inertia M_ii the loop is tuned for [kg m^2] (7,).
    """
    k = np.asarray(stiffness, float)
    return 2.0 * np.asarray(damping_ratio, float) * np.sqrt(k * np.asarray(inertia, float))
