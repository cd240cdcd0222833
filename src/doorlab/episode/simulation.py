"""One episode on the simulated station, its whole life here: :func:`run_episode` builds the
diagram, runs it and reads the logs out of it.

1. The timeline: :func:`doorlab.episode.schedule.make_schedule` (hold, the move to the first
   plan's start, the plans).
2. Build (:func:`build_simulated_episode`): the station, or with ``station.driver.timing:
   kuka_driver`` the arm's cell around it (:mod:`doorlab.cell.arm_cell`); the command wiring
   and the logger (:mod:`doorlab.episode.wiring`); ``station.safety``'s monitor.
3. Run (``_simulate``): from the initial state, in chunks of simulated time so that
   Ctrl-C and SIGTERM are handled (:func:`advance_interruptibly`).
4. Result (``_result``): the logged channels, the measured arm, hinges and fingers
   read from the logged plant state, as an :class:`~doorlab.episode.result.EpisodeResult`;
   a safety stop keeps the logs up to it, a non-finite state is a divergence.

The real cell runs the same schedule, wiring and logger over LCM
(:mod:`doorlab.hardware.episode`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from pydrake.common.yaml import yaml_dump_typed
from pydrake.geometry import Meshcat
from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, TrajectorySource, VectorLogSink
from pydrake.trajectories import PiecewisePolynomial

from doorlab.cell.arm_cell import (
    WATCH_DELAY,
    ArmCell,
    ExternalTorqueWatch,
    build_arm_cell,
    read_cycle_log,
)
from doorlab.cell.frames import FINGER_JOINTS, LEFT_HINGE, RIGHT_HINGE
from doorlab.cell.safety import SafetyLimits, SafetyMonitor
from doorlab.cell.station import Station, build_station
from doorlab.config import Scenario
from doorlab.constants import Q_HOME
from doorlab.control.plan_base import Plan
from doorlab.episode.result import EpisodeResult, schedule_fields
from doorlab.episode.schedule import ScheduledPlan, make_schedule, tick_lag
from doorlab.episode.wiring import CommandWiring, EpisodeLogger, wire_commands
from doorlab.errors import ConfigError, ControllerError, SafetyStop, SimulationError
from doorlab.kuka import CYCLE_PERIOD, WSG_COMMAND_PERIOD

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


@dataclass(frozen=True)
class SimulatedEpisode:
    """A built simulated episode: the diagram, the station in it, the logger, the schedule,
    the command wiring (whose :meth:`~doorlab.episode.wiring.CommandWiring.advance_to` runs the
    plan runner's ticks); with ``station.driver.timing: kuka_driver`` the arm cell around the
    station and its per-cycle status log."""

    diagram: Diagram
    station: Station
    logger: EpisodeLogger
    schedule: list[ScheduledPlan]
    t_final: float
    commands: CommandWiring
    arm: ArmCell | None = None
    cycle_logger: VectorLogSink | None = None


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
        SafetyStop, ControllerError: A command broke a safety limit, a plug-in's plan raised
            or sent no valid command: the run stopped there (the error's ``result`` holds
            the logs up to it).
    """
    q_initial = np.asarray(q_initial, float)
    schedule = make_schedule(
        plans, gripper_widths, q_initial=q_initial, q_start=q_start, scenario=scenario
    )
    episode = build_simulated_episode(scenario, schedule, q_initial=q_initial, meshcat=meshcat)
    arc_index = (len(plans) - 1 if arc_plan_index is None else arc_plan_index) + 2
    simulator = Simulator(episode.diagram)
    wall_start = time.perf_counter()
    try:
        wall_time = _simulate(
            simulator, episode, scenario, q_initial, meshcat=meshcat, realtime_rate=realtime_rate
        )
    except SafetyStop as stop:
        wall_time = time.perf_counter() - wall_start
        partial, _ = _result(episode, simulator, scenario, wall_time, arc_index)
        raise SafetyStop(stop.violation, result=partial) from None
    except ControllerError as stop:  # a plug-in raised in a tick: its logs up to there
        wall_time = time.perf_counter() - wall_start
        partial, _ = _result(episode, simulator, scenario, wall_time, arc_index)
        raise ControllerError(str(stop), result=partial) from None
    result, finite = _result(episode, simulator, scenario, wall_time, arc_index)
    if not finite:
        raise SimulationError("the simulation diverged: the plant state became non-finite")
    return result


# Build ---------------------------------------------------------------------------------------


def build_simulated_episode(
    scenario: Scenario,
    schedule: Sequence[ScheduledPlan],
    *,
    q_initial: np.ndarray,
    meshcat: Meshcat | None = None,
) -> SimulatedEpisode:
    """The episode's diagram on the simulated station: the station, the shared command
    wiring (:func:`doorlab.episode.wiring.wire_commands`) and the logger."""
    t_final = schedule[-1].t_end + scenario.timeline.extra_time
    builder = DiagramBuilder()
    lag = tick_lag(scenario.station.time_step, scenario.timeline.control_period)
    if scenario.station.driver.timing == "kuka_driver":
        if meshcat is not None:
            raise ConfigError(
                "--meshcat draws doorlab's cell only; station.driver.timing kuka_driver "
                "runs the arm's cell without it"
            )
        return _build_arm_episode(builder, scenario, schedule, q_initial, t_final, lag)
    station = build_station(scenario.station, meshcat=meshcat)
    cell = builder.AddSystem(station.diagram)
    wiring = wire_commands(
        builder, cell, schedule, scenario=scenario, q_initial=q_initial, t_final=t_final, lag=lag
    )
    # The arm's measured state, the hinges and the fingers are read from the plant state.
    channels = {
        "q_commanded": cell.GetOutputPort("iiwa_position_commanded"),
        "tau_feedforward": wiring.tau_ff,
        "tau_commanded": cell.GetOutputPort("iiwa_torque_commanded"),
        "tau_external": cell.GetOutputPort("iiwa_torque_external"),
        "plant_state": cell.GetOutputPort("plant_state"),
    }
    if scenario.station.safety.enabled:
        _add_safety_monitor(builder, cell, wiring, scenario, q_initial=q_initial, lag=lag)
    log_period = scenario.timeline.log_period
    logger = EpisodeLogger(builder, channels, log_period)
    if _SEPARATE_LOGGERS:  # the 353b732 design's nine loggers, for doorlab.studies.legacy (unused)
        for name in _SEPARATE_LOG_PORTS:
            LogVectorOutput(cell.GetOutputPort(name), builder, log_period)
        LogVectorOutput(wiring.tau_ff, builder, log_period)
    diagram = builder.Build()
    diagram.set_name("doorlab_episode")
    return SimulatedEpisode(diagram, station, logger, list(schedule), t_final, wiring)


def _build_arm_episode(
    builder: DiagramBuilder,
    scenario: Scenario,
    schedule: Sequence[ScheduledPlan],
    q_initial: np.ndarray,
    t_final: float,
    lag: float,
) -> SimulatedEpisode:
    """The episode on the arm's cell (``station.driver.timing: kuka_driver``,
    :mod:`doorlab.cell.arm_cell`): the plans read each cycle's status; their commands, and the
    gripper's as a hardware client sends it (20 Hz), act from the next cycle; no command at
    the first cycle (t = 0), as for a client's first status; kuka_driver's external-torque
    stop. The logs are the truth (the plant, the command the arm tracks)."""
    arm = build_arm_cell(scenario.station, q_initial=q_initial)
    cell = builder.AddSystem(arm.diagram)
    wiring = wire_commands(
        builder,
        cell,
        schedule,
        scenario=scenario,
        q_initial=q_initial,
        t_final=t_final,
        lag=lag,
        gripper_link=(WSG_COMMAND_PERIOD, CYCLE_PERIOD),
    )
    first = PiecewisePolynomial.ZeroOrderHold([0.0, lag, t_final + 1.0], np.array([[0.0, 1, 1]]))
    valid = builder.AddSystem(TrajectorySource(first))
    valid.set_name("first_command_at_the_first_tick")
    builder.Connect(valid.get_output_port(), cell.GetInputPort("iiwa_command_valid"))
    watch = builder.AddSystem(
        ExternalTorqueWatch(
            scenario.station.driver.external_torque_limit, offset=arm.offset + WATCH_DELAY
        )
    )
    builder.Connect(cell.GetOutputPort("iiwa_torque_external"), watch.get_input_port())
    channels = {
        "q_commanded": cell.GetOutputPort("applied_iiwa_position"),
        "tau_feedforward": cell.GetOutputPort("applied_feedforward_torque"),
        "tau_commanded": cell.GetOutputPort("station_torque_commanded"),
        "tau_external": cell.GetOutputPort("station_torque_external"),
        "tau_external_estimated": cell.GetOutputPort("iiwa_torque_external"),
        "plant_state": cell.GetOutputPort("plant_state"),
    }
    if scenario.station.safety.enabled:
        _add_safety_monitor(builder, cell, wiring, scenario, q_initial=q_initial, lag=lag)
    logger = EpisodeLogger(builder, channels, scenario.timeline.log_period)
    cycle_logger = LogVectorOutput(cell.GetOutputPort("status"), builder, CYCLE_PERIOD)
    diagram = builder.Build()
    diagram.set_name("doorlab_arm_episode")
    return SimulatedEpisode(
        diagram, arm.station, logger, list(schedule), t_final, wiring, arm, cycle_logger
    )


def _add_safety_monitor(
    builder: DiagramBuilder, cell, wiring, scenario: Scenario, *, q_initial: np.ndarray, lag: float
) -> None:
    """``station.safety``: every command checked at its tick, before the plant steps with it
    (halfway between the command's switch, ``lag`` after the tick, and the next plant step)."""
    limits = SafetyLimits.from_config(scenario.station.safety, q_initial)
    monitor = builder.AddSystem(
        SafetyMonitor(limits, control_period=scenario.timeline.control_period, offset=1.5 * lag)
    )
    builder.Connect(wiring.q_ref, monitor.GetInputPort("iiwa_position"))
    builder.Connect(wiring.tau_ff, monitor.GetInputPort("iiwa_feedforward_torque"))
    builder.Connect(
        cell.GetOutputPort("iiwa_position_measured"), monitor.GetInputPort("iiwa_position_measured")
    )


# Run -----------------------------------------------------------------------------------------


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


ADVANCE_CHUNK_S = 0.25
"""The episode advances this much simulated time per ``AdvanceTo`` call [s]; between calls
Python runs, so Ctrl-C and SIGTERM are handled within one chunk (measured, on 2 loaded cores:
at most 80-200 ms of waiting for C++, against 4-7 s for the whole episode in one call; the 96
calls' fixed cost, ~15 us each, is 0.04 % of the advance: benchmarks/chunked_advance.py)."""
MAX_PACED_CHUNK_WALL_S = 0.1
"""With real-time pacing a chunk is at most this much wall time [s] (Drake sleeps in C++)."""


def advance_interruptibly(
    simulator: Simulator,
    t_final: float,
    *,
    realtime_rate: float = 0.0,
    advance: Callable[[Simulator, float], None] | None = None,
) -> None:
    """``simulator.AdvanceTo(t_final)`` in chunks of simulated time, so that Python's signal
    handlers run between them.

    A diagram of C++ systems only (an IK episode, or the joint-space phases before the plan
    runner's first tick) or real-time pacing (which sleeps in C++) would not return to Python
    before ``t_final``: Ctrl-C and SIGTERM would wait for the whole episode. The chunks are
    bit-identical to one call: every state is discrete, its events are scheduled from t = 0,
    and stopping between two of them advances time only (tests/test_simulation.py checks it).

    Args:
        simulator: An initialized simulator.
        t_final: Where to stop [s].
        realtime_rate: The simulator's target real-time rate (0: as fast as possible); a paced
            chunk lasts at most :data:`MAX_PACED_CHUNK_WALL_S` of wall time.
        advance: ``advance(simulator, t)`` advances to t (default ``simulator.AdvanceTo``;
            the episode's :meth:`~doorlab.episode.wiring.CommandWiring.advance_to` runs the
            plan runner's ticks on the way).
    """
    chunk = ADVANCE_CHUNK_S
    if realtime_rate > 0:
        chunk = min(chunk, realtime_rate * MAX_PACED_CHUNK_WALL_S)
    t_start = simulator.get_context().get_time()
    k = 1
    while True:
        t = min(t_start + k * chunk, t_final)
        if advance is None:
            simulator.AdvanceTo(t)
        else:
            advance(simulator, t)
        if t >= t_final:
            return
        k += 1


def _simulate(
    simulator: Simulator,
    episode: SimulatedEpisode,
    scenario: Scenario,
    q_initial: np.ndarray,
    *,
    meshcat: Meshcat | None,
    realtime_rate: float,
) -> float:
    """Runs the episode to its end (or a safety stop); returns the wall time [s]."""
    # Every state is discrete (plant, plan runner, gripper): no continuous state to
    # integrate, so the cheapest fixed-step integrator just advances time between events
    # (the default error-controlled one costs ~10 % of an episode for nothing).
    ResetIntegratorFromFlags(simulator, "explicit_euler", scenario.station.time_step)
    context = simulator.get_mutable_context()
    if episode.arm is not None:
        episode.arm.initialize(context, door_angles=scenario.initial_door_angles())
    else:
        _initialize(episode.station, context, q_initial, scenario)
    simulator.set_target_realtime_rate(realtime_rate)
    if meshcat is not None:
        meshcat.StartRecording()
    wall_start = time.perf_counter()
    try:
        simulator.Initialize()
        advance = episode.commands.advance_to
        if episode.arm is not None:  # locked until the first command, applied at 5 ms
            first = CYCLE_PERIOD + episode.arm.offset + WATCH_DELAY
            advance(simulator, min(first, episode.t_final))
            episode.arm.unlock(context)
        advance_interruptibly(
            simulator, episode.t_final, realtime_rate=realtime_rate, advance=advance
        )
    except RuntimeError as e:
        message = str(e).splitlines()[0]
        raise SimulationError(
            f"the simulation failed at t = {context.get_time():.3f} s: {message}"
        ) from None
    finally:
        if meshcat is not None:
            meshcat.StopRecording()
            meshcat.PublishRecording()
    return time.perf_counter() - wall_start


# Result --------------------------------------------------------------------------------------


def _result(
    episode: SimulatedEpisode,
    simulator: Simulator,
    scenario: Scenario,
    wall_time: float,
    arc_index: int,
) -> tuple[EpisodeResult, bool]:
    """The episode's logs as they stand in the simulator's context, and whether the logged
    plant state is finite."""
    t, data = episode.logger.read(simulator.get_context())
    measured = plant_state_channels(episode.station, data["plant_state"])
    cycle_log = {}
    if episode.cycle_logger is not None:
        cycle_log = read_cycle_log(episode.cycle_logger, simulator.get_context())
    result = EpisodeResult(
        t=t,
        q_commanded=data["q_commanded"],
        q_measured=measured["q_measured"],
        v_measured=measured["v_measured"],
        tau_external=data["tau_external"],
        tau_feedforward=data["tau_feedforward"],
        tau_commanded=data["tau_commanded"],
        door_angles=measured["door_angles"],
        wsg_width=measured["wsg_width"],
        plant_positions=measured["plant_positions"],
        wall_time_s=wall_time,
        scenario_yaml=yaml_dump_typed(scenario),
        cycle_log=cycle_log,
        tau_external_estimated=data.get("tau_external_estimated"),
        **schedule_fields(episode.schedule, arc_index),
    )
    return result, bool(np.all(np.isfinite(data["plant_state"])))


def plant_state_channels(station: Station, x: np.ndarray) -> dict[str, np.ndarray]:
    """The measured arm state, hinges and fingers from logged plant states x (n, nq + nv):
    ``q_measured``, ``v_measured``, ``door_angles``, ``wsg_width``, ``plant_positions``."""
    plant = station.plant
    nq = plant.num_positions()
    q_all, v_all = x[:, :nq], x[:, nq:]
    # Column indices of a model instance's positions/velocities in the plant's.
    arm_q = plant.GetPositionsFromArray(station.iiwa, np.arange(nq)).astype(int)
    arm_v = plant.GetVelocitiesFromArray(station.iiwa, np.arange(v_all.shape[1])).astype(int)
    fingers = plant.GetPositionsFromArray(station.wsg, np.arange(nq)).astype(int)
    hinges = [plant.GetJointByName(h, station.cupboard).position_start() for h in HINGES]
    return {
        "q_measured": q_all[:, arm_q],
        "v_measured": v_all[:, arm_v],
        "door_angles": q_all[:, hinges],
        "wsg_width": q_all[:, fingers[1]] - q_all[:, fingers[0]],  # right - left finger
        "plant_positions": q_all,
    }
