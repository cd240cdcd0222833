"""``doorlab sim-driver``: doorlab's simulated cell (:mod:`doorlab.hardware.sim_cell`: the
station behind the drivers' LCM protocol, its timing) as its own diagram and simulator, paced
to real time, serving until a signal or a duration, with its ground truth.

:class:`SimDriver` is the process's core (``doorlab.hardware.serve`` its command line); for a
driver inside another diagram (a client on one ``memq://`` bus) use
:func:`~doorlab.hardware.sim_cell.add_sim_driver`.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydrake.common.yaml import yaml_dump_typed
from pydrake.lcm import DrakeLcm
from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
from pydrake.systems.framework import Context, DiagramBuilder, EventStatus

from doorlab.config import Scenario, validate
from doorlab.errors import ConfigError, SimulationError
from doorlab.hardware.ground_truth import (
    DRIVER_FILE,
    GROUND_TRUTH_FILE,
    SCENARIO_FILE,
    GroundTruth,
)
from doorlab.hardware.protocol import (
    IIWA_STATUS_PERIOD,
    JOINT_LIMIT_MARGIN,
    START_COMMAND_GUARD,
    WSG_STATUS_PERIOD,
)
from doorlab.hardware.sim_cell import STATUS_DELAY, add_sim_driver, start_guard_message


@dataclass(frozen=True)
class DriverOutcome:
    """How a run of :class:`SimDriver` ended.

    Attributes:
        status: ``"stopped"`` (the duration ran out), ``"interrupted"`` (a signal),
            ``"aborted"`` (the start guard), or ``"failed"`` (the physics, or a command
            the receivers reject, e.g. not 7 joints).
        message: Why, in one line ("" when stopped).
        sim_time_s: Simulated time at the end [s]. wall_time_s: Wall time since the first
            status [s].
        exit_code: The process's exit code: 0 stopped, 1 aborted or failed, 128 + the
            signal when interrupted (130 Ctrl-C, 143 SIGTERM).
    """

    status: str
    message: str
    sim_time_s: float
    wall_time_s: float
    exit_code: int

    @property
    def realtime_rate(self) -> float:
        """Simulated seconds per wall second (1.0 when it kept pace)."""
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else math.nan


class SimDriver:
    """The simulated driver as its own diagram and simulator (``doorlab sim-driver``).

    Args:
        scenario: The station and its initial state (validated here); ``doors`` sets the
            doors open or closed.
        lcm_url: The bus (check it with :func:`doorlab.hardware.protocol.resolve_lcm_url`);
            ``memq://`` only to talk to a client in this process.
        utime_warmup: Send utime -1 in the first 200 statuses, as the real driver does.
        record: Log the ground truth (:meth:`ground_truth`, :meth:`write_output`).
    """

    def __init__(
        self,
        scenario: Scenario,
        *,
        lcm_url: str,
        utime_warmup: bool = False,
        record: bool = False,
    ):
        self.scenario = validate(scenario)
        self.lcm_url = lcm_url
        self.lcm = DrakeLcm(lcm_url)
        builder = DiagramBuilder()
        self.systems = add_sim_driver(
            builder, self.lcm, self.scenario, utime_warmup=utime_warmup, record=record
        )
        self.diagram = builder.Build()
        self.diagram.set_name("doorlab_sim_driver")
        self.simulator = Simulator(self.diagram)
        # Every state is discrete: the integrator only advances time between events.
        ResetIntegratorFromFlags(self.simulator, "explicit_euler", scenario.station.time_step)
        self.systems.initialize(self.simulator.get_mutable_context())
        self.outcome: DriverOutcome | None = None

    @property
    def time(self) -> float:
        """The simulation time [s]."""
        return self.simulator.get_context().get_time()

    def run(
        self,
        *,
        duration: float = math.inf,
        realtime_rate: float = 1.0,
        guard: float = START_COMMAND_GUARD,
    ) -> DriverOutcome:
        """Serves the protocol until ``duration`` [s] of simulation time, a signal, or an abort.

        The first status goes out at once (its slot t = 0). A command within ``guard`` of it (wall
        time when paced, simulation time when ``realtime_rate`` is 0) aborts before it acts.
        Ctrl-C (KeyboardInterrupt) and :class:`doorlab.errors.Interrupted` (SIGTERM, SIGHUP
        under doorlab's CLI) end the run between two steps; the state stays consistent.

        Args:
            duration: Simulated time to run for [s] (default: until a signal).
            realtime_rate: 1.0 keeps pace with the wall clock; 0 runs as fast as possible.
            guard: The start guard [s] (0 disables it).

        Returns:
            How it ended (also kept in :attr:`outcome`).

        Raises:
            ConfigError: It ran before (a driver serves once).
        """
        if self.outcome is not None:
            raise ConfigError("SimDriver.run serves once; build a new SimDriver")
        simulator = self.simulator
        simulator.set_target_realtime_rate(realtime_rate)
        paced = realtime_rate > 0
        wall_start = time.monotonic()
        status, message, exit_code = "stopped", "", 0
        try:
            try:
                simulator.Initialize()  # the first status goes out at t = STATUS_DELAY
                wall_start = time.monotonic()
                if guard > 0:
                    self._advance_through_guard(duration, guard, paced, wall_start)
                if self.time < duration:
                    simulator.AdvanceTo(duration)
            except _StartGuardTripped as e:
                status, message, exit_code = "aborted", str(e), 1
            except RuntimeError as e:  # the physics, or a message the receivers reject
                first = str(e).splitlines()[0] if str(e) else type(e).__name__
                status, exit_code = "failed", 1
                message = f"the simulation failed at t = {self.time:.3f} s: {first}"
        except KeyboardInterrupt as e:
            from doorlab.errors import interrupt_exit_code

            code = interrupt_exit_code(e)
            status, exit_code = "interrupted", code
            message = f"stopped by signal {code - 128} at t = {self.time:.3f} s"
        self.outcome = DriverOutcome(
            status, message, self.time, time.monotonic() - wall_start, exit_code
        )
        return self.outcome

    def _advance_through_guard(
        self, duration: float, guard: float, paced: bool, wall_start: float
    ) -> None:
        """Steps through the start guard with a per-step monitor, one status at a time."""
        simulator = self.simulator
        systems = self.systems

        def elapsed() -> float:
            return time.monotonic() - wall_start if paced else self.time

        tripped = []

        def monitor(context: Context) -> EventStatus:
            if elapsed() < guard and systems.iiwa_commands_received() > 0:
                tripped.append(elapsed())
                return EventStatus.ReachedTermination(
                    systems.iiwa_command_subscriber, start_guard_message(guard, tripped[0])
                )
            return EventStatus.DidNothing()

        if systems.iiwa_commands_received() > 0:  # read while initializing
            raise _StartGuardTripped(start_guard_message(guard, 0.0))
        simulator.set_monitor(monitor)
        try:
            while elapsed() < guard and self.time < duration:
                simulator.AdvanceTo(min(duration, self.time + IIWA_STATUS_PERIOD))
                if tripped:
                    raise _StartGuardTripped(start_guard_message(guard, tripped[0]))
        finally:
            simulator.clear_monitor()

    def ground_truth(self) -> GroundTruth:
        """The logged ground truth so far (needs ``record=True``)."""
        return self.systems.ground_truth(self.simulator.get_context())

    def summary(self) -> dict:
        """The run's facts for ``driver.json`` (after :meth:`run`)."""
        outcome = self.outcome
        t = self.time
        return {
            "status": outcome.status if outcome else "not run",
            "message": outcome.message if outcome else "",
            "lcm_url": self.lcm_url,
            "doors": self.scenario.doors,
            "sim_time_s": t,
            "wall_time_s": outcome.wall_time_s if outcome else 0.0,
            "realtime_rate": outcome.realtime_rate if outcome else math.nan,
            "iiwa_statuses_sent": _slots(t - STATUS_DELAY, IIWA_STATUS_PERIOD),
            "wsg_statuses_sent": _slots(t, WSG_STATUS_PERIOD),
            "iiwa_commands_received": self.systems.iiwa_commands_received(),
            "wsg_commands_received": self.systems.wsg_commands_received(),
            "utime_warmup": self.systems.utime_warmup,
            "status_period_s": IIWA_STATUS_PERIOD,
            "wsg_status_period_s": WSG_STATUS_PERIOD,
            "start_command_guard_s": START_COMMAND_GUARD,
            "joint_limit_margin_rad": float(JOINT_LIMIT_MARGIN),
            "log_period_s": self.scenario.timeline.log_period,
            **self._command_timing(),
        }

    def _command_timing(self) -> dict:
        """How the applied commands' timing compared with one process (with ``record``)."""
        if self.systems.command_logger is None:
            return {}
        delays = self.systems.command_delays(self.simulator.get_context())
        late = delays[delays > 0]
        return {
            "iiwa_commands_applied": len(delays),
            "iiwa_commands_late": len(late),  # acted a plant step or more after one process
            "iiwa_command_delay_mean_s": float(np.mean(np.maximum(delays, 0)))
            * self.scenario.station.time_step
            if len(delays)
            else math.nan,
        }

    def write_output(self, staging: Path) -> None:
        """Writes ``ground_truth.npz``, ``driver.json`` and ``scenario.yaml`` into ``staging``
        (a folder from :func:`doorlab.runs.prepare_output`)."""
        self.ground_truth().save(staging / GROUND_TRUTH_FILE)
        (staging / DRIVER_FILE).write_text(json.dumps(_finite(self.summary()), indent=2) + "\n")
        (staging / SCENARIO_FILE).write_text(yaml_dump_typed(self.scenario))


def _slots(t: float, period: float) -> int:
    """How many of the times 0, period, 2 period, ... are at or before t [s]."""
    return int(math.floor(t / period + 1e-9)) + 1 if t >= 0 else 0


def _finite(data: dict) -> dict:
    return {
        k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in data.items()
    }


class _StartGuardTripped(SimulationError):
    """A command arrived within the start guard."""
