"""The plan runner and the episode: run plans on the station, return named, time-stamped logs.

Timeline of an episode (the original's, station facts §4): hold q_initial, move with a cubic to
the first user plan's start, then the user's plans; every plan stays active for its duration
plus ``PLAN_SETTLE_TIME``; ``extra_time`` follows the last plan.
"""

from __future__ import annotations

import io
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
from pydrake.common.yaml import yaml_dump_typed
from pydrake.geometry import Meshcat
from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
from pydrake.systems.framework import BasicVector, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput

from doorlab.config import Scenario
from doorlab.constants import NUM_JOINTS, Q_HOME
from doorlab.errors import ConfigError, SimulationError
from doorlab.frames import FINGER_JOINTS, LEFT_HINGE, RIGHT_HINGE
from doorlab.plans import ArmState, JointSpacePlan, Plan
from doorlab.station import Station, build_station

_PLAN_LOG_PREFIX = "plan_log."
"""Keys of EpisodeResult.plan_log's columns in a saved ``.npz``."""

PLAN_SETTLE_TIME = 1.0
"""Every plan stays active this long after its duration [s] (the original's timeline)."""


@dataclass(frozen=True)
class ScheduledPlan:
    """A plan with its active window [t_start, t_end) [s] and its gripper setpoint [m]."""

    plan: Plan
    t_start: float
    t_end: float
    gripper_width: float


def make_schedule(
    plans: Sequence[Plan],
    gripper_widths: Sequence[float],
    *,
    q_initial: np.ndarray,
    q_start: np.ndarray,
    scenario: Scenario,
) -> list[ScheduledPlan]:
    """The original timeline: hold, cubic move to ``q_start``, then ``plans``.

    Args:
        plans: The user's plans, in order.
        gripper_widths: Finger separation setpoint for each user plan [m].
        q_initial: Where the arm starts (7,) [rad].
        q_start: Where the first user plan starts (7,) [rad].
        scenario: Durations and the approach gripper width.
    """
    if len(plans) != len(gripper_widths):
        raise ConfigError(
            f"need one gripper setpoint per plan: {len(plans)} plans, "
            f"{len(gripper_widths)} setpoints"
        )
    if not plans:
        raise ConfigError("need at least one plan")
    timeline = scenario.timeline
    approach = scenario.station.gripper.approach_width
    move = JointSpacePlan.cubic(
        [0.0, timeline.approach_duration], np.vstack([q_initial, q_start]), name="move_to_start"
    )
    every = [
        (JointSpacePlan.hold(q_initial, timeline.hold_duration), approach),
        (move, approach),
        *zip(plans, gripper_widths, strict=True),
    ]
    schedule = []
    t = 0.0
    for plan, width in every:
        t_end = t + plan.duration + PLAN_SETTLE_TIME
        schedule.append(ScheduledPlan(plan, t, t_end, float(width)))
        t = t_end
    return schedule


class PlanRunner(LeafSystem):
    """Executes a schedule of plans at a fixed control period (the outer loop).

    Input ports: ``iiwa_position_measured``, ``iiwa_velocity_estimated``,
    ``iiwa_torque_external`` (7 each). Output ports (state outputs, no Python per simulation
    step): ``iiwa_position`` (q_ref), ``iiwa_feedforward_torque`` (tau_ff), ``wsg_position``.
    """

    def __init__(
        self,
        schedule: Sequence[ScheduledPlan],
        *,
        control_period: float,
        q_initial: np.ndarray,
        gripper_width: float,
    ):
        super().__init__()
        self.set_name("plan_runner")
        self._schedule = list(schedule)
        self._starts = [s.t_start for s in self._schedule]
        self._cursor = 0
        self._q = self.DeclareVectorInputPort("iiwa_position_measured", NUM_JOINTS)
        self._v = self.DeclareVectorInputPort("iiwa_velocity_estimated", NUM_JOINTS)
        self._tau_ext = self.DeclareVectorInputPort("iiwa_torque_external", NUM_JOINTS)
        self._q_ref = self.DeclareDiscreteState(BasicVector(np.asarray(q_initial, float)))
        self._tau_ff = self.DeclareDiscreteState(NUM_JOINTS)
        self._wsg = self.DeclareDiscreteState(BasicVector([gripper_width]))
        self.DeclareStateOutputPort("iiwa_position", self._q_ref)
        self.DeclareStateOutputPort("iiwa_feedforward_torque", self._tau_ff)
        self.DeclareStateOutputPort("wsg_position", self._wsg)
        self.DeclarePeriodicDiscreteUpdateEvent(control_period, 0.0, self._tick)

    def active(self, t: float) -> ScheduledPlan:
        """The scheduled plan active at time t [s] (the last one after the schedule ends)."""
        # Ticks come in increasing time: move a cursor instead of searching the schedule.
        while self._cursor + 1 < len(self._schedule) and t >= self._starts[self._cursor + 1]:
            self._cursor += 1
        while self._cursor > 0 and t < self._starts[self._cursor]:
            self._cursor -= 1
        return self._schedule[self._cursor]

    def _tick(self, context, discrete_state) -> None:
        t = context.get_time()
        scheduled = self.active(t)
        state = ArmState(self._q.Eval(context), self._v.Eval(context), self._tau_ext.Eval(context))
        command = scheduled.plan.command(t - scheduled.t_start, state)
        discrete_state.get_mutable_vector(self._q_ref).SetFromVector(command.q_ref)
        discrete_state.get_mutable_vector(self._tau_ff).SetFromVector(command.tau_ff)
        discrete_state.get_mutable_vector(self._wsg).SetAtIndex(0, scheduled.gripper_width)


@dataclass(frozen=True)
class EpisodeResult:
    """Named, time-stamped logs of one episode (all sampled every log period).

    Attributes:
        t: Sample times (n,) [s].
        q_commanded, q_measured: (n, 7) [rad]. v_measured: (n, 7) [rad/s].
        tau_external: Contact torques on the arm joints (n, 7) [N m].
        tau_feedforward: tau_ff sent by the plans (n, 7) [N m].
        tau_commanded: Torque applied by the joints after saturation (n, 7) [N m].
        door_angles: Hinge angles (n, 2) [rad], columns (left, right).
        wsg_width: Finger separation (n,) [m].
        plant_positions: Positions of the whole plant (n, nq), for replays.
        plan_names: Names of the scheduled plans. plan_starts: Their start times (k,) [s].
        arc_window: [t_start, t_end] of the door-opening arc [s], shape (2,).
        wall_time_s: Wall-clock time of the simulation [s].
        scenario_yaml: The scenario that produced the logs.
        plan_log: The arc plan's own per-tick table {channel: (m,)} (empty for plans that
            record nothing); its ``t`` column is the episode's time [s]. The adaptive plan's
            channels are listed in :data:`doorlab.adaptive.LOG_CHANNELS`.
    """

    t: np.ndarray
    q_commanded: np.ndarray
    q_measured: np.ndarray
    v_measured: np.ndarray
    tau_external: np.ndarray
    tau_feedforward: np.ndarray
    tau_commanded: np.ndarray
    door_angles: np.ndarray
    wsg_width: np.ndarray
    plant_positions: np.ndarray
    plan_names: tuple[str, ...]
    plan_starts: np.ndarray
    arc_window: np.ndarray
    wall_time_s: float = 0.0
    scenario_yaml: str = field(default="", compare=False)
    plan_log: dict[str, np.ndarray] = field(default_factory=dict, compare=False)

    @property
    def sim_time_s(self) -> float:
        """Simulated duration [s]."""
        return float(self.t[-1]) if len(self.t) else 0.0

    def window(self, t_start: float, t_end: float) -> np.ndarray:
        """Boolean mask of the samples with t_start <= t <= t_end (tolerates float noise)."""
        eps = 1e-9
        return (self.t >= t_start - eps) & (self.t <= t_end + eps)

    def save(self, path: str | Path) -> None:
        """Writes every channel to an ``.npz`` file (see :meth:`load`)."""
        arrays = {}
        for f in fields(self):
            if f.name == "plan_log":
                continue
            arrays[f.name] = np.asarray(getattr(self, f.name))
        for name, column in self.plan_log.items():
            arrays[f"{_PLAN_LOG_PREFIX}{name}"] = np.asarray(column)
        buffer = io.BytesIO()
        np.savez_compressed(buffer, **arrays)
        Path(path).write_bytes(buffer.getvalue())

    @classmethod
    def load(cls, path: str | Path) -> EpisodeResult:
        """Reads a file written by :meth:`save`."""
        with np.load(path, allow_pickle=False) as data:
            values = {}
            for f in fields(cls):
                if f.name == "plan_log":
                    values[f.name] = {
                        key[len(_PLAN_LOG_PREFIX) :]: data[key]
                        for key in data.files
                        if key.startswith(_PLAN_LOG_PREFIX)
                    }
                    continue
                value = data[f.name]
                if f.name == "plan_names":
                    value = tuple(str(s) for s in value)
                elif f.name in ("wall_time_s",):
                    value = float(value)
                elif f.name == "scenario_yaml":
                    value = str(value)
                values[f.name] = value
        return cls(**values)


def _initialize(station: Station, context, q_initial: np.ndarray, scenario: Scenario) -> None:
    plant = station.plant
    plant_context = plant.GetMyMutableContextFromRoot(context)
    plant.SetPositions(plant_context, station.iiwa, q_initial)
    width = scenario.station.gripper.initial_width
    for joint_name, q in zip(FINGER_JOINTS, (-width / 2, width / 2), strict=True):
        plant.GetJointByName(joint_name, station.wsg).set_translation(plant_context, q)
    left, right = scenario.initial_door_angles()
    plant.GetJointByName(LEFT_HINGE, station.cupboard).set_angle(plant_context, left)
    plant.GetJointByName(RIGHT_HINGE, station.cupboard).set_angle(plant_context, right)
    if station.interpolator is not None:
        station.interpolator.set_initial_position(
            station.interpolator.GetMyMutableContextFromRoot(context), q_initial
        )


def run_episode(
    scenario: Scenario,
    plans: Sequence[Plan],
    gripper_widths: Sequence[float],
    *,
    q_start: np.ndarray,
    q_initial: np.ndarray = Q_HOME,
    arc_plan_index: int | None = None,
    meshcat: Meshcat | None = None,
    realtime_rate: float = 0.0,
) -> EpisodeResult:
    """Simulates one episode: hold, move to ``q_start``, run ``plans``, then ``extra_time``.

    Args:
        scenario: A validated scenario (physics, timeline, gripper).
        plans: The user's plans, in order.
        gripper_widths: Finger separation setpoint for each plan [m].
        q_start: Where the first plan starts (7,) [rad]; the arm moves there first.
        q_initial: Initial arm configuration (7,) [rad].
        arc_plan_index: Index in ``plans`` of the door-opening plan, whose
            [start, start + duration] becomes ``arc_window`` (default: the last plan).
        meshcat: Draw the episode live in this Meshcat.
        realtime_rate: 0 runs as fast as possible; 1 runs at wall-clock speed.

    Returns:
        The logs.

    Raises:
        SimulationError: The physics engine failed or the state became non-finite.
    """
    schedule = make_schedule(
        plans, gripper_widths, q_initial=q_initial, q_start=q_start, scenario=scenario
    )
    timeline = scenario.timeline
    builder = DiagramBuilder()
    station = build_station(scenario.station, meshcat=meshcat)
    station_system = builder.AddSystem(station.diagram)
    runner = builder.AddSystem(
        PlanRunner(
            schedule,
            control_period=timeline.control_period,
            q_initial=q_initial,
            gripper_width=schedule[0].gripper_width,
        )
    )
    for name in ("iiwa_position_measured", "iiwa_velocity_estimated", "iiwa_torque_external"):
        builder.Connect(station_system.GetOutputPort(name), runner.GetInputPort(name))
    for name in ("iiwa_position", "iiwa_feedforward_torque", "wsg_position"):
        builder.Connect(runner.GetOutputPort(name), station_system.GetInputPort(name))
    force_limit = builder.AddSystem(ConstantVectorSource([scenario.station.gripper.force_limit]))
    force_limit.set_name("wsg_force_limit")
    builder.Connect(force_limit.get_output_port(), station_system.GetInputPort("wsg_force_limit"))

    period = timeline.log_period
    channels = {
        "q_commanded": station_system.GetOutputPort("iiwa_position_commanded"),
        "q_measured": station_system.GetOutputPort("iiwa_position_measured"),
        "v_measured": station_system.GetOutputPort("iiwa_velocity_estimated"),
        "tau_external": station_system.GetOutputPort("iiwa_torque_external"),
        "tau_feedforward": runner.GetOutputPort("iiwa_feedforward_torque"),
        "tau_commanded": station_system.GetOutputPort("iiwa_torque_commanded"),
        "door_angles": station_system.GetOutputPort("door_angles"),
        "wsg_state": station_system.GetOutputPort("wsg_state_measured"),
        "plant_state": station_system.GetOutputPort("plant_state"),
    }
    loggers = {name: LogVectorOutput(port, builder, period) for name, port in channels.items()}
    diagram = builder.Build()
    diagram.set_name("doorlab_episode")

    simulator = Simulator(diagram)
    # Every state is discrete (plant, plan runner, gripper): no continuous state to
    # integrate, so the cheapest fixed-step integrator just advances time between events
    # (the default error-controlled one costs ~10 % of an episode for nothing).
    ResetIntegratorFromFlags(simulator, "explicit_euler", scenario.station.time_step)
    context = simulator.get_mutable_context()
    _initialize(station, context, np.asarray(q_initial, float), scenario)
    simulator.set_target_realtime_rate(realtime_rate)
    t_final = schedule[-1].t_end + timeline.extra_time
    if meshcat is not None:
        meshcat.StartRecording()
    wall_start = time.perf_counter()
    try:
        simulator.Initialize()
        simulator.AdvanceTo(t_final)
    except RuntimeError as e:
        message = str(e).splitlines()[0]
        raise SimulationError(
            f"the simulation failed at t = {context.get_time():.3f} s: {message}"
        ) from None
    wall_time = time.perf_counter() - wall_start
    if meshcat is not None:
        meshcat.StopRecording()
        meshcat.PublishRecording()

    logs = {name: logger.FindLog(context) for name, logger in loggers.items()}
    t = logs["q_measured"].sample_times()
    data = {name: log.data().T for name, log in logs.items()}
    nq = station.plant.num_positions()
    arc_index = (len(plans) - 1 if arc_plan_index is None else arc_plan_index) + 2
    arc = schedule[arc_index]
    plan_log = {}
    log_table = getattr(arc.plan, "log_table", None)
    if callable(log_table):
        plan_log = dict(log_table())
        if "t" in plan_log:
            plan_log["t"] = plan_log["t"] + arc.t_start
    result = EpisodeResult(
        t=t,
        q_commanded=data["q_commanded"],
        q_measured=data["q_measured"],
        v_measured=data["v_measured"],
        tau_external=data["tau_external"],
        tau_feedforward=data["tau_feedforward"],
        tau_commanded=data["tau_commanded"],
        door_angles=data["door_angles"],
        wsg_width=data["wsg_state"][:, 0],
        plant_positions=data["plant_state"][:, :nq],
        plan_names=tuple(s.plan.name for s in schedule),
        plan_starts=np.array([s.t_start for s in schedule]),
        arc_window=np.array([arc.t_start, arc.t_start + arc.plan.duration]),
        wall_time_s=wall_time,
        scenario_yaml=yaml_dump_typed(scenario),
        plan_log=plan_log,
    )
    if not np.all(np.isfinite(data["plant_state"])):
        raise SimulationError("the simulation diverged: the plant state became non-finite")
    return result
