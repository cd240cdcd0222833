"""The identification's status loop over LCM: the script (:mod:`.script`) answered status by
status, every command checked before it goes out, as ``doorlab run --hardware`` does
(:mod:`doorlab.hardware.episode`'s rules and constants):

- the first command no sooner than ``FIRST_COMMAND_DELAY`` (0.3 s) after the first status;
  statuses with a negative utime are skipped and never answered;
- the watchdog: no fresh status for ``WATCHDOG_TIMEOUT`` (50 ms) stops commanding
  (``driver_lost``);
- every command checked against ``station.safety``'s limits (:mod:`doorlab.cell.safety`); one
  that breaks a limit is not sent and the run stops (``safety_stop``); one ready more than a
  period after its status is dropped (the arm holds the previous one);
- Ctrl-C or SIGTERM stops commanding at once (``interrupted``).

When commanding stops the driver holds the last command (in position mode it never expires).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from drake import lcmt_iiwa_command

from doorlab.cell.safety import SafetyLimits, Violation, check_command
from doorlab.constants import NUM_JOINTS
from doorlab.hardware.episode import STALE_ANSWER, WATCHDOG_PERIODS, WATCHDOG_TIMEOUT, start_status
from doorlab.hardware.identify.script import Script
from doorlab.hardware.link import DriverLink, Status
from doorlab.hardware.protocol import IIWA_COMMAND_CHANNEL, IIWA_STATUS_PERIOD


@dataclass
class IdentifyLog:
    """Every status the script answered and the command that answered it (one row each).

    Attributes:
        utime: The status's utime [us]. arrival: Its arrival on the link's clock [s].
        q, q_commanded, v, tau_external: The status's joint positions measured and commanded
            [rad], filtered velocity [rad/s], external torque [N m] (7 each).
        q_ref, tau_ff: The command that answered it (7 each); NaN where none went out.
        sent: Whether a command went out for it (False: dropped as stale, or the stop).
    """

    utime: list[int] = field(default_factory=list)
    arrival: list[float] = field(default_factory=list)
    q: list[np.ndarray] = field(default_factory=list)
    q_commanded: list[np.ndarray] = field(default_factory=list)
    v: list[np.ndarray] = field(default_factory=list)
    tau_external: list[np.ndarray] = field(default_factory=list)
    q_ref: list[np.ndarray] = field(default_factory=list)
    tau_ff: list[np.ndarray] = field(default_factory=list)
    sent: list[bool] = field(default_factory=list)
    stale: int = 0
    skipped: int = 0

    def add(self, status: Status) -> None:
        nan = np.full(NUM_JOINTS, np.nan)
        self.utime.append(status.utime)
        self.arrival.append(status.arrival)
        self.q.append(status.q)
        self.q_commanded.append(status.q_commanded)
        self.v.append(nan if status.v is None else status.v)
        self.tau_external.append(nan if status.tau_external is None else status.tau_external)
        self.q_ref.append(nan)
        self.tau_ff.append(nan)
        self.sent.append(False)

    def arrays(self) -> dict[str, np.ndarray]:
        """The log as arrays (for ``identify_log.npz``): one row per status, ``cycle`` the
        status's cycle since the first (utime / 5 ms)."""
        out = {
            name: np.asarray(getattr(self, name), float if name != "sent" else bool)
            for name in ("arrival", "q", "q_commanded", "v", "tau_external", "q_ref", "tau_ff")
        }
        out["sent"] = np.asarray(self.sent, bool)
        utime = np.asarray(self.utime, np.int64)
        out["utime"] = utime
        out["cycle"] = (
            np.rint((utime - utime[0]) * 1e-6 / IIWA_STATUS_PERIOD).astype(np.int64)
            if len(utime)
            else utime
        )
        return out


@dataclass(frozen=True)
class SessionOutcome:
    """How the loop ended: ``ok`` (the script ran to its end), ``driver_lost``,
    ``safety_stop`` or ``interrupted``; the message, the violation, the interrupt."""

    status: str
    message: str
    violation: Violation | None
    interrupt: KeyboardInterrupt | None
    log: IdentifyLog


def run_session(
    script: Script,
    link: DriverLink,
    limits: SafetyLimits,
    *,
    wait: float,
    log: IdentifyLog | None = None,
) -> SessionOutcome:
    """Answers statuses with the script's commands until it ends or a stop (module doc).

    Args:
        log: Where to record (the caller's, so that what was recorded survives an exception
            this function does not expect); a new one if None.
    """
    log = IdentifyLog() if log is None else log
    command_message = lcmt_iiwa_command()
    command_message.num_joints = NUM_JOINTS
    command_message.num_torques = NUM_JOINTS
    q_ref_previous: np.ndarray | None = None
    t_previous: float | None = None
    status = start_status(link, wait)
    utime0 = status.utime
    last_fresh = status.arrival
    try:
        while True:
            log.add(status)
            command = script.send(status)
            if command is None:
                return SessionOutcome("ok", "", None, None, log)
            t = (status.utime - utime0) * 1e-6
            previous = status.q if q_ref_previous is None else q_ref_previous
            dt = IIWA_STATUS_PERIOD if t_previous is None else t - t_previous
            violation = check_command(
                limits,
                t=t,
                q_ref=command.q_ref,
                tau_ff=command.tau_ff,
                q_measured=status.q,
                q_ref_previous=previous,
                dt=max(dt, IIWA_STATUS_PERIOD),
            )
            if violation is not None:
                return SessionOutcome(
                    "safety_stop", f"safety stop: {violation.message()}", violation, None, log
                )
            log.q_ref[-1], log.tau_ff[-1] = command.q_ref, command.tau_ff
            if link.clock() - status.arrival > STALE_ANSWER:
                log.stale += 1  # the driver holds the last command; the next is fresh
            else:
                command_message.utime = status.utime
                command_message.joint_position = [float(v) for v in command.q_ref]
                command_message.joint_torque = [float(v) for v in command.tau_ff]
                link.lcm.Publish(IIWA_COMMAND_CHANNEL, command_message.encode())
                log.sent[-1] = True
                q_ref_previous, t_previous = command.q_ref, t
            while True:  # the next fresh status, or the watchdog
                nxt = link.next_status(last_fresh + WATCHDOG_TIMEOUT)
                if nxt is None:
                    lost = link.clock() - last_fresh
                    return SessionOutcome(
                        "driver_lost",
                        f"no fresh status for {1e3 * lost:.0f} ms after t = {t:.3f} s "
                        f"(watchdog: {WATCHDOG_PERIODS} periods): commanding stopped, the "
                        "driver holds the last command",
                        None,
                        None,
                        log,
                    )
                if not nxt.valid:
                    log.skipped += 1
                    continue
                if nxt.utime > status.utime:
                    break
            status, last_fresh = nxt, nxt.arrival
    except KeyboardInterrupt as e:  # Ctrl-C, SIGTERM (doorlab.errors.Interrupted)
        return SessionOutcome("interrupted", "interrupted", None, e, log)
