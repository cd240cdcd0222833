"""Domain exceptions of doorlab.

Every error a user can cause derives from :class:`DoorlabError`, so the CLI can turn
it into a one-line message and exit code 2 without a traceback.
"""

from __future__ import annotations


class DoorlabError(Exception):
    """Root of every doorlab error."""


class ConfigError(DoorlabError, ValueError):
    """A scenario, CLI option or API argument is invalid (names the field and range)."""


class PluginError(ConfigError):
    """A controller plug-in (``--controller FILE.py:NAME``, ``MODULE:NAME`` or an installed one)
    cannot be used: it does not import, NAME is neither a :class:`doorlab.Controller` nor a
    function ``(scenario, geometry, plant) -> ArcPlan``, or its build raised or returned no
    ArcPlan. The message is one line naming the plug-in and what went wrong."""


class IkError(DoorlabError):
    """Inverse kinematics found no solution within the tolerances.

    Attributes:
        knot: Index of the knot that failed (None for a one-shot solve).
        residual: Position residual of the best iterate [m] (nan if unknown).
    """

    def __init__(self, message: str, *, knot: int | None = None, residual: float = float("nan")):
        super().__init__(message)
        self.knot = knot
        self.residual = residual


class SimulationError(DoorlabError):
    """The simulation could not run (e.g. the physics engine failed)."""


class OutputError(DoorlabError):
    """An output folder cannot be written (exists without --force, not writable)."""


class Interrupted(KeyboardInterrupt):
    """A termination signal (SIGTERM, SIGHUP) raised as an exception, like Ctrl-C's
    KeyboardInterrupt, so that every way out runs the same clean-up.

    Catch ``KeyboardInterrupt`` to handle Ctrl-C and these alike; the exit code is
    ``128 + signum`` (130 for SIGINT, 143 for SIGTERM, 129 for SIGHUP).

    Attributes:
        signum: The signal's number.
    """

    def __init__(self, signum: int):
        super().__init__(f"signal {signum}")
        self.signum = signum

    @property
    def exit_code(self) -> int:
        """The process's exit code for this signal (128 + signum)."""
        return 128 + self.signum


def interrupt_exit_code(error: KeyboardInterrupt) -> int:
    """The exit code of an interruption: 128 + the signal (130 for a plain Ctrl-C)."""
    return error.exit_code if isinstance(error, Interrupted) else 130


class RunStopped(DoorlabError):
    """A run stopped before its end for a reason that is a result, not a bug: its status
    (``safety_stop``, ``driver_lost``) sets the exit code (:data:`doorlab.outputs.runs.EXIT_CODES`).

    Attributes:
        status: The run's status.
        result: The logs up to the stop (an :class:`doorlab.episode.result.EpisodeResult`), or None.
    """

    status = "stopped"

    def __init__(self, message: str, *, result=None):
        super().__init__(message)
        self.result = result


class SafetyStop(RunStopped):
    """A command broke a safety limit; it was not sent (:mod:`doorlab.cell.safety`).

    Attributes:
        violation: The :class:`doorlab.cell.safety.Violation` (limit, joint, value, bound, time).
    """

    status = "safety_stop"

    def __init__(self, violation, *, result=None):
        super().__init__(f"safety stop: {violation.message()}", result=result)
        self.violation = violation


class DriverLost(RunStopped):
    """The arm's driver stopped sending statuses during the run; commanding stopped."""

    status = "driver_lost"


class ControllerError(RunStopped):
    """A controller raised during a control tick, or returned something that is not a command
    (a q_ref and a tau_ff of 7 finite numbers each): the run stopped there (status
    ``controller_error``), with its logs up to the stop. Only plug-ins are checked so:
    a built-in's exception is a bug of doorlab's."""

    status = "controller_error"


class NoDriver(DoorlabError):
    """No driver answered before the run started (nothing moved, nothing was written)."""
