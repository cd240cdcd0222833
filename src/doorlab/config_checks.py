"""The scenario's checks: one-line ConfigErrors naming the dotted field and its valid
range (:func:`doorlab.config.validate` calls them), and the bounds they use. The
sections are duck-typed here, so this module imports no dataclass of
:mod:`doorlab.config`.
"""

from __future__ import annotations

import dataclasses
import math

from doorlab.constants import NUM_JOINTS
from doorlab.errors import ConfigError
from doorlab.runtime.inputs import quote

MAX_EPISODE_DURATION = 600.0
"""Longest timeline [s]: the sum of its durations (hold, approach, grasp, arc, extra_time; each
plan also settles 1 s). 25x the problem set's 24 s episode: the logs are kept in memory, and every
metric, plot and replay covers the whole episode; a longer one is surely a typo."""
MIN_ARC_SAMPLES = 10
"""The arc plan must tick and be logged at least this often: its metrics (tracking errors,
door lag) come from those samples, so ``control_period`` and ``log_period`` are at most
``arc_duration`` / 10."""
MAX_LOG_SAMPLES = 300_000
"""Most log samples of an episode (its length / ``log_period``): 600 s at 2 ms; each holds
about 50 numbers, ~120 MB kept in memory before the metrics' copies."""
COMMAND_TIMINGS = ("next_step", "kuka_driver")
"""``station.driver.timing``: when a plan's command acts (:class:`doorlab.config.DriverConfig`)."""


def check(condition: bool, message: str) -> None:
    if not condition:
        raise ConfigError(message)


def positive(name: str, value: float) -> None:
    check(
        isinstance(value, (int, float)) and math.isfinite(value) and value > 0,
        f"{name} must be a finite number > 0, got {quote(value)}",
    )


def non_negative(name: str, value: float) -> None:
    check(
        isinstance(value, (int, float)) and math.isfinite(value) and value >= 0,
        f"{name} must be a finite number >= 0, got {quote(value)}",
    )


def choice(name: str, value: str, choices: tuple[str, ...]) -> None:
    check(value in choices, f"{name} must be one of {', '.join(choices)}; got {quote(value)}")


def gains(name: str, values: list[float], *, allow_zero: bool) -> None:
    check(
        isinstance(values, (list, tuple)) and len(values) == NUM_JOINTS,
        f"{name} must be a list of {NUM_JOINTS} numbers, got {quote(values)}",
    )
    for i, v in enumerate(values):
        (non_negative if allow_zero else positive)(f"{name}[{i}]", v)


def validate_timeline(scenario) -> None:
    """Every duration and period finite, positive and bounded (see MAX_EPISODE_DURATION)."""
    timeline, time_step = scenario.timeline, scenario.station.time_step
    for f in dataclasses.fields(timeline):
        value = getattr(timeline, f.name)
        if f.name == "extra_time":
            non_negative(f"timeline.{f.name}", value)
        else:
            positive(f"timeline.{f.name}", value)
    durations = [f.name for f in dataclasses.fields(timeline) if not f.name.endswith("_period")]
    total = sum(getattr(timeline, name) for name in durations)
    check(
        total <= MAX_EPISODE_DURATION,
        f"the timeline's durations ({', '.join(f'timeline.{n}' for n in durations)}) add up "
        f"to {quote(total)} s; at most {MAX_EPISODE_DURATION:g} s (25x the problem set's "
        "episode: the logs are kept in memory and every metric, plot and replay covers the "
        "whole episode)",
    )
    check(
        time_step <= timeline.control_period,
        f"station.time_step ({time_step} s) must not exceed timeline.control_period "
        f"({timeline.control_period} s)",
    )
    check(
        timeline.log_period >= time_step,
        f"timeline.log_period ({timeline.log_period} s) must be >= station.time_step "
        f"({time_step} s)",
    )
    arc = timeline.arc_duration
    for name in ("control_period", "log_period"):
        value = getattr(timeline, name)
        check(
            value <= arc / MIN_ARC_SAMPLES,
            f"timeline.{name} ({quote(value)} s) must be at most timeline.arc_duration / "
            f"{MIN_ARC_SAMPLES} ({arc / MIN_ARC_SAMPLES:g} s): the arc plan must "
            + ("act" if name == "control_period" else "be logged")
            + f" at least {MIN_ARC_SAMPLES} times, its metrics come from those samples",
        )
    samples = (total + 4.0) / timeline.log_period  # + the plans' settle times
    check(
        samples <= MAX_LOG_SAMPLES,
        f"timeline.log_period ({timeline.log_period} s) gives {samples:.0f} log samples over "
        f"the episode; at most {MAX_LOG_SAMPLES} (about 50 numbers each, kept in memory)",
    )


def validate_safety(safety) -> None:
    check(isinstance(safety.enabled, bool), "station.safety.enabled must be true or false")
    check(
        isinstance(safety.joint_limit_margin, (int, float))
        and 0.0 <= safety.joint_limit_margin <= 0.5,
        f"station.safety.joint_limit_margin must be in [0, 0.5] rad, got "
        f"{quote(safety.joint_limit_margin)}",
    )
    positive("station.safety.gap_time", safety.gap_time)
    for name in ("speed_fraction", "torque_fraction"):
        value = getattr(safety, name)
        check(
            isinstance(value, (int, float)) and 0.0 < value <= 1.0,
            f"station.safety.{name} must be in (0, 1], got {quote(value)}",
        )


KUKA_STIFFNESS_MAX = 5000.0
"""KUKA's largest joint stiffness [N m/rad] (JointImpedanceControlMode)."""
KUKA_DAMPING_RANGE = (0.1, 1.0)
"""KUKA's dimensionless joint damping (JointImpedanceControlMode.setDamping*)."""


def validate_kuka(loop, driver, timeline) -> None:
    """KUKA's loop gains (``station.inner_loop.kuka_*``) and ``station.driver``."""
    gains("station.inner_loop.kuka_stiffness", loop.kuka_stiffness, allow_zero=False)
    gains("station.inner_loop.kuka_damping", loop.kuka_damping, allow_zero=False)
    for i, value in enumerate(loop.kuka_stiffness):
        check(
            value <= KUKA_STIFFNESS_MAX,
            f"station.inner_loop.kuka_stiffness[{i}] must be in (0, {KUKA_STIFFNESS_MAX:g}] "
            f"N m/rad (KUKA's joint impedance), got {quote(value)}",
        )
    low, high = KUKA_DAMPING_RANGE
    for i, value in enumerate(loop.kuka_damping):
        check(
            low <= value <= high,
            f"station.inner_loop.kuka_damping[{i}] must be in [{low:g}, {high:g}] (KUKA's "
            f"dimensionless damping), got {quote(value)}",
        )
    choice("station.driver.timing", driver.timing, COMMAND_TIMINGS)
    positive("station.driver.velocity_filter_cutoff", driver.velocity_filter_cutoff)
    positive("station.driver.external_torque_limit", driver.external_torque_limit)
    if driver.timing == "kuka_driver":
        check(
            abs(timeline.control_period - 0.005) < 1e-12,
            "station.driver.timing kuka_driver runs the plans at kuka_driver's 5 ms cycle: "
            f"timeline.control_period must be 0.005, got {quote(timeline.control_period)}",
        )
