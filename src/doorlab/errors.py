"""Domain exceptions of doorlab.

Every error a user can cause derives from :class:`DoorlabError`, so the CLI can turn
it into a one-line message and exit code 2 without a traceback.
"""

from __future__ import annotations


class DoorlabError(Exception):
    """Root of every doorlab error."""


class ConfigError(DoorlabError, ValueError):
    """A scenario, CLI option or API argument is invalid (names the field and range)."""


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
