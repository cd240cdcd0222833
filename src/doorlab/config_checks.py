"""The scenario's checks: one-line ConfigErrors naming the dotted field and its valid
range (:func:`doorlab.config.validate` calls them), and the bounds they use. The
sections are duck-typed here, so this module imports no dataclass of
:mod:`doorlab.config`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
from dataclasses import dataclass

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
KUKA_DAMPING_MODELS = ("rotor_link", "link", "driver_kd", "values")
"""``station.inner_loop.kuka_damping_model``: how KUKA's dimensionless damping becomes N m s/rad
(:func:`doorlab.cell.station.loop_gains`)."""


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


MAX_CUPBOARD_POSITION_ERROR = 0.05
"""Largest |station.cupboard_position_error| per axis [m]: 5 cm, twice the fingers' opening
for the approach (25 mm): beyond it a plan grasps at thin air whatever it does."""


def validate_position_error(error) -> None:
    """``station.cupboard_position_error``: three numbers within the bound [m]."""
    check(
        isinstance(error, (list, tuple))
        and len(error) == 3
        and all(
            isinstance(v, (int, float))
            and not isinstance(v, bool)
            and math.isfinite(v)
            and abs(v) <= MAX_CUPBOARD_POSITION_ERROR
            for v in error
        ),
        f"station.cupboard_position_error must be three numbers [m] within "
        f"+-{MAX_CUPBOARD_POSITION_ERROR:g} m, got {quote(error)}",
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
    choice("station.inner_loop.kuka_damping_model", loop.kuka_damping_model, KUKA_DAMPING_MODELS)
    values = loop.kuka_damping_values
    if loop.kuka_damping_model == "values":
        check(
            values is not None,
            "station.inner_loop.kuka_damping_model 'values' needs "
            "station.inner_loop.kuka_damping_values (7 numbers [N m s/rad])",
        )
    if values is not None:
        gains("station.inner_loop.kuka_damping_values", values, allow_zero=False)
        check(
            loop.kuka_damping_model == "values",
            "station.inner_loop.kuka_damping_values applies to kuka_damping_model 'values' "
            f"only; it is {quote(loop.kuka_damping_model)} (set it to values, or remove the "
            "values)",
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


MAX_LOAD_MASS = 7.0
"""Largest ``station.arm.load_mass`` [kg]: the iiwa 7's payload."""


def validate_arm_model(arm, time_step: float) -> None:
    """``station.arm`` (:class:`doorlab.config.ArmModelConfig`)."""
    from doorlab.kuka import CYCLE_PERIOD, MAX_LATENCY

    mass = arm.load_mass
    if mass is not None:
        check(
            isinstance(mass, (int, float)) and math.isfinite(mass) and 0 <= mass <= MAX_LOAD_MASS,
            f"station.arm.load_mass must be in [0, {MAX_LOAD_MASS:g}] kg (the iiwa 7's payload) "
            f"or null (exact: the gripper's mass), got {quote(mass)}",
        )
    gains("station.arm.coulomb_friction", arm.coulomb_friction, allow_zero=True)
    gains("station.arm.stiction", arm.stiction, allow_zero=True)
    for i, (fc, fs) in enumerate(zip(arm.coulomb_friction, arm.stiction, strict=True)):
        check(
            fs >= fc,
            f"station.arm.stiction[{i}] ({quote(fs)} N m) must be >= "
            f"station.arm.coulomb_friction[{i}] ({quote(fc)} N m): friction at rest is the "
            "largest",
        )
        check(fs <= 20.0, f"station.arm.stiction[{i}] must be at most 20 N m, got {quote(fs)}")
    positive("station.arm.friction_compensation_band", arm.friction_compensation_band)
    non_negative("station.arm.latency", arm.latency)
    non_negative("station.arm.latency_jitter", arm.latency_jitter)
    check(
        arm.latency + arm.latency_jitter <= MAX_LATENCY + 1e-12
        and arm.latency_jitter <= arm.latency + 1e-12,
        f"station.arm.latency ({quote(arm.latency)} s) and latency_jitter "
        f"({quote(arm.latency_jitter)} s): latency - jitter >= 0 and latency + jitter <= "
        f"{MAX_LATENCY:g} s (a command acts within the cycle after the one that received it)",
    )
    if arm.latency > 0 or arm.latency_jitter > 0:
        steps = CYCLE_PERIOD / time_step
        check(
            abs(steps - round(steps)) < 1e-9,
            f"station.arm.latency needs a station.time_step that divides the 5 ms cycle "
            f"(e.g. 0.0025, the arm preset's), got {quote(time_step)}",
        )
    gains("station.arm.external_torque_noise", arm.external_torque_noise, allow_zero=True)
    for i, value in enumerate(arm.external_torque_noise):
        check(
            value <= 10.0,
            f"station.arm.external_torque_noise[{i}] must be at most 10 N m, got {quote(value)}",
        )
    check(
        isinstance(arm.seed, int) and not isinstance(arm.seed, bool) and 0 <= arm.seed < 2**31,
        f"station.arm.seed must be an integer in [0, 2^31), got {quote(arm.seed)}",
    )


ENTRY_POINT_GROUP = "doorlab.controllers"
"""The entry-point group of installed controller plug-ins (:mod:`doorlab.episode.plugins`)."""
CONTROLLER_FORMS = "FILE.py:NAME, MODULE:NAME"
"""How a plug-in is named besides an installed one's name."""


@dataclass(frozen=True)
class ControllerSpec:
    """What a controller spec names (``Scenario.controller``, ``--controller``).

    Attributes:
        kind: ``builtin``, ``file`` (FILE.py:NAME), ``module`` (MODULE:NAME) or
            ``entry_point`` (an installed plug-in's name).
        target: The built-in's or entry point's name, the file's path or the module's name.
        name: NAME, the attribute in the file or module ("" for built-ins and entry points).
    """

    kind: str
    target: str
    name: str = ""


@functools.cache
def installed_controller_names() -> tuple[str, ...]:
    """The names of the installed plug-ins (entry points of :data:`ENTRY_POINT_GROUP`), read
    once per process."""
    from importlib.metadata import entry_points

    return tuple(sorted({entry.name for entry in entry_points(group=ENTRY_POINT_GROUP)}))


def _dotted(text: str) -> bool:
    return bool(text) and all(part.isidentifier() for part in text.split("."))


def controller_choices(builtins: tuple[str, ...]) -> str:
    """The valid controllers in words: the built-ins, the installed plug-ins, the forms."""
    installed = installed_controller_names()
    extra = f", installed: {', '.join(installed)}" if installed else ""
    return f"{', '.join(builtins)} (built-in{extra}), or a plug-in {CONTROLLER_FORMS}"


def controller_spec(value: object, builtins: tuple[str, ...]) -> ControllerSpec:
    """Parses a controller spec, without importing anything.

    Args:
        value: A built-in's name, an installed plug-in's name, ``FILE.py:NAME`` or
            ``MODULE:NAME`` (NAME may be dotted: an attribute of an attribute).
        builtins: The built-ins' names.

    Raises:
        ConfigError: Not one of those (the message lists the valid ones).
    """
    shown = quote(value)
    if not isinstance(value, str) or not value or value != value.strip():
        raise ConfigError(f"controller must be one of {controller_choices(builtins)}; got {shown}")
    if ":" not in value:
        if value in builtins:
            return ControllerSpec("builtin", value)
        if value in installed_controller_names():
            return ControllerSpec("entry_point", value)
        raise ConfigError(f"controller must be one of {controller_choices(builtins)}; got {shown}")
    target, _, name = value.rpartition(":")
    if not target or not _dotted(name):
        raise ConfigError(
            f"controller {shown}: a plug-in is {CONTROLLER_FORMS} (NAME a Python name, e.g. "
            "my_controller.py:build_plan)"
        )
    if target.endswith(".py") or "/" in target or os.sep in target:
        return ControllerSpec("file", target, name)
    if not _dotted(target):
        raise ConfigError(
            f"controller {shown}: {quote(target)} is neither a Python file nor a module name "
            f"(dotted Python names); a plug-in is {CONTROLLER_FORMS}"
        )
    return ControllerSpec("module", target, name)


def absolute_controller(value: str, base_dir: str | os.PathLike) -> str:
    """``value`` with a plug-in file's relative path made absolute against ``base_dir`` (other
    specs unchanged): a scenario then names the same file from any working directory, and a
    worker process or machine loads that file."""
    if not isinstance(value, str) or ":" not in value:
        return value
    target, _, name = value.rpartition(":")
    if not (target.endswith(".py") or "/" in target or os.sep in target):
        return value
    path = os.path.expanduser(target)
    if not os.path.isabs(path):
        path = os.path.join(os.fspath(base_dir), path)
    return f"{os.path.normpath(path)}:{name}"
