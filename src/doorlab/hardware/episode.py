"""An episode on the real cell: the shared wiring driven by the driver's statuses, every command
checked before it goes out.

Clock and pacing: the episode's time is the driver's. t = 0 at the first status the cell's
diagram receives; a status's time is its ``utime`` since then, on the driver's 5 ms grid. For
each status the diagram advances to just past it (its plan tick runs on it) and one command
answers it, so commands go out at the status rate and the run is paced by the arm's own clock
(real time). The plan runner ticks ``TICK_LAG`` after each status slot.

Safety, in the order it acts (the values are the module's constants):

- the first command goes out no sooner than ``FIRST_COMMAND_DELAY`` (0.3 s) after the first
  status the link received (drake-iiwa-driver aborts on a command within 0.25 s of its first);
- statuses with a negative utime (the real driver's clock not settled) are skipped: the diagram
  never sees them and no command answers (echoes) them;
- the watchdog: no fresh status for ``WATCHDOG_TIMEOUT`` (10 periods, 50 ms) stops
  commanding (status ``driver_lost``);
- every command is checked (:mod:`doorlab.cell.safety`); one that breaks a limit is not sent and
  the run stops (status ``safety_stop``); one that is ready more than ``STALE_ANSWER`` (5 ms)
  after its status arrived is dropped (the arm holds the previous one; the next status gets a
  fresh answer);
- Ctrl-C or SIGTERM stops commanding at once (status ``interrupted``);
- a plug-in's plan that raises in a tick, or computes no valid command, stops commanding there
  (status ``controller_error``: :class:`doorlab.episode.plugins.GuardedPlan`); its command of
  that tick is never sent.

When commanding stops, for whatever reason, the driver holds the last command it received
(in position mode a command never expires).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from pydrake.common.yaml import yaml_dump_typed
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Diagram, DiagramBuilder

from doorlab.cell.safety import SafetyLimits, Violation, check_command
from doorlab.config import Scenario
from doorlab.control.plan_base import Plan
from doorlab.episode.result import EpisodeResult, schedule_fields
from doorlab.episode.schedule import ScheduledPlan, make_schedule
from doorlab.episode.wiring import CommandWiring, EpisodeLogger, wire_commands
from doorlab.errors import ControllerError, NoDriver
from doorlab.hardware.estimates import door_angle_estimate, hardware_plant_positions
from doorlab.hardware.interface import HardwareCell, build_hardware_cell
from doorlab.hardware.link import DriverLink, Status
from doorlab.hardware.protocol import IIWA_STATUS_PERIOD as STATUS_PERIOD

WATCHDOG_PERIODS = 10
WATCHDOG_TIMEOUT = WATCHDOG_PERIODS * STATUS_PERIOD
"""No fresh status for this long [s] (10 periods, 50 ms) and commanding stops."""
FIRST_COMMAND_DELAY = 0.3
"""The first command goes out no sooner than this after the first status [s]."""
TICK_LAG = 1e-4
"""The plan runner ticks this long after each status slot [s]: after the status is in."""
STATUS_WINDOW = 0.5 * STATUS_PERIOD
"""For a status at t the diagram advances to t + this [s]: its tick, not the next one's."""
STALE_ANSWER = STATUS_PERIOD
"""A command not ready within this of its status's arrival [s] is dropped, not sent: the next
status is due and gets a fresh answer (a descheduled client on a busy host)."""

STOP_STATUSES = ("driver_lost", "safety_stop", "interrupted", "controller_error")
_ROUND_TRIP_SEARCH = 20
"""A command is looked for in the next this many statuses (100 ms) after it went out."""


@dataclass
class LinkRecord:
    """What went over the link: every valid status and every command, on the link's clock.

    Attributes:
        status_arrival: Arrival times of the statuses the episode used [s].
        status_utime: Their utimes [us]. status_q_commanded: Their joint_position_commanded.
        status_q_measured: Their joint_position_measured.
        command_sent: When each command was published [s]. command_t: Its episode time [s].
        command_q: Its q_ref (7,) [rad]. command_utime: The utime it echoed [us].
        skipped: Statuses with a negative utime (skipped, never answered).
        stale: Commands dropped because they were ready too late (``STALE_ANSWER``).
    """

    status_arrival: list[float] = field(default_factory=list)
    status_utime: list[int] = field(default_factory=list)
    status_q_commanded: list[np.ndarray] = field(default_factory=list)
    status_q_measured: list[np.ndarray] = field(default_factory=list)
    command_sent: list[float] = field(default_factory=list)
    command_t: list[float] = field(default_factory=list)
    command_q: list[np.ndarray] = field(default_factory=list)
    command_utime: list[int] = field(default_factory=list)
    skipped: int = 0
    stale: int = 0

    def add_status(self, status: Status) -> None:
        self.status_arrival.append(status.arrival)
        self.status_utime.append(status.utime)
        self.status_q_commanded.append(status.q_commanded)
        self.status_q_measured.append(status.q)

    def round_trips(self, tolerance: float = 1e-9) -> np.ndarray:
        """Command -> the first status that reflects it (its joint_position_commanded equals
        the command's q_ref), for each command that differs from the one before [s]."""
        arrivals = np.asarray(self.status_arrival)
        echoed = np.asarray(self.status_q_commanded).reshape(-1, 7)
        sent = np.asarray(self.command_sent)
        q = np.asarray(self.command_q).reshape(-1, 7)
        changed = np.ones(len(q), dtype=bool)
        changed[1:] = np.max(np.abs(np.diff(q, axis=0)), axis=1) > tolerance
        sent, q = sent[changed], q[changed]
        first = np.searchsorted(arrivals, sent, side="right")  # statuses arrive in order
        trip = np.full(len(sent), np.nan)
        for k in range(_ROUND_TRIP_SEARCH):  # the k-th status after each command
            index = first + k
            inside = (index < len(arrivals)) & np.isnan(trip)
            rows = np.flatnonzero(inside)
            hit = np.max(np.abs(echoed[index[rows]] - q[rows]), axis=1) <= tolerance
            trip[rows[hit]] = arrivals[index[rows[hit]]] - sent[rows[hit]]
        return trip[np.isfinite(trip)]

    def command_intervals(self) -> np.ndarray:
        """Time between consecutive commands [s]."""
        return np.diff(np.asarray(self.command_sent))

    def answer_times(self) -> np.ndarray:
        """From each status's arrival to the command that answered it [s]."""
        arrival = dict(zip(self.status_utime, self.status_arrival, strict=True))
        return np.array(
            [
                sent - arrival[utime]
                for sent, utime in zip(self.command_sent, self.command_utime, strict=True)
            ]
        )

    def status_jitter(self) -> np.ndarray:
        """Each status's arrival minus the driver's clock (its utime), less the smallest such
        difference [s]: how late each came against the earliest one (pacing and transport)."""
        lateness = np.asarray(self.status_arrival) - 1e-6 * np.asarray(self.status_utime)
        return lateness - lateness.min() if len(lateness) else lateness


@dataclass(frozen=True)
class HardwareOutcome:
    """How an episode on the real cell ended.

    Attributes:
        result: The logs (up to the stop); None if the run stopped before its first command.
        status: ``ok`` (the episode ran to its end) or one of :data:`STOP_STATUSES`.
        message: Why it stopped ("" for ok).
        violation: The broken limit (``safety_stop``).
        interrupt: The KeyboardInterrupt (``interrupted``), for the exit code.
        record: The link's statuses and commands. limits: The run's safety limits.
        t_stop: Episode time at which commanding stopped [s] (None for ok).
        last_status_to_stop: Link-clock time from the last fresh status to the stop [s].
    """

    result: EpisodeResult | None
    status: str
    message: str
    violation: Violation | None
    interrupt: KeyboardInterrupt | None
    record: LinkRecord
    limits: SafetyLimits
    t_stop: float | None
    last_status_to_stop: float | None


@dataclass
class _Episode:
    diagram: Diagram
    cell: HardwareCell
    cell_system: Diagram
    logger: EpisodeLogger
    schedule: list[ScheduledPlan]
    t_final: float
    commands: CommandWiring  # its advance_to runs the plan runner's ticks


def _build(scenario: Scenario, schedule: list[ScheduledPlan], link: DriverLink, q_initial):
    t_final = schedule[-1].t_end + scenario.timeline.extra_time
    builder = DiagramBuilder()
    cell = build_hardware_cell(link.lcm)
    system = builder.AddSystem(cell.diagram)
    wiring = wire_commands(
        builder,
        system,
        schedule,
        scenario=scenario,
        q_initial=q_initial,
        t_final=t_final,
        lag=TICK_LAG,
    )
    channels = {
        "q_commanded": system.GetOutputPort("iiwa_position_commanded"),
        "tau_feedforward": wiring.tau_ff,
        "tau_commanded": system.GetOutputPort("iiwa_torque_commanded"),
        "tau_external": system.GetOutputPort("iiwa_torque_external"),
        "q_measured": system.GetOutputPort("iiwa_position_measured"),
        "v_measured": system.GetOutputPort("iiwa_velocity_estimated"),
        "wsg_state": system.GetOutputPort("wsg_state_measured"),
        "status_time": system.GetOutputPort("iiwa_status_time"),
    }
    logger = EpisodeLogger(builder, channels, scenario.timeline.log_period)
    diagram = builder.Build()
    diagram.set_name("doorlab_hardware_episode")
    return _Episode(diagram, cell, system, logger, list(schedule), t_final, wiring)


class _Runner:
    """The status loop of one episode (see the module docstring)."""

    def __init__(
        self,
        scenario: Scenario,
        episode: _Episode,
        link: DriverLink,
        limits,
        answer_delay: float = 0.0,
    ):
        self.scenario = scenario
        self.answer_delay = answer_delay
        self.episode = episode
        self.link = link
        self.limits = limits
        self.record = LinkRecord()
        self.simulator = Simulator(episode.diagram)
        self.context = self.simulator.get_mutable_context()
        cell = episode.cell
        self._cell_context = episode.cell_system.GetMyContextFromRoot(self.context)
        self._sender_context = cell.command_sender.GetMyMutableContextFromRoot(self.context)
        self._publisher_context = cell.iiwa_command.GetMyContextFromRoot(self.context)
        self._ports = {
            name: episode.cell_system.GetInputPort(name)
            for name in ("iiwa_position", "iiwa_feedforward_torque")
        }
        self._q_port = episode.cell_system.GetOutputPort("iiwa_position_measured")
        self.utime0: int | None = None
        self.t = 0.0
        self.last_fresh: float | None = None
        self.q_ref_previous: np.ndarray | None = None
        self.t_previous_command: float | None = None

    def next_fresh_status(self) -> Status | None:
        """The next valid status before the watchdog's deadline (None: the driver is lost)."""
        while True:
            status = self.link.next_status(self.last_fresh + WATCHDOG_TIMEOUT)
            if status is None:
                return None
            if not status.valid:
                self.record.skipped += 1
                continue
            if self.utime0 is not None and status.utime <= self.record.status_utime[-1]:
                continue  # not newer than the last one (a repeat)
            return status

    def slot(self, status: Status) -> float:
        """The status's episode time on the driver's grid [s]."""
        k = round((status.utime - self.utime0) * 1e-6 / STATUS_PERIOD)
        return k * STATUS_PERIOD

    def command(self, status: Status, t: float) -> Violation | None:
        """Checks the command for ``status`` and publishes it unless it breaks a limit."""
        q_ref = np.array(self._ports["iiwa_position"].Eval(self._cell_context))
        tau_ff = np.array(self._ports["iiwa_feedforward_torque"].Eval(self._cell_context))
        q = np.array(self._q_port.Eval(self._cell_context))
        previous = q if self.q_ref_previous is None else self.q_ref_previous
        dt = STATUS_PERIOD if self.t_previous_command is None else t - self.t_previous_command
        violation = check_command(
            self.limits,
            t=t,
            q_ref=q_ref,
            tau_ff=tau_ff,
            q_measured=q,
            q_ref_previous=previous,
            dt=max(dt, STATUS_PERIOD),
        )
        if violation is not None:
            return violation
        if self.link.clock() - status.arrival > STALE_ANSWER:
            self.record.stale += 1  # the driver holds the last command; the next is fresh
            return None
        if self.answer_delay > 0:  # a test's knob: a client this slow to answer
            hold_until(self.link.clock, status.arrival + self.answer_delay)
        # Echo the status's utime exactly (the sender truncates seconds x 1e6).
        sender = self.episode.cell.command_sender
        sender.get_time_input_port().FixValue(self._sender_context, [(status.utime + 0.5) * 1e-6])
        self.episode.cell.iiwa_command.ForcedPublish(self._publisher_context)
        self.record.command_sent.append(self.link.clock())
        self.record.command_t.append(t)
        self.record.command_q.append(q_ref)
        self.record.command_utime.append(status.utime)
        self.q_ref_previous = q_ref
        self.t_previous_command = t
        return None

    def run(self, first: Status) -> tuple[str, str, Violation | None]:
        """Answers statuses from ``first`` (t = 0) until the episode's end or a stop."""
        self.utime0 = first.utime
        self.last_fresh = first.arrival
        self.simulator.Initialize()
        status = first
        while True:
            t = self.slot(status)
            self.record.add_status(status)
            self.episode.commands.advance_to(
                self.simulator, min(t + STATUS_WINDOW, self.episode.t_final)
            )
            self.t = t
            violation = self.command(status, t)
            if violation is not None:
                return "safety_stop", f"safety stop: {violation.message()}", violation
            while True:
                status = self.next_fresh_status()
                if status is None:
                    lost = self.link.clock() - self.last_fresh
                    why = (
                        "statuses were waiting: this process did not run (an overloaded host)"
                        if self.link.waiting()
                        else "none came"
                    )
                    return (
                        "driver_lost",
                        f"no fresh status for {1e3 * lost:.0f} ms after t = {self.t:.3f} s "
                        f"(watchdog: {WATCHDOG_PERIODS} periods; {why}): commanding stopped, "
                        "the driver holds the last command",
                        None,
                    )
                if self.slot(status) > t:
                    break
            self.last_fresh = status.arrival
            if self.slot(status) >= self.episode.t_final:
                self.episode.commands.advance_to(self.simulator, self.episode.t_final)
                return "ok", "", None


def hold_until(clock, t: float) -> None:
    """Waits until ``clock()`` reaches ``t`` [s]: sleeps, then yields for the last 0.3 ms
    (a sleep's wake-up is late by up to a few tenths of a millisecond)."""
    while (remaining := t - clock()) > 0:
        time.sleep(remaining - 3e-4 if remaining > 6e-4 else 0.0)


def start_status(link: DriverLink, wait: float) -> Status:
    """After a pause (the confirmation): forgets the stale statuses and returns a fresh valid
    one, no sooner than ``FIRST_COMMAND_DELAY`` after the first status the link received.

    Raises:
        NoDriver: No valid status within ``wait`` [s].
    """
    link.drain()
    deadline = link.clock() + wait
    while True:
        status = link.next_status(deadline)
        if status is None:
            raise NoDriver(
                f"the driver on {link.url} stopped sending statuses before the run started"
            )
        ready = status.arrival - link.first_arrival >= FIRST_COMMAND_DELAY
        if status.valid and ready:
            return status


def run_hardware_episode(
    scenario: Scenario,
    plans: Sequence[Plan],
    gripper_widths: Sequence[float],
    *,
    q_start: np.ndarray,
    link: DriverLink,
    wait: float,
    arc_plan_index: int | None = None,
    answer_delay: float = 0.0,
) -> HardwareOutcome:
    """Runs one episode on the real cell: hold the arm where it is, move to ``q_start``, run
    ``plans``, then ``extra_time``, answering each status with a checked command.

    Args:
        scenario: A validated scenario (timeline, gripper, ``station.safety``'s limits; its
            physics settings do not apply: the arm's own inner loop runs).
        plans, gripper_widths, q_start, arc_plan_index: As for
            :func:`doorlab.episode.simulation.run_episode`.
        link: The LCM link (a status already received: :meth:`DriverLink.wait_first_status`).
        wait: How long to wait for a fresh status at the start [s].
        answer_delay: For tests: each command leaves no sooner than this after its status
            arrived [s] (a client that slow; 0: as soon as it is ready). The stale-answer
            check still reads when the command was ready.

    Returns:
        How it ended, with the logs up to then.

    Raises:
        NoDriver: The driver stopped before the first command (nothing was sent).
    """
    s0 = start_status(link, wait)
    q_initial = s0.q
    schedule = make_schedule(
        plans, gripper_widths, q_initial=q_initial, q_start=q_start, scenario=scenario
    )
    limits = SafetyLimits.from_config(scenario.station.safety, q_initial)
    # Now what a stop needs (after one, the folder is written while every millisecond counts).
    scenario_yaml = yaml_dump_typed(scenario)
    np.percentile(np.arange(3.0), [50, 99])  # numpy imports its helpers on first use
    episode = _build(scenario, schedule, link, q_initial)
    runner = _Runner(scenario, episode, link, limits, answer_delay)
    # Statuses that came while the diagram was built reached the link but not the cell's new
    # subscribers: forget them; the next one reaches both.
    link.drain()
    deadline = link.clock() + WATCHDOG_TIMEOUT
    first = None
    while first is None or not first.valid:
        first = link.next_status(deadline)
        if first is None:
            raise NoDriver(f"the driver on {link.url} stopped before the first command")
    wall_start = time.perf_counter()
    interrupt = None
    try:
        status, message, violation = runner.run(first)
    except KeyboardInterrupt as e:  # Ctrl-C, SIGTERM (doorlab.errors.Interrupted)
        status, message, violation, interrupt = "interrupted", "interrupted", None, e
    except ControllerError as e:  # a plug-in raised in a tick, or sent no valid command
        status, message, violation = "controller_error", str(e), None
    stopped = link.clock()
    wall = time.perf_counter() - wall_start
    arc_index = (len(plans) - 1 if arc_plan_index is None else arc_plan_index) + 2
    result = _result(runner, scenario, scenario_yaml, wall, arc_index)
    return HardwareOutcome(
        result=result,
        status=status,
        message=message,
        violation=violation,
        interrupt=interrupt,
        record=runner.record,
        limits=limits,
        t_stop=None if status == "ok" else runner.t,
        last_status_to_stop=None if status == "ok" else stopped - runner.last_fresh,
    )


def _result(
    runner: _Runner, scenario: Scenario, scenario_yaml: str, wall: float, arc_index: int
) -> EpisodeResult:
    """The logs as they stand, with what the real cell cannot measure left out (the hinges)
    or estimated and named so (``door_angle_estimated``)."""
    episode = runner.episode
    t, data = episode.logger.read(runner.context)
    fields = schedule_fields(episode.schedule, arc_index)
    width = data["wsg_state"][:, 0]
    estimate = door_angle_estimate(
        t, data["q_measured"], width, scenario, arc_start=float(fields["arc_window"][0])
    )
    return EpisodeResult(
        t=t,
        q_commanded=data["q_commanded"],
        q_measured=data["q_measured"],
        v_measured=data["v_measured"],
        tau_external=data["tau_external"],
        tau_feedforward=data["tau_feedforward"],
        tau_commanded=data["tau_commanded"],
        door_angles=None,
        wsg_width=width,
        plant_positions=hardware_plant_positions(data["q_measured"], width, estimate, scenario),
        wall_time_s=wall,
        scenario_yaml=scenario_yaml,
        door_angle_estimated=estimate,
        status_time=data["status_time"][:, 0],
        cell="hardware",
        **fields,
    )


def describe_latency(record: LinkRecord) -> dict[str, float]:
    """Link statistics for metrics.json [ms]: the round trip (a command to the first status
    that reflects it), the interval between commands, the answer time (a status's arrival to
    its command) and how late statuses came against the earliest (the driver's pacing)."""

    def stat(x: np.ndarray, f) -> float:
        return float(f(x)) if len(x) else math.nan

    out: dict[str, float] = {
        "commands": len(record.command_sent),
        "statuses": len(record.status_arrival),
        "skipped_statuses": record.skipped,
        "stale_commands_dropped": record.stale,
    }
    for name, values in (
        ("round_trip", record.round_trips()),
        ("command_interval", record.command_intervals()),
        ("answer", record.answer_times()),
        ("status_lateness", record.status_jitter()),
    ):
        ms = 1e3 * values
        out[f"{name}_median_ms"] = stat(ms, np.median)
        out[f"{name}_p99_ms"] = stat(ms, lambda x: np.percentile(x, 99))
        out[f"{name}_max_ms"] = stat(ms, np.max)
    out["command_interval_std_ms"] = stat(1e3 * record.command_intervals(), np.std)
    return out
