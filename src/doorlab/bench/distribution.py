"""The cupboards a benchmark draws: :class:`BenchDistribution` (typed, loaded from YAML like the
scenario), each episode's draw from its own seeded stream, and the benchmark's planned runs.

Episode i of seed S draws from ``numpy.random.default_rng([S, i])``: the same cupboards
whatever the number of episodes, the jobs or the executor (episode 7 of 200 is episode 7 of
1,000), and every controller meets the same N cupboards (a paired comparison). Each episode
draws :data:`DRAWS` uniform numbers in one order, whatever ranges are zero, so that changing
one range leaves the other fields' draws alone.

What varies is what the cell can vary honestly: where the cupboard truly stands against where
the plans believe it (``station.cupboard_yaw_error``, ``station.cupboard_position_error``),
how stiff its hinge turns (``station.hinge_damping``), how well the fingers grip the handle
(``station.friction``) and where the grasp IK aims Q (``ik.grasp_offset``: the controllers
that grasp through :func:`doorlab.grasp_configuration`; the built-in ``ik`` grasps at its first
knot and does not see it). The doors start closed.

Example YAML (every key optional; unknown keys are errors)::

    yaw_error_deg: 5.0              # station.cupboard_yaw_error ~ U(-5, 5) deg
    position_error_mm: [5, 5, 2]    # station.cupboard_position_error ~ U(-x, x) per axis of W
    hinge_damping: [0.5, 4.0]       # station.hinge_damping ~ log-uniform [N m s/rad]
    friction: [0.6, 1.0]            # station.friction ~ uniform [-]
    grasp_offset_mm: [0.5, 0.5, 0.5]  # ik.grasp_offset ~ U(-x, x) per axis of W
"""

from __future__ import annotations

import copy
import dataclasses
import math
from pathlib import Path

import numpy as np

from doorlab.bench.document import BenchDistribution
from doorlab.config import (
    MAX_CUPBOARD_POSITION_ERROR,
    MAX_CUPBOARD_YAW_ERROR,
    MAX_GRASP_OFFSET,
    Scenario,
    _check_shape,
    validate,
)
from doorlab.errors import ConfigError
from doorlab.runtime.inputs import load_yaml, quote, read_text_file
from doorlab.sweep.spec import PlannedRun, scenario_key

__all__ = [
    "AXES",
    "DRAWS",
    "BenchDistribution",
    "describe_distribution",
    "draw_episode",
    "load_distribution",
    "plan_bench",
    "validate_distribution",
]

AXES = (
    "episode",
    "station.cupboard_yaw_error",
    "station.cupboard_position_error[0]",
    "station.cupboard_position_error[1]",
    "station.cupboard_position_error[2]",
    "station.hinge_damping",
    "station.friction",
    "ik.grasp_offset[0]",
    "ik.grasp_offset[1]",
    "ik.grasp_offset[2]",
)
"""The table's columns of each episode's cupboard (SI units: rad, m, N m s/rad, -)."""
DRAWS = 9
"""Uniform numbers each episode draws, in the order of :data:`AXES` after ``episode``."""
MAX_EPISODES = 100_000
"""Most episodes per controller (a benchmark of 1,000 is a long afternoon on 2 cores)."""


def validate_distribution(distribution: BenchDistribution) -> BenchDistribution:
    """Checks every range against the scenario's bounds; returns the distribution.

    Raises:
        ConfigError: Naming the field and its valid range.
    """
    d = distribution

    def half_widths(name: str, values, count: int, bound: float, unit: str) -> None:
        ok = (
            isinstance(values, (list, tuple))
            and len(values) == count
            and all(_number(v) and 0 <= v <= bound for v in values)
        )
        if not ok:
            raise ConfigError(
                f"distribution.{name} must be {count} half-width{'s' if count > 1 else ''} in "
                f"[0, {bound:g}] {unit}, got {quote(values)}"
            )

    half_widths("yaw_error_deg", [d.yaw_error_deg], 1, math.degrees(MAX_CUPBOARD_YAW_ERROR), "deg")
    half_widths(
        "position_error_mm", d.position_error_mm, 3, 1e3 * MAX_CUPBOARD_POSITION_ERROR, "mm"
    )
    half_widths("grasp_offset_mm", d.grasp_offset_mm, 3, 1e3 * MAX_GRASP_OFFSET, "mm")
    for name, low_bound in (("hinge_damping", 0.0), ("friction", 0.0)):
        values = getattr(d, name)
        ok = (
            isinstance(values, (list, tuple))
            and len(values) == 2
            and all(_number(v) for v in values)
            and low_bound <= values[0] <= values[1]
            and (name != "hinge_damping" or values[0] > 0)
            and values[1] <= 100.0
        )
        if not ok:
            raise ConfigError(
                f"distribution.{name} must be [low, high] with "
                f"{'0 < low' if name == 'hinge_damping' else '0 <= low'} <= high <= 100, got "
                f"{quote(values)}"
            )
    return distribution


def _number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def load_distribution(path: str | Path | None) -> BenchDistribution:
    """The distribution of a YAML file (keys left out keep the defaults), or the defaults.

    Raises:
        ConfigError: Missing or invalid file, unknown keys, wrong types, ranges out of bounds
            (one line naming the file and the field).
    """
    if path is None:
        return validate_distribution(BenchDistribution())
    from pydrake.common.yaml import yaml_load_typed

    path = Path(path)
    prefix = f"distribution file {str(path)!r}: "
    text = read_text_file(path, what="distribution file")
    try:
        data = load_yaml(text)
        if data is None:
            return validate_distribution(BenchDistribution())
        _check_shape(data, BenchDistribution, "")
        loaded = yaml_load_typed(schema=BenchDistribution, data=text, defaults=BenchDistribution())
        return validate_distribution(loaded)
    except ConfigError as e:
        raise ConfigError(f"{prefix}{e}") from None


def draw_episode(distribution: BenchDistribution, seed: int, episode: int) -> dict[str, float]:
    """Episode ``episode``'s cupboard: :data:`AXES`' values (but ``episode``), SI units."""
    d = distribution
    u = np.random.default_rng([seed, episode]).random(DRAWS)

    def symmetric(x: float, half_width: float) -> float:
        return float((2.0 * x - 1.0) * half_width)

    low, high = d.hinge_damping
    damping = float(math.exp(math.log(low) + u[4] * (math.log(high) - math.log(low))))
    f_low, f_high = d.friction
    values = {
        "station.cupboard_yaw_error": math.radians(symmetric(u[0], d.yaw_error_deg)),
        **{
            f"station.cupboard_position_error[{k}]": 1e-3 * symmetric(u[1 + k], w)
            for k, w in enumerate(d.position_error_mm)
        },
        "station.hinge_damping": damping,
        "station.friction": float(f_low + u[5] * (f_high - f_low)),
        **{
            f"ik.grasp_offset[{k}]": 1e-3 * symmetric(u[6 + k], w)
            for k, w in enumerate(d.grasp_offset_mm)
        },
    }
    return values


def episode_scenario(base: Scenario, controller: str, values: dict[str, float]) -> Scenario:
    """``base`` with the controller, the doors closed and one episode's cupboard (a copy)."""
    scenario = copy.deepcopy(base)
    scenario.controller, scenario.doors, scenario.door_angles = controller, "closed", None
    station = scenario.station
    station.cupboard_yaw_error = values["station.cupboard_yaw_error"]
    station.cupboard_position_error = [
        values[f"station.cupboard_position_error[{k}]"] for k in range(3)
    ]
    station.hinge_damping = values["station.hinge_damping"]
    station.friction = values["station.friction"]
    scenario.ik.grasp_offset = [values[f"ik.grasp_offset[{k}]"] for k in range(3)]
    return scenario


def plan_bench(
    controllers: list[str],
    *,
    episodes: int,
    seed: int,
    base: Scenario | None = None,
    distribution: BenchDistribution | None = None,
) -> list[PlannedRun]:
    """Every run of a benchmark: each controller over the same ``episodes`` cupboards, in
    (controller, episode) order, each scenario validated.

    Raises:
        ConfigError: Bad counts or random seed, an episode's scenario invalid (naming its values).
    """
    if not isinstance(episodes, int) or isinstance(episodes, bool) or not 1 <= episodes:
        raise ConfigError(f"episodes must be an integer >= 1, got {quote(episodes)}")
    if episodes > MAX_EPISODES:
        raise ConfigError(
            f"episodes must be at most {MAX_EPISODES} per controller, got {episodes} (each "
            "episode is seconds of a core)"
        )
    if not isinstance(seed, int) or isinstance(seed, bool) or not 0 <= seed < 2**63:
        raise ConfigError(f"seed must be an integer in [0, 2^63), got {quote(seed)}")
    if not controllers:
        raise ConfigError("a benchmark needs at least one controller")
    base = validate(copy.deepcopy(base) if base is not None else Scenario())
    distribution = validate_distribution(distribution or BenchDistribution())
    draws = [draw_episode(distribution, seed=seed, episode=i) for i in range(episodes)]
    runs = []
    for controller in controllers:
        for i, values in enumerate(draws):
            scenario = episode_scenario(base, controller, values)
            try:
                validate(scenario)
            except ConfigError as e:
                raise ConfigError(f"episode {i}'s cupboard: {e}") from None
            runs.append(
                PlannedRun(len(runs), scenario_key(scenario), {"episode": i, **values}, scenario)
            )
    return runs


def describe_distribution(distribution: BenchDistribution) -> list[dict[str, str]]:
    """The distribution as rows for the card and bench.json: field, what is drawn, unit."""
    d = distribution
    px, py, pz = d.position_error_mm
    gx, gy, gz = d.grasp_offset_mm
    return [
        {
            "field": "station.cupboard_yaw_error",
            "draw": f"uniform in [-{d.yaw_error_deg:g}, {d.yaw_error_deg:g}] deg",
            "what": "the true cupboard turned about the handle from where the plans believe it",
        },
        {
            "field": "station.cupboard_position_error",
            "draw": f"uniform in +-({px:g}, {py:g}, {pz:g}) mm, per axis of W",
            "what": "the true cupboard moved from where the plans believe it",
        },
        {
            "field": "station.hinge_damping",
            "draw": f"log-uniform in [{d.hinge_damping[0]:g}, {d.hinge_damping[1]:g}] N m s/rad",
            "what": "the hinges' viscous damping",
        },
        {
            "field": "station.friction",
            "draw": f"uniform in [{d.friction[0]:g}, {d.friction[1]:g}]",
            "what": "Coulomb friction of the fingers on the handle",
        },
        {
            "field": "ik.grasp_offset",
            "draw": f"uniform in +-({gx:g}, {gy:g}, {gz:g}) mm, per axis of W",
            "what": "where the grasp IK aims Q off the handle (controllers that grasp through "
            "doorlab.grasp_configuration; not ik, which grasps at its first knot)",
        },
        {"field": "doors", "draw": "closed", "what": "every episode opens the closed door"},
    ]


def distribution_dict(distribution: BenchDistribution) -> dict:
    """The distribution's fields (bench.json)."""
    return dataclasses.asdict(distribution)
