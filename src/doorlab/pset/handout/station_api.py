"""The 2019 problem set's API (``ManipulationStationSimulator``, problem-set plans, VectorLog-like
logs) implemented on doorlab's station, timeline and plan runner.

The problem-set folder written by ``doorlab pset init`` keeps the original file names; its
files subclass or call what is defined here, so a student reads short files. Nothing here is
student code: the five student functions live in the folder.

A *problem-set plan* has ``duration`` and ``CalcPositionCommand(q_iiwa, q_cmd, v_iiwa,
tau_iiwa, t_plan, control_period)`` / ``CalcTorqueCommand(...)`` (same arguments);
:class:`ProblemSetPlanAdapter` turns one into a doorlab :class:`~doorlab.control.plans.Plan`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
from pydrake.geometry import Meshcat
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import JacobianWrtVariable
from pydrake.trajectories import PiecewisePolynomial

from doorlab.cell.frames import L7_FRAME
from doorlab.cell.station import make_controller_plant
from doorlab.config import Scenario, validate
from doorlab.constants import NUM_JOINTS
from doorlab.errors import ConfigError

if TYPE_CHECKING:
    from doorlab.control.plan_base import ArmState, Command
    from doorlab.episode.result import EpisodeResult

# doorlab.control.plans and doorlab.episode.simulation (which hold or load doorlab's reference
# control laws) are imported where an episode runs, not here: the grader's student process imports
# this module for the plans' base classes and must not load the reference solutions
# (doorlab.pset.isolation.guard).

_ZERO = np.zeros(NUM_JOINTS)


class StudentCodeError(RuntimeError):
    """A student's plan returned something the robot cannot take (wrong shape, NaN)."""


class VectorLogView:
    """What the 2019 notebook reads from a Drake ``VectorLog``: ``data()`` (channels x samples) and
    ``sample_times()`` (samples,) [s]."""

    def __init__(self, t: np.ndarray, data: np.ndarray):
        self._t = np.asarray(t, dtype=float)
        self._data = np.asarray(data, dtype=float)

    def data(self) -> np.ndarray:
        """Logged values, shape (channels, samples)."""
        return self._data

    def sample_times(self) -> np.ndarray:
        """Sample times, shape (samples,) [s]."""
        return self._t

    def num_samples(self) -> int:
        """Number of samples."""
        return len(self._t)


def _checked(value, what: str, t_plan: float) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise StudentCodeError(
            f"{what} returned {type(value).__name__}, expected a ({NUM_JOINTS},) array "
            f"(t_plan = {t_plan:.3f} s)"
        ) from None
    if array.shape != (NUM_JOINTS,):
        raise StudentCodeError(
            f"{what} returned shape {np.shape(value)}, expected ({NUM_JOINTS},) "
            f"(t_plan = {t_plan:.3f} s)"
        )
    if not np.all(np.isfinite(array)):
        raise StudentCodeError(
            f"{what} returned a non-finite value {array.tolist()} (t_plan = {t_plan:.3f} s)"
        )
    return array


class ProblemSetPlanAdapter:
    """A doorlab plan around a problem-set plan: the plan runner's tick calls the plan's
    ``CalcPositionCommand`` and ``CalcTorqueCommand`` with the notebook's arguments.

    ``q_cmd`` (the notebook's "last position command") is the q_ref this adapter sent at the
    previous tick (the measured q at the first tick). Commands are checked: a wrong shape or a
    non-finite value raises :class:`StudentCodeError` naming the method and time.
    """

    def __init__(self, plan, control_period: float, *, name: str | None = None):
        self.plan = plan
        self.name = name or type(plan).__name__
        self.duration = float(plan.duration)
        self.control_period = control_period
        self._q_cmd: np.ndarray | None = None

    def command(self, t: float, state: ArmState) -> Command:
        """Asks the plan for q_ref (7,) [rad] and tau_ff (7,) [N m] at t [s]."""
        from doorlab.control.plan_base import Command

        q_cmd = state.q if self._q_cmd is None else self._q_cmd
        args = (state.q, q_cmd.copy(), state.v, state.tau_external, t, self.control_period)
        q_ref = _checked(self.plan.CalcPositionCommand(*args), "CalcPositionCommand", t)
        tau_ff = _checked(self.plan.CalcTorqueCommand(*args), "CalcTorqueCommand", t)
        self._q_cmd = q_ref
        return Command(q_ref, tau_ff)


class ProblemSetPlanBase:
    """The original's ``PlanBase``: a plan with ``duration`` [s] and the two command methods
    (hold the measured position, no feedforward torque unless overridden)."""

    def __init__(self, trajectory: PiecewisePolynomial | None = None):
        self.traj = trajectory
        self.duration = None if trajectory is None else float(trajectory.end_time())

    def get_duration(self) -> float:
        """Duration of the plan [s]."""
        return self.duration

    def CalcPositionCommand(self, q_iiwa, q_cmd, v_iiwa, tau_iiwa, t_plan, control_period):
        """q_ref (7,) [rad]; by default the last command."""
        return np.asarray(q_cmd, dtype=float)

    def CalcTorqueCommand(self, q_iiwa, q_cmd, v_iiwa, tau_iiwa, t_plan, control_period):
        """tau_ff (7,) [N m]; by default zero."""
        return _ZERO.copy()


class ProblemSetJointSpacePlan(ProblemSetPlanBase):
    """q_ref = trajectory(t_plan), clamped to the trajectory's time span."""

    def __init__(self, trajectory: PiecewisePolynomial):
        if trajectory is None or trajectory.rows() != NUM_JOINTS:
            raise ConfigError(f"JointSpacePlan needs a {NUM_JOINTS}-row PiecewisePolynomial")
        super().__init__(trajectory)

    def CalcPositionCommand(self, q_iiwa, q_cmd, v_iiwa, tau_iiwa, t_plan, control_period):
        """The trajectory's value at t_plan [s]."""
        t = min(max(t_plan, self.traj.start_time()), self.traj.end_time())
        return self.traj.value(t).ravel()


class ArmKinematics:
    """Pose of L7, position of Q and the Jacobian Jv_V_WL7q on the controllers' arm model."""

    def __init__(self, plant: MultibodyPlant | None = None):
        self.plant = plant or make_controller_plant()
        self.context = self.plant.CreateDefaultContext()
        self.L7 = self.plant.GetFrameByName(L7_FRAME)
        self.W = self.plant.world_frame()

    def X_WL7(self, q: np.ndarray) -> RigidTransform:
        """Pose of L7 in W at q (7,) [rad]."""
        self.plant.SetPositions(self.context, q)
        return self.L7.CalcPoseInWorld(self.context)

    def Jv_V_WL7q(self, q: np.ndarray, p_L7Q: np.ndarray) -> np.ndarray:
        """Geometric Jacobian of L7 at Q in W, shape (6, 7) (rows: angular, translational)."""
        self.plant.SetPositions(self.context, q)
        return self.plant.CalcJacobianSpatialVelocity(
            self.context, JacobianWrtVariable.kV, self.L7, p_L7Q, self.W, self.W
        )


class ProblemSetTaskSpacePlanBase(ProblemSetPlanBase):
    """The original's ``IiwaTaskSpacePlan``: kinematics and tracking errors of Q and L7.

    The reference of Q is relative to where Q is when the plan starts (``p_WQ_0``):
    ``p_WQ_ref(t) = p_WQ_0 + calc_p_Q(t / duration)``; L7's is ``calc_R_WL7_ref(t / duration)``.
    """

    def __init__(
        self,
        calc_p_Q: Callable[[float], np.ndarray],
        calc_R_WL7_ref: Callable[[float], RotationMatrix],
        duration: float,
        p_L7Q: np.ndarray,
    ):
        super().__init__()
        self.calc_p_Q = calc_p_Q
        self.calc_R_WL7_ref = calc_R_WL7_ref
        self.duration = float(duration)
        self.p_L7Q = np.asarray(p_L7Q, dtype=float)
        self.p_WQ_0: np.ndarray | None = None
        self.q_iiwa_previous = np.zeros(NUM_JOINTS)
        self._kinematics = ArmKinematics()
        self.plant = self._kinematics.plant
        # Updated by CalcKinematics:
        self.X_WL7: RigidTransform | None = None
        self.p_WQ: np.ndarray | None = None
        self.R_WL7: RotationMatrix | None = None
        self.Jv_WL7q: np.ndarray | None = None

    def UpdatePwq0(self, p_WQ_0: np.ndarray) -> None:
        """Sets where Q was when the plan started (3,) [m]."""
        self.p_WQ_0 = np.array(p_WQ_0, dtype=float)

    def CalcKinematics(self, q_iiwa: np.ndarray, v_iiwa: np.ndarray) -> None:
        """Updates ``X_WL7``, ``p_WQ``, ``R_WL7`` and ``Jv_WL7q`` (6, 7) at q_iiwa (7,) [rad];
        the first call also records ``p_WQ_0``."""
        self.X_WL7 = self._kinematics.X_WL7(q_iiwa)
        self.p_WQ = self.X_WL7 @ self.p_L7Q
        self.R_WL7 = self.X_WL7.rotation()
        self.Jv_WL7q = self._kinematics.Jv_V_WL7q(q_iiwa, self.p_L7Q)
        if self.p_WQ_0 is None:
            self.UpdatePwq0(self.p_WQ)

    def CalcPositionError(self, t_plan: float) -> np.ndarray:
        """e_xyz = p_WQ_ref(t) - p_WQ (3,) [m] (after :meth:`CalcKinematics`)."""
        tau = min(max(t_plan / self.duration, 0.0), 1.0)
        return self.p_WQ_0 + np.asarray(self.calc_p_Q(tau), dtype=float) - self.p_WQ

    def CalcOrientationError(self, t_plan: float) -> RotationMatrix:
        """R_L7L7r = R_WL7^T R_WL7_ref(t) (after :meth:`CalcKinematics`)."""
        tau = min(max(t_plan / self.duration, 0.0), 1.0)
        return self.R_WL7.inverse() @ self.calc_R_WL7_ref(tau)


def problem_set_scenario(
    base: Scenario,
    door_angles: Sequence[float],
    *,
    extra_time: float,
    gripper_setpoint_initial: float,
) -> Scenario:
    """``base`` with the 2019 notebook's ``RunSimulation`` arguments: the (left, right) hinge angles
    [rad], the time simulated after the last plan [s] and the initial finger separation [m]
    (validated)."""
    scenario = replace(
        base,
        door_angles=[float(door_angles[0]), float(door_angles[1])],
        timeline=replace(base.timeline, extra_time=float(extra_time)),
        station=replace(
            base.station,
            gripper=replace(base.station.gripper, approach_width=float(gripper_setpoint_initial)),
        ),
    )
    validate(scenario)
    return scenario


class StationRun:
    """The problem set's ``RunSimulation``, on doorlab's station and timeline."""

    def __init__(self, scenario: Scenario | None = None):
        self.scenario = scenario or Scenario()
        self.result: EpisodeResult | None = None
        self.last_scenario: Scenario | None = None
        self.meshcat: Meshcat | None = None

    def run(
        self,
        q0_iiwa: np.ndarray,
        door_angles: Sequence[float],
        plan_list: Sequence,
        gripper_setpoint_list: Sequence[float],
        *,
        extra_time: float,
        real_time_rate: float,
        meshcat: Meshcat | None,
        gripper_setpoint_initial: float,
    ) -> tuple:
        """Runs the plans after the original's hold and move-to-start; returns the problem set's
        six outputs (four arm logs, the plant-position log, plan start times (k + 3,) [s])."""
        if not plan_list:
            raise ConfigError("plan_list is empty: give at least one plan")
        first = plan_list[0]
        if getattr(first, "traj", None) is None:
            raise ConfigError(
                "the first plan must be a JointSpacePlan (its trajectory's start is where the "
                "arm moves before the plans run)"
            )
        from doorlab.episode.simulation import run_episode

        scenario = problem_set_scenario(
            self.scenario,
            door_angles,
            extra_time=extra_time,
            gripper_setpoint_initial=gripper_setpoint_initial,
        )
        self.last_scenario = scenario
        period = scenario.timeline.control_period
        plans = [ProblemSetPlanAdapter(p, period) for p in plan_list]
        result = run_episode(
            scenario,
            plans,
            [float(w) for w in gripper_setpoint_list],
            q_start=first.traj.value(first.traj.start_time()).ravel(),
            q_initial=np.asarray(q0_iiwa, dtype=float),
            meshcat=meshcat,
            realtime_rate=real_time_rate,
        )
        self.result = result
        t = result.t
        logs = (
            VectorLogView(t, result.q_commanded.T),
            VectorLogView(t, result.q_measured.T),
            VectorLogView(t, result.tau_external.T),
            VectorLogView(t, result.v_measured.T),
            # Positions of the whole plant (the original logged positions and velocities).
            VectorLogView(t, result.plant_positions.T),
        )
        schedule_end = result.plan_starts[-1] + plans[-1].duration + 1.0
        t_plan = np.append(result.plan_starts, schedule_end)
        return (*logs, t_plan)

    def run_real_robot(
        self,
        plan_list: Sequence,
        gripper_setpoint_list: Sequence[float],
        *,
        extra_time: float,
        lcm_url: str | None = None,
        wait: float = 5.0,
        yes: bool = False,
        link=None,
    ) -> tuple:
        """The problem set's ``RunRealRobot``: the same plans on the real arm over LCM, through the
        path of ``doorlab run --hardware`` (:mod:`doorlab.hardware`), from where the arm is.

        It waits ``wait`` [s] for the driver on ``lcm_url`` (default: Drake's), prints the plan
        and asks before the arm moves (``yes`` skips the question), then answers every status
        with a checked command (``station.safety``'s limits, the 50 ms watchdog).

        Returns:
            The 2019 API's five outputs: (iiwa_position_command_log,
            iiwa_position_measured_log, iiwa_velocity_estimated_log,
            iiwa_external_torque_log, t_plan), logs like :meth:`run`'s. (The real cell has
            no plant state to log; ``self.result`` holds every channel.)

        Raises:
            NoDriver: No status within ``wait``. SafetyStop, DriverLost: The run stopped
                (``self.result`` holds the logs up to the stop). KeyboardInterrupt: Ctrl-C
                stopped it (the same). ConfigError: Not confirmed, or bad plans.
        """
        from doorlab.errors import DriverLost, SafetyStop
        from doorlab.hardware.episode import run_hardware_episode
        from doorlab.hardware.link import DriverLink
        from doorlab.hardware.run import describe_plan

        if not plan_list or getattr(plan_list[0], "traj", None) is None:
            raise ConfigError(
                "the first plan must be a JointSpacePlan (the arm moves to its start)"
            )
        scenario = replace(
            self.scenario, timeline=replace(self.scenario.timeline, extra_time=float(extra_time))
        )
        validate(scenario)
        self.last_scenario = scenario
        link = link or DriverLink(url=lcm_url)
        first = link.wait_first_status(wait)
        first_plan = plan_list[0]
        q_start = first_plan.traj.value(first_plan.traj.start_time()).ravel()
        print(describe_plan(scenario, q_start, first, link.url), flush=True)
        if not yes and input("Move the arm? [y/N] ").strip().lower() not in ("y", "yes"):
            raise ConfigError("not confirmed: nothing moved")
        period = scenario.timeline.control_period
        plans = [ProblemSetPlanAdapter(p, period) for p in plan_list]
        widths = [float(w) for w in gripper_setpoint_list]
        outcome = run_hardware_episode(
            scenario, plans, widths, q_start=q_start, link=link, wait=wait
        )
        self.result = result = outcome.result
        if outcome.interrupt is not None:
            raise outcome.interrupt
        if outcome.violation is not None:
            raise SafetyStop(outcome.violation, result=result)
        if outcome.status != "ok":
            raise DriverLost(outcome.message, result=result)
        t = result.t
        schedule_end = result.plan_starts[-1] + plans[-1].duration + 1.0
        return (
            VectorLogView(t, result.q_commanded.T),
            VectorLogView(t, result.q_measured.T),
            VectorLogView(t, result.v_measured.T),
            VectorLogView(t, result.tau_external.T),
            np.append(result.plan_starts, schedule_end),
        )


_MESHCAT: Meshcat | None = None


def shared_meshcat() -> Meshcat:
    """One Drake Meshcat per process (on localhost), started on first use."""
    global _MESHCAT
    if _MESHCAT is None:
        _MESHCAT = Meshcat()
        print(f"Meshcat: {_MESHCAT.web_url()}", flush=True)
    return _MESHCAT
