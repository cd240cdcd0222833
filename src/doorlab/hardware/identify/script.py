"""The motions ``doorlab identify`` makes the arm run, one command per status (pure: a generator
fed each status, yielding each command; no LCM, no clock).

In order (defaults of :class:`ScriptSettings`; every command is checked against the real run's
limits before it goes out, :mod:`doorlab.cell.safety`):

1. **move** from where the arm stands to the calibration pose (:data:`Q_CALIBRATION`, near the
   problem set's grasp pose, clear of the cupboard), a cubic in joint space over
   ``move_duration``;
2. **rest** there ``rest_duration``: KUKA's external torque at rest is its load-data error
   plus noise (:func:`doorlab.hardware.identify.fit.fit_rest`);
3. per joint, **breakaway**: q_ref = the last measured q (KUKA's friction observer off, as
   for the impedance plan) and tau_ff = the torque the rest showed missing plus a slow ramp,
   up and then down, each until the joint moves (``breakaway_speed``) or the ramp reaches
   ``breakaway_torque_max``; then back to the pose (``fit_breakaway``, ``fit_coulomb``);
4. per joint, **steps**: q_ref ramps by +-``step_size`` at ``step_speed_fraction`` of the data
   sheet's speed (a jump would break the joint-speed limit), holds, ramps back (``fit_step``:
   effective inertia, damping, latency);
5. per joint, **timed steps**: single-cycle steps of the largest size the joint-speed limit
   allows, each answering a known status (``fit_timed_steps``: each cycle's latency, so the
   latency and its jitter).

Each command carries a label (:class:`Segment`) so the fits find their samples in the log.
"""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import dataclass, field

import numpy as np

from doorlab.constants import JOINT_SPEED_LIMITS, NUM_JOINTS, Q_GRASP
from doorlab.kuka import CYCLE_PERIOD

PERIOD = CYCLE_PERIOD
Q_CALIBRATION = tuple(float(v) for v in Q_GRASP + np.array([0.0, -0.3, 0.0, -0.35, 0.0, 0.2, 0.0]))
"""The calibration pose [rad]: the problem set's grasp pose (where the damping models are
defined) drawn back 14 cm from the handle (joints 2, 4, 6), so that no step of the script
touches the cupboard (at the grasp pose itself the fingers hit the handle when joint 1 or 3
steps: 2.3 N m of contact, measured)."""


@dataclass(frozen=True)
class ScriptSettings:
    """The script's amplitudes and durations (``doorlab identify``'s options set some).

    Attributes:
        joints: Which joints (0-6) to identify.
        repeats: Steps, timed steps and breakaways per joint and direction.
        move_duration: The move to the calibration pose [s].
        rest_duration: The rest at it [s].
        step_size: The ramped step [rad] (within the position-gap limit: 1.5 deg).
        step_speed_fraction: The step's ramp speed, a fraction of the data sheet's speed
            (within ``station.safety.speed_fraction``).
        step_hold: How long each step and its return are held [s].
        timed_step_hold: How long each timed step is held [s].
        breakaway_rate: The feed-forward ramp [N m/s].
        breakaway_torque_max: The ramp stops there [N m], or at the safety limit's 0.9.
        breakaway_speed: The joint has broken away at this filtered speed [rad/s].
        breakaway_travel: ... or once it has moved this far [rad].
        return_duration: The move back to the pose after a breakaway [s].
        bias_duration: How long the rest's missing torque is ramped in [s].
        slide_duration: After a breakaway the torque is held this long at most [s] (the
            joint slides: Coulomb friction), or until ``breakaway_travel``.
    """

    joints: tuple[int, ...] = tuple(range(NUM_JOINTS))
    repeats: int = 2
    move_duration: float = 12.0
    rest_duration: float = 3.0
    step_size: float = np.deg2rad(1.5)
    step_speed_fraction: float = 0.4
    step_hold: float = 0.6
    timed_step_hold: float = 0.4
    breakaway_rate: float = 2.0
    breakaway_torque_max: float = 8.0
    breakaway_speed: float = 0.02
    breakaway_travel: float = np.deg2rad(0.5)
    return_duration: float = 1.0
    bias_duration: float = 1.0
    slide_duration: float = 0.3
    q_calibration: tuple[float, ...] = Q_CALIBRATION

    def duration_estimate(self) -> float:
        """The script's length if every breakaway ramps all the way [s] (an upper bound)."""
        per_joint = (
            2 * self.repeats * (self.breakaway_torque_max / self.breakaway_rate)
            + 2 * self.repeats * (self.return_duration + 0.3)
            + 4 * self.repeats * (self.step_hold + 0.1)
            + 4 * self.repeats * self.timed_step_hold
        )
        return self.move_duration + self.rest_duration + len(self.joints) * per_joint


@dataclass
class Segment:
    """A labelled stretch of the script.

    Attributes:
        kind: ``move``, ``rest``, ``breakaway``, ``return``, ``step``, ``timed_step``.
        joint: The joint it moves (-1: all / none). start: Its first command's index.
        stop: One past its last command's index. sign: +1 or -1 (a direction).
        info: What the script measured on the way (a breakaway's torque).
    """

    kind: str
    joint: int
    start: int
    stop: int = -1
    sign: int = 0
    info: dict = field(default_factory=dict)


@dataclass
class Command:
    """One command: q_ref (7,) [rad] and tau_ff (7,) [N m]."""

    q_ref: np.ndarray
    tau_ff: np.ndarray


class Script:
    """The identification script as a generator of commands (see the module docstring).

    Use: ``script = Script(settings, q_start, limits_tau)``, then for each status
    ``command = script.send(status)`` until it returns None (done). ``segments`` lists what
    ran, with command indices.

    Args:
        settings: The amplitudes and durations.
        q_start: Where the arm stands (7,) [rad].
        tau_limit: The largest |tau_ff| the safety limits allow per joint (7,) [N m].
        speed_limit: The largest implied joint speed the limits allow (7,) [rad/s].
    """

    def __init__(
        self,
        settings: ScriptSettings,
        q_start: np.ndarray,
        *,
        tau_limit: np.ndarray,
        speed_limit: np.ndarray,
    ):
        self.settings = settings
        self.q_start = np.asarray(q_start, float)
        self.q_c = np.asarray(settings.q_calibration, float)
        self.tau_limit = np.asarray(tau_limit, float)
        self.speed_limit = np.asarray(speed_limit, float)
        self.segments: list[Segment] = []
        self.count = 0
        self.rest_bias = np.zeros(NUM_JOINTS)
        self.tau_base = np.zeros(NUM_JOINTS)  # added to every command after the rest
        self._generator = self._script()
        self._started = False

    def send(self, status) -> Command | None:
        """The command answering ``status`` (None: the script is over)."""
        try:
            if not self._started:
                self._started = True
                next(self._generator)  # to the first status
            command = self._generator.send(status)
        except StopIteration:
            self._close()
            return None
        self.count += 1
        return command

    def _close(self) -> None:
        if self.segments and self.segments[-1].stop < 0:
            self.segments[-1].stop = self.count

    def _begin(self, kind: str, joint: int = -1, sign: int = 0) -> Segment:
        self._close()
        segment = Segment(kind, joint, self.count, sign=sign)
        self.segments.append(segment)
        return segment

    def _hold(self, q: np.ndarray, tau: np.ndarray | None, seconds: float) -> Generator:
        tau = self.tau_base if tau is None else tau
        for _ in range(max(1, round(seconds / PERIOD))):
            yield Command(q.copy(), tau.copy())

    def _move(self, q_from: np.ndarray, q_to: np.ndarray, seconds: float) -> Generator:
        n = max(1, round(seconds / PERIOD))
        for k in range(1, n + 1):
            s = k / n
            blend = 3 * s**2 - 2 * s**3
            yield Command(q_from + blend * (q_to - q_from), self.tau_base.copy())

    def _script(self) -> Generator:
        s = self.settings
        status = yield
        # 1. move, 2. rest
        self._begin("move")
        status = yield from self._relay(self._move(self.q_start, self.q_c, s.move_duration))
        self._begin("rest")
        torques = []
        for command in self._hold(self.q_c, None, s.rest_duration):
            status = yield command
            if status.tau_external is not None:
                torques.append(status.tau_external)
        if torques:  # what KUKA's model lacks at rest: its load-data error
            self.rest_bias = -np.mean(torques[len(torques) // 2 :], axis=0)
        # From here on every command adds it, ramped in: the arm stands at the pose itself
        # (not sagged by what KUKA's gravity model lacks), so q_ref = q starts there.
        self._begin("bias")
        n = max(1, round(s.bias_duration / PERIOD))
        for k in range(1, n + 1):
            status = yield Command(self.q_c.copy(), (k / n) * self.rest_bias)
        self.tau_base = np.clip(self.rest_bias, -0.5 * self.tau_limit, 0.5 * self.tau_limit)
        status = yield from self._relay(self._hold(self.q_c, None, 0.5))
        # 3. breakaways
        for joint in s.joints:
            for _ in range(s.repeats):
                for sign in (+1, -1):
                    status = yield from self._breakaway(joint, sign, status)
        # 4. steps
        for joint in s.joints:
            speed = s.step_speed_fraction * JOINT_SPEED_LIMITS[joint]
            for _ in range(s.repeats):
                for sign in (+1, -1):
                    self._begin("step", joint, sign)
                    target = self.q_c.copy()
                    target[joint] += sign * s.step_size
                    ramp = max(1, int(np.ceil(s.step_size / (speed * PERIOD))))
                    status = yield from self._relay(self._linear(self.q_c, target, ramp))
                    status = yield from self._relay(self._hold(target, None, s.step_hold))
                    status = yield from self._relay(self._linear(target, self.q_c, ramp))
                    status = yield from self._relay(self._hold(self.q_c, None, s.step_hold))
        # 5. timed steps
        for joint in s.joints:
            size = 0.9 * self.speed_limit[joint] * PERIOD
            for _ in range(s.repeats):
                for sign in (+1, -1):
                    self._begin("timed_step", joint, sign)
                    target = self.q_c.copy()
                    target[joint] += sign * size
                    status = yield from self._relay(self._hold(target, None, s.timed_step_hold))
                    status = yield from self._relay(self._hold(self.q_c, None, s.timed_step_hold))
        self._close()

    def _linear(self, q_from: np.ndarray, q_to: np.ndarray, n: int) -> Generator:
        for k in range(1, n + 1):
            yield Command(q_from + (k / n) * (q_to - q_from), self.tau_base.copy())

    def _relay(self, commands) -> Generator:
        status = None
        for command in commands:
            status = yield command
        return status

    def _breakaway(self, joint: int, sign: int, status) -> Generator:
        s = self.settings
        segment = self._begin("breakaway", joint, sign)
        limit = min(s.breakaway_torque_max, 0.9 * self.tau_limit[joint])
        bias = self.tau_base.copy()
        start = np.asarray(status.q, float).copy()
        tau_ramp = 0.0
        broke = False
        while True:
            tau = bias.copy()
            tau[joint] += sign * tau_ramp
            tau = np.clip(tau, -0.9 * self.tau_limit, 0.9 * self.tau_limit)
            q_ref = self.q_c.copy()
            q_ref[joint] = status.q[joint]  # KUKA's observer off: q_ref = q
            status = yield Command(q_ref, tau)
            moved = abs(status.q[joint] - start[joint])
            speed = abs(status.v[joint]) if status.v is not None else 0.0
            if speed >= s.breakaway_speed or moved >= s.breakaway_travel:
                broke = True
                break
            if tau_ramp >= limit:
                break
            tau_ramp += s.breakaway_rate * PERIOD
        segment.info = {"broke_away": broke, "tau_ff": float(tau[joint]), "ramp": tau_ramp}
        # sliding: the torque held (Coulomb friction), until the travel or the time is up
        for _ in range(round(s.slide_duration / PERIOD) if broke else 0):
            if abs(status.q[joint] - start[joint]) >= s.breakaway_travel:
                break
            q_ref = self.q_c.copy()
            q_ref[joint] = status.q[joint]
            status = yield Command(q_ref, tau)
        self._begin("return", joint, sign)
        here = np.asarray(status.q, float).copy()
        q_from = self.q_c.copy()
        q_from[joint] = here[joint]
        status = yield from self._relay(self._move(q_from, self.q_c, s.return_duration))
        status = yield from self._relay(self._hold(self.q_c, None, 0.3))
        return status
