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

from doorlab.cell.arm_cell import ExternalTorqueFreeze
from doorlab.config import Scenario, validate
from doorlab.constants import Q_HOME
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
from doorlab.hardware.sim_cell import add_sim_driver, start_guard_message
from doorlab.kuka import external_torque_limits


@dataclass(frozen=True)
class DriverOutcome:
    """How a run of :class:`SimDriver` ended.

    Attributes:
        status: ``"stopped"`` (the duration ran out), ``"interrupted"`` (a signal),
            ``"aborted"`` (the start guard, or kuka_driver's external-torque stop), or
            ``"failed"`` (the physics, or a command the receivers reject, e.g. not 7
            joints).
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
            ``memq://`` only to talk to a client in this process (the driver then reads the
            bus from Python after each status, so the client's Python handlers run with the
            GIL held: :mod:`doorlab.hardware.sim_cell`).
        utime_warmup: Send utime -1 in the first 200 statuses, as the real driver does.
        record: Log the ground truth (:meth:`ground_truth`, :meth:`write_output`).
        q_initial: The arm's start pose (7,) [rad] (an episode's: q_home).
    """

    def __init__(
        self,
        scenario: Scenario,
        *,
        lcm_url: str,
        utime_warmup: bool = False,
        record: bool = False,
        q_initial: np.ndarray = Q_HOME,
    ):
        self.scenario = validate(scenario)
        self.lcm_url = lcm_url
        self.lcm = DrakeLcm(lcm_url)
        builder = DiagramBuilder()
        self.systems = add_sim_driver(
            builder,
            self.lcm,
            self.scenario,
            q_initial=q_initial,
            utime_warmup=utime_warmup,
            record=record,
            # On memq:// the client is in this process, its handlers Python: read from Python.
            read_bus="every_cycle" if lcm_url.startswith("memq://") else "every_step",
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
                self.systems.advance_to(simulator, duration)
            except _StartGuardTripped as e:
                status, message, exit_code = "aborted", str(e), 1
            except ExternalTorqueFreeze as e:
                status, message, exit_code = "aborted", freeze_message(e.violation), 1
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
                systems.advance_to(simulator, min(duration, self.time + IIWA_STATUS_PERIOD))
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
            "iiwa_statuses_sent": _slots(t - self.systems.status_offset, IIWA_STATUS_PERIOD),
            "wsg_statuses_sent": _slots(t, WSG_STATUS_PERIOD),
            "iiwa_commands_received": self.systems.iiwa_commands_received(),
            "wsg_commands_received": self.systems.wsg_commands_received(),
            "utime_warmup": self.systems.utime_warmup,
            "status_period_s": IIWA_STATUS_PERIOD,
            "wsg_status_period_s": WSG_STATUS_PERIOD,
            "start_command_guard_s": START_COMMAND_GUARD,
            "joint_limit_margin_rad": float(JOINT_LIMIT_MARGIN),
            "inner_loop": self.scenario.station.inner_loop.kind,
            "velocity_filter_cutoff_hz": self.scenario.station.driver.velocity_filter_cutoff,
            "external_torque_limits_Nm": external_torque_limits(
                self.scenario.station.driver.external_torque_limit
            ).tolist(),
            "log_period_s": self.scenario.timeline.log_period,
            **self._command_timing(),
        }

    def _command_timing(self) -> dict:
        """When the commands were applied against kuka_driver's cycle (with ``record``)."""
        if self.systems.command_logger is None:
            return {}
        delays = self.systems.command_delays(self.simulator.get_context())
        late = delays[delays > 0]
        received = self.systems.iiwa_commands_received()
        return {
            "iiwa_commands_applied": len(delays),
            # applied a cycle or more after the one following the status they answer
            "iiwa_commands_late": len(late),
            "iiwa_command_cycles_late_max": int(late.max()) if len(late) else 0,
            "iiwa_command_delay_mean_s": float(np.mean(np.maximum(delays, 0))) * IIWA_STATUS_PERIOD
            if len(delays)
            else math.nan,
            # read, but replaced by a newer one before a cycle applied them
            "iiwa_commands_superseded": max(received - len(delays), 0),
        }

    def write_output(self, staging: Path) -> None:
        """Writes ``ground_truth.npz``, ``driver.json`` and ``scenario.yaml`` into ``staging``
        (a folder from :func:`doorlab.runtime.folders.prepare_output`)."""
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


def freeze_message(violation) -> str:
    """kuka_driver's external-torque stop in one line: the joint, the torque, the limit."""
    return (
        f"external torque: |tau_external| = {violation.value:.3g} N m on "
        f"{violation.joint_name} over kuka_driver's limit {violation.bound:.3g} N m at "
        f"t = {violation.t:.3f} s; the "
        "driver exits, as kuka_driver does ('Robot0 is in an unsafe state.')"
    )


class _StartGuardTripped(SimulationError):
    """A command arrived within the start guard."""
