"""A frozen copy of ``doorlab/simulation.py`` at main 2f990e7 (before issue 18 split it into
schedule, plan_runner, episode and simulation): the reference the split episode must match
bit for bit (tests/test_episode_split.py). Do not edit it (its imports follow the modules'
moves of issue 28, nothing else); only that test imports it.

Its original docstring:

The plan runner and the episode: run plans on the station, return named, time-stamped logs.

Timeline of an episode (the original's, station facts §4): hold q_initial, move with a cubic to
the first user plan's start, then the user's plans; every plan stays active for its duration
plus ``PLAN_SETTLE_TIME``; ``extra_time`` follows the last plan.
"""

from __future__ import annotations

import io
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
from pydrake.common.yaml import yaml_dump_typed
from pydrake.geometry import Meshcat
from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import (
    Adder,
    ConstantVectorSource,
    LogVectorOutput,
    Multiplexer,
    TrajectorySource,
)
from pydrake.trajectories import PiecewisePolynomial

from doorlab.cell.frames import FINGER_JOINTS, LEFT_HINGE, RIGHT_HINGE
from doorlab.cell.station import Station, build_station
from doorlab.config import Scenario
from doorlab.constants import NUM_JOINTS, Q_HOME
from doorlab.control.plans import ArmState, JointSpacePlan, Plan
from doorlab.errors import ConfigError, SimulationError

HINGES = (LEFT_HINGE, RIGHT_HINGE)

_SEPARATE_LOGGERS = False
"""Also log the station's channels one logger each, as the 353b732 design did (its cost,
for :mod:`doorlab.studies.legacy`; the logs come from the one multiplexed logger either way)."""
_SEPARATE_LOG_PORTS = (
    "iiwa_position_commanded",
    "iiwa_position_measured",
    "iiwa_velocity_estimated",
    "iiwa_torque_external",
    "iiwa_torque_commanded",
    "door_angles",
    "wsg_state_measured",
    "plant_state",
)

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


def joint_space_prefix(schedule: Sequence[ScheduledPlan]) -> int:
    """How many scheduled plans, from the start, are pure joint trajectories (no feedback)."""
    k = 0
    while k < len(schedule) and isinstance(schedule[k].plan, JointSpacePlan):
        k += 1
    return k


def _first_tick(t: float, period: float) -> float:
    """The first tick k * period at or after t [s] (float noise tolerated)."""
    return math.ceil(t / period - 1e-9) * period


def _tick_lag(time_step: float, period: float) -> float:
    """How long after a tick its command may switch on without missing a plant step [s].

    Ticks and plant steps share the grid of g = gcd(time_step, period); a discrete update at
    tick t_k reaches the plant at its first step after t_k, which is at least g later: a
    switch at t_k + g / 2 does the same, clear of float noise on either side.
    """
    ns = math.gcd(round(time_step * 1e9), round(period * 1e9))
    return 0.5 * ns * 1e-9


def prefix_trajectory(
    schedule: Sequence[ScheduledPlan], k: int, t_final: float
) -> PiecewisePolynomial:
    """The q_ref of the first ``k`` (joint-space) scheduled plans as one trajectory in episode
    time: each plan's trajectory from its start, its end value held until the next plan (the
    last one's until ``t_final``) [rad].

    Args:
        schedule: The episode's schedule. k: :func:`joint_space_prefix` of it (>= 1).
        t_final: Where the trajectory ends [s].
    """
    pieces: list[PiecewisePolynomial] = []
    for i, scheduled in enumerate(schedule[:k]):
        trajectory = scheduled.plan.trajectory
        piece = trajectory.Clone()
        piece.shiftRight(scheduled.t_start - trajectory.start_time())
        t_next = schedule[i + 1].t_start if i + 1 < k else t_final
        q_end = trajectory.value(trajectory.end_time())
        if t_next > piece.end_time():
            hold = PiecewisePolynomial.ZeroOrderHold(
                [piece.end_time(), t_next], np.hstack([q_end, q_end])
            )
            piece.ConcatenateInTime(hold)
        pieces.append(piece)
    total = pieces[0]
    for piece in pieces[1:]:
        total.ConcatenateInTime(piece)
    return total


class PlanRunner(LeafSystem):
    """Executes a schedule of plans at a fixed control period (the outer loop), in Python.

    The episode hands it only the part of the schedule that needs feedback, from ``t_first``
    (the first tick) on; before that its outputs are zero. It sends q_ref - ``q_offset``: the
    episode adds ``q_offset`` back in C++ (the joint-space trajectory's end value, which the
    trajectory source keeps sending), so q_ref is continuous at the handoff.

    Timing: the plan ticking at t_k = t_first + k period sees the arm after every plant step at
    or before t_k, and its command acts from the first plant step after t_k. The runner's
    update event fires ``lag`` after each tick (:func:`run_episode` passes :func:`_tick_lag`:
    half the grid that ticks and plant steps share, so no step lies in between; the default 0
    fires at the tick itself) and hands the plan t_k itself. (An
    event at t_k exactly would leave that order to float rounding when t_k is a plant step:
    Drake sums offset + k period and n time_step separately, and at the default 5 ms / 2 ms
    about one such tick in five fell an ulp before the step, saw the arm one step earlier
    and acted one step sooner, or an ulp after it.)

    Input ports: ``iiwa_state`` (14: q [rad], v [rad/s]), ``iiwa_torque_external`` (7).
    Output ports (state outputs, no Python per simulation step): ``iiwa_position`` (q_ref),
    ``iiwa_feedforward_torque`` (tau_ff).
    """

    def __init__(
        self,
        schedule: Sequence[ScheduledPlan],
        *,
        control_period: float,
        t_first: float = 0.0,
        lag: float = 0.0,
        q_offset: np.ndarray | None = None,
    ):
        super().__init__()
        self.set_name("plan_runner")
        self._period = control_period
        self._t_first = t_first
        self._lag = lag
        self._schedule = list(schedule)
        self._starts = [s.t_start for s in self._schedule]
        self._cursor = 0
        self._x = self.DeclareVectorInputPort("iiwa_state", 2 * NUM_JOINTS)
        self._tau_ext = self.DeclareVectorInputPort("iiwa_torque_external", NUM_JOINTS)
        self._q_offset = (
            np.zeros(NUM_JOINTS) if q_offset is None else np.asarray(q_offset, float).copy()
        )
        self._q_ref = self.DeclareDiscreteState(NUM_JOINTS)
        self._tau_ff = self.DeclareDiscreteState(NUM_JOINTS)
        self.DeclareStateOutputPort("iiwa_position", self._q_ref)
        self.DeclareStateOutputPort("iiwa_feedforward_torque", self._tau_ff)
        self.DeclarePeriodicDiscreteUpdateEvent(control_period, t_first + lag, self._tick)

    def active(self, t: float) -> ScheduledPlan:
        """The scheduled plan active at time t [s] (the last one after the schedule ends)."""
        # Ticks come in increasing time: move a cursor instead of searching the schedule.
        while self._cursor + 1 < len(self._schedule) and t >= self._starts[self._cursor + 1]:
            self._cursor += 1
        while self._cursor > 0 and t < self._starts[self._cursor]:
            self._cursor -= 1
        return self._schedule[self._cursor]

    def _tick(self, context, discrete_state) -> None:
        k = round((context.get_time() - self._lag - self._t_first) / self._period)
        t = self._t_first + k * self._period
        scheduled = self.active(t)
        x = self._x.Eval(context)
        state = ArmState(x[:NUM_JOINTS], x[NUM_JOINTS:], self._tau_ext.Eval(context))
        command = scheduled.plan.command(t - scheduled.t_start, state)
        discrete_state.set_value(self._q_ref, command.q_ref - self._q_offset)
        discrete_state.set_value(self._tau_ff, command.tau_ff)


@dataclass(frozen=True)
class EpisodeResult:
    """Named, time-stamped logs of one episode (all sampled every log period).

    Attributes:
        t: Sample times (n,) [s].
        q_commanded, q_measured: (n, 7) [rad]. v_measured: (n, 7) [rad/s].
        tau_external: Contact torques on the arm joints (n, 7) [N m].
        tau_feedforward: tau_ff sent by the plans (n, 7) [N m].
        tau_commanded: Torque the joints receive (n, 7) [N m]: the actuators' after
            saturation plus, for the stiffness loop, the joints' damping -(Dq + h Kq) qdot.
        door_angles: Hinge angles (n, 2) [rad], columns (left, right).
        wsg_width: Finger separation (n,) [m].
        plant_positions: Positions of the whole plant (n, nq), for replays.
        plan_names: Names of the scheduled plans. plan_starts: Their start times (k,) [s].
        arc_window: [t_start, t_end] of the door-opening arc [s], shape (2,).
        wall_time_s: Wall-clock time of the simulation [s].
        scenario_yaml: The scenario that produced the logs.
        plan_log: The arc plan's own per-tick table {channel: (m,)} (empty for plans that
            record nothing); its ``t`` column is the episode's time [s]. The adaptive plan's
            channels are listed in :data:`doorlab.control.adaptive.LOG_CHANNELS`.
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
    t_final = schedule[-1].t_end + timeline.extra_time
    builder = DiagramBuilder()
    station = build_station(scenario.station, meshcat=meshcat)
    station_system = builder.AddSystem(station.diagram)

    def add(system, name: str):
        system.set_name(name)
        return builder.AddSystem(system)

    # q_ref: the joint-space plans at the start (hold, move, grasp; all of an IK episode) come
    # from C++ trajectory sources; the Python plan runner takes over at the first plan that
    # needs feedback (its first tick), with no Python before it. The sources then keep sending
    # their last value q_handoff, and the runner sends q_ref - q_handoff: the sum is q_ref.
    # They send exactly what the runner would have: the plans sampled at its ticks t_k, each
    # sample reaching the plant (and the logs) from the first step after t_k, as a discrete
    # update at t_k does.
    period = timeline.control_period
    lag = _tick_lag(scenario.station.time_step, period)
    k = joint_space_prefix(schedule)
    t_first = _first_tick(schedule[k].t_start, period) if k < len(schedule) else t_final
    q_ref_sum = add(Adder(2, NUM_JOINTS), "q_ref")
    if k > 0:
        prefix = prefix_trajectory(schedule, k, t_final + 1.0)
        ticks = np.arange(int(np.floor(t_first / period - 1e-9)) + 1) * period
        ticks = ticks[ticks < t_first - 1e-9] if k < len(schedule) else ticks
        samples = np.column_stack([prefix.value(t).ravel() for t in ticks])
        q_handoff = samples[:, -1]
        held = np.column_stack([samples, q_handoff])
        end = t_final + 1.0
        applied = PiecewisePolynomial.ZeroOrderHold([0.0, *(ticks[1:] + lag), end], held)
        joint_source = add(TrajectorySource(applied), "joint_space_plans")
    else:
        q_handoff = np.asarray(q_initial, float)
        joint_source = add(ConstantVectorSource(q_handoff), "joint_space_plans")
    builder.Connect(joint_source.get_output_port(), q_ref_sum.get_input_port(0))
    if k < len(schedule):
        runner = add(
            PlanRunner(
                schedule[k:],
                control_period=period,
                t_first=t_first,
                lag=lag,
                q_offset=q_handoff,
            ),
            "plan_runner",
        )
        for name in ("iiwa_state", "iiwa_torque_external"):
            builder.Connect(station_system.GetOutputPort(name), runner.GetInputPort(name))
        q_ref_runner = runner.GetOutputPort("iiwa_position")
        tau_ff_port = runner.GetOutputPort("iiwa_feedforward_torque")
    else:
        zero = np.zeros(NUM_JOINTS)
        q_ref_runner = add(ConstantVectorSource(zero), "no_runner").get_output_port()
        tau_ff_port = add(ConstantVectorSource(zero), "no_feedforward").get_output_port()
    builder.Connect(q_ref_runner, q_ref_sum.get_input_port(1))
    builder.Connect(q_ref_sum.get_output_port(), station_system.GetInputPort("iiwa_position"))
    builder.Connect(tau_ff_port, station_system.GetInputPort("iiwa_feedforward_torque"))
    # The gripper's setpoint: a C++ zero-order hold switching at the first step after the
    # tick that starts each plan (as the runner's state did).
    widths = [s.gripper_width for s in schedule]
    switches = [_first_tick(s.t_start, period) + lag for s in schedule[1:]]
    wsg = add(
        TrajectorySource(
            PiecewisePolynomial.ZeroOrderHold(
                [0.0, *switches, t_final + 1.0], np.array([[*widths, widths[-1]]])
            )
        ),
        "wsg_position",
    )
    builder.Connect(wsg.get_output_port(), station_system.GetInputPort("wsg_position"))
    force_limit = builder.AddSystem(ConstantVectorSource([scenario.station.gripper.force_limit]))
    force_limit.set_name("wsg_force_limit")
    builder.Connect(force_limit.get_output_port(), station_system.GetInputPort("wsg_force_limit"))

    # One logger of one C++ Multiplexer (one publish per sample, not one per channel); the
    # arm's measured state, the hinges and the fingers are read from the plant state after.
    channels = {
        "q_commanded": station_system.GetOutputPort("iiwa_position_commanded"),
        "tau_feedforward": tau_ff_port,
        "tau_commanded": station_system.GetOutputPort("iiwa_torque_commanded"),
        "tau_external": station_system.GetOutputPort("iiwa_torque_external"),
        "plant_state": station_system.GetOutputPort("plant_state"),
    }
    mux = add(Multiplexer([port.size() for port in channels.values()]), "log_channels")
    for i, port in enumerate(channels.values()):
        builder.Connect(port, mux.get_input_port(i))
    logger = LogVectorOutput(mux.get_output_port(), builder, timeline.log_period)
    if _SEPARATE_LOGGERS:  # the 353b732 design's nine loggers, for doorlab.studies.legacy (unused)
        for name in _SEPARATE_LOG_PORTS:
            LogVectorOutput(station_system.GetOutputPort(name), builder, timeline.log_period)
        LogVectorOutput(tau_ff_port, builder, timeline.log_period)
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

    log = logger.FindLog(context)
    t = log.sample_times()
    columns = np.cumsum([0, *(port.size() for port in channels.values())])
    samples = log.data().T
    data = {
        name: samples[:, start:end]
        for name, start, end in zip(channels, columns[:-1], columns[1:], strict=True)
    }
    plant = station.plant
    x = data["plant_state"]
    nq = plant.num_positions()
    q_all, v_all = x[:, :nq], x[:, nq:]
    # Column indices of a model instance's positions/velocities in the plant's.
    arm_q = plant.GetPositionsFromArray(station.iiwa, np.arange(nq)).astype(int)
    arm_v = plant.GetVelocitiesFromArray(station.iiwa, np.arange(v_all.shape[1])).astype(int)
    fingers = plant.GetPositionsFromArray(station.wsg, np.arange(nq)).astype(int)
    hinges = [plant.GetJointByName(h, station.cupboard).position_start() for h in HINGES]
    data["q_measured"] = q_all[:, arm_q]
    data["v_measured"] = v_all[:, arm_v]
    data["door_angles"] = q_all[:, hinges]
    data["wsg_width"] = q_all[:, fingers[1]] - q_all[:, fingers[0]]  # right - left finger
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
        wsg_width=data["wsg_width"],
        plant_positions=q_all,
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
