"""The typed distribution of a benchmark, loaded with ``yaml_load_typed`` like the scenario.

No ``from __future__ import annotations`` here: Drake's YAML loader reads the field types at
run time, as it does for :class:`doorlab.config.Scenario`.
"""

from dataclasses import dataclass, field


@dataclass
class BenchDistribution:
    """The cupboards ``doorlab bench`` draws (:mod:`doorlab.bench.distribution`): each field
    independently per episode, uniform (the hinge's damping log-uniform); a half-width or a
    range of zero width holds the field at that value."""

    # [deg] station.cupboard_yaw_error ~ U(-x, x): the true cupboard turned about the handle
    yaw_error_deg: float = 5.0
    # [mm] half-widths per axis of W (x, y, z): station.cupboard_position_error ~ U(-x, x)
    position_error_mm: list[float] = field(default_factory=lambda: [5.0, 5.0, 2.0])
    # [N m s/rad] [low, high]: station.hinge_damping ~ log-uniform (the default model: 1.0)
    hinge_damping: list[float] = field(default_factory=lambda: [0.5, 4.0])
    # [-] [low, high]: station.friction (fingers on the handle) ~ uniform (default model: 1.0)
    friction: list[float] = field(default_factory=lambda: [0.6, 1.0])
    # [mm] half-widths per axis of W: ik.grasp_offset ~ U(-x, x) (the original's feasibility
    # IK grasped up to 0.5 mm off the handle per axis)
    grasp_offset_mm: list[float] = field(default_factory=lambda: [0.5, 0.5, 0.5])
