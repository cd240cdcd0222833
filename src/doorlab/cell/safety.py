"""Limits every arm command is checked against before it goes out (pure functions).

``doorlab run --hardware`` checks each command before it publishes it; a simulated run does the
same when ``station.safety.enabled`` is set, so a plan can be rehearsed under the exact limits
of the real run. A violation stops the run before that command is sent (status
``safety_stop``). The limits, from :mod:`doorlab.constants`' data sheet and
:class:`doorlab.config.SafetyConfig` (defaults in brackets):

``joint_position``
    |q_ref_i| <= limit_i - ``joint_limit_margin`` [5 deg]; a joint that already stands in that
    band when the run starts may be commanded anywhere up to where it stood (q_home has joint 4
    at 119.98 deg of its 120 deg), never further out.
``position_gap``
    |q_ref_i - q_measured_i| <= speed_limit_i x ``gap_time`` [20 ms]: the arm could close the
    gap at its data-sheet speed within that time (1.7-3.1 deg).
``joint_speed``
    |q_ref_i - q_ref_i(previous command)| / dt <= ``speed_fraction`` [0.5] x speed_limit_i: the
    speed the commands themselves imply (the first command is compared with the measured q).
``feedforward_torque``
    |tau_ff_i| <= ``torque_fraction`` [0.25] x torque_limit_i (44, 27.5 and 10 N m).
``finite``
    every entry of q_ref and tau_ff is a finite number.

The defaults leave each of the shipped plans a wide margin (measured over the four controllers,
doors open and closed, default scenario): the largest gap 3.4 ms of travel at the data-sheet
speed, the largest implied speed 0.24 of it, the largest tau_ff 0.035 of the torque limit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import LeafSystem

from doorlab.cell.frames import ARM_JOINTS
from doorlab.config import SafetyConfig
from doorlab.constants import (
    JOINT_POSITION_LIMITS,
    JOINT_SPEED_LIMITS,
    JOINT_TORQUE_LIMITS,
    NUM_JOINTS,
)
from doorlab.errors import SafetyStop

LIMIT_NAMES = ("finite", "joint_position", "position_gap", "joint_speed", "feedforward_torque")
"""The checks, in the order they are made."""

_UNITS = {
    "finite": "",
    "joint_position": "rad",
    "position_gap": "rad",
    "joint_speed": "rad/s",
    "feedforward_torque": "N m",
    "external_torque": "N m",
}
"""Units by limit; ``external_torque`` is kuka_driver's freeze, checked on each status
(:class:`doorlab.cell.arm_cell.ExternalTorqueWatch`), not on commands."""


@dataclass(frozen=True)
class SafetyLimits:
    """The bounds of one run, per joint (7,).

    Attributes:
        q_max: Largest |q_ref| [rad]. gap_max: Largest |q_ref - q_measured| [rad].
        speed_max: Largest implied joint speed [rad/s]. tau_max: Largest |tau_ff| [N m].
    """

    q_max: np.ndarray
    gap_max: np.ndarray
    speed_max: np.ndarray
    tau_max: np.ndarray

    @classmethod
    def from_config(cls, config: SafetyConfig, q_start: np.ndarray) -> SafetyLimits:
        """The limits for a run whose arm starts at ``q_start`` (7,) [rad]."""
        inside = JOINT_POSITION_LIMITS - config.joint_limit_margin
        return cls(
            q_max=np.maximum(inside, np.abs(np.asarray(q_start, float))),
            gap_max=JOINT_SPEED_LIMITS * config.gap_time,
            speed_max=JOINT_SPEED_LIMITS * config.speed_fraction,
            tau_max=JOINT_TORQUE_LIMITS * config.torque_fraction,
        )

    def to_dict(self) -> dict[str, list[float]]:
        """JSON-ready bounds by limit name (per joint)."""
        return {
            "joint_position_rad": self.q_max.tolist(),
            "position_gap_rad": self.gap_max.tolist(),
            "joint_speed_rad_s": self.speed_max.tolist(),
            "feedforward_torque_Nm": self.tau_max.tolist(),
        }


@dataclass(frozen=True)
class Violation:
    """A command that broke a limit.

    Attributes:
        limit: One of :data:`LIMIT_NAMES`. joint: The joint's index 0-6.
        value: The offending value. bound: The limit it broke (both in the limit's unit).
        t: Episode time of the command [s].
    """

    limit: str
    joint: int
    value: float
    bound: float
    t: float

    @property
    def joint_name(self) -> str:
        """The joint's model name (``iiwa_joint_1`` .. ``iiwa_joint_7``)."""
        return ARM_JOINTS[self.joint]

    def message(self) -> str:
        """One line: which limit, which joint, when."""
        if self.limit == "finite":
            return f"{self.joint_name}: a non-finite command at t = {self.t:.3f} s"
        unit = _UNITS[self.limit]
        digits = 4
        while f"{self.value:.{digits}g}" == f"{self.bound:.{digits}g}" and digits < 12:
            digits += 2  # show where the value passed the bound
        return (
            f"{self.limit} limit broken on {self.joint_name} at t = {self.t:.3f} s: "
            f"{self.value:.{digits}g} {unit} > {self.bound:.{digits}g} {unit}"
        )

    def to_dict(self) -> dict:
        """JSON-ready fields (``value`` is null for a non-finite command)."""
        value = self.value if math.isfinite(self.value) else None
        return {
            "limit": self.limit,
            "joint": self.joint_name,
            "value": value,
            "bound": self.bound,
            "unit": _UNITS[self.limit],
            "t": self.t,
        }


def check_command(
    limits: SafetyLimits,
    *,
    t: float,
    q_ref: np.ndarray,
    tau_ff: np.ndarray,
    q_measured: np.ndarray,
    q_ref_previous: np.ndarray,
    dt: float,
) -> Violation | None:
    """The first limit the command (q_ref, tau_ff) at time t breaks, or None.

    Args:
        limits: The run's bounds.
        t: Episode time [s]. q_ref: (7,) [rad]. tau_ff: (7,) [N m].
        q_measured: The arm's measured q when the command is made (7,) [rad].
        q_ref_previous: The previous command's q_ref (the measured q before the first) [rad].
        dt: Time since the previous command [s] (> 0).
    """
    q_ref = np.asarray(q_ref, float)
    tau_ff = np.asarray(tau_ff, float)
    bad = ~(np.isfinite(q_ref) & np.isfinite(tau_ff))
    if bad.any():
        return Violation("finite", int(np.argmax(bad)), math.nan, math.nan, t)
    checks = (
        ("joint_position", np.abs(q_ref), limits.q_max),
        ("position_gap", np.abs(q_ref - q_measured), limits.gap_max),
        ("joint_speed", np.abs(q_ref - q_ref_previous) / dt, limits.speed_max),
        ("feedforward_torque", np.abs(tau_ff), limits.tau_max),
    )
    for name, values, bounds in checks:
        over = values > bounds
        if over.any():
            joint = int(np.argmax(values - bounds))
            return Violation(name, joint, float(values[joint]), float(bounds[joint]), t)
    return None


class SafetyMonitor(LeafSystem):
    """Checks the commands a simulated cell receives, at every control tick, before the plant
    steps with them (``station.safety.enabled``); raises :class:`doorlab.errors.SafetyStop`.

    Its publish event fires ``offset`` after each tick t_k: after the tick's command switches
    on (``lag`` after t_k) and before the first plant step after t_k (at least twice ``lag``
    after it, :func:`doorlab.episode.schedule.tick_lag`), so it sees what the plant will step with
    and the arm the plan saw. Python per control tick, not per plant step.

    Input ports: ``iiwa_position`` (q_ref, 7), ``iiwa_feedforward_torque`` (7),
    ``iiwa_position_measured`` (7).
    """

    def __init__(self, limits: SafetyLimits, *, control_period: float, offset: float):
        super().__init__()
        self.set_name("safety_monitor")
        self._limits = limits
        self._period = control_period
        self._offset = offset
        self._q_ref = self.DeclareVectorInputPort("iiwa_position", NUM_JOINTS)
        self._tau_ff = self.DeclareVectorInputPort("iiwa_feedforward_torque", NUM_JOINTS)
        self._q = self.DeclareVectorInputPort("iiwa_position_measured", NUM_JOINTS)
        self._previous: np.ndarray | None = None
        self.DeclarePeriodicPublishEvent(control_period, offset, self._check)

    def _check(self, context) -> None:
        t = round((context.get_time() - self._offset) / self._period) * self._period
        q = self._q.Eval(context)
        q_ref = self._q_ref.Eval(context)
        previous = q if self._previous is None else self._previous
        violation = check_command(
            self._limits,
            t=t,
            q_ref=q_ref,
            tau_ff=self._tau_ff.Eval(context),
            q_measured=q,
            q_ref_previous=previous,
            dt=self._period,
        )
        if violation is not None:
            raise SafetyStop(violation)
        self._previous = np.array(q_ref)
