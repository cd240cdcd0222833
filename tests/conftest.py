"""Shared fixtures: full episodes are expensive (~3-5 s each), so each is run once per session."""

from __future__ import annotations

import os
from functools import cache

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")


@cache
def _run(controller: str, doors: str, knots: int | None, inner_loop: str = "stiffness"):
    from doorlab.config import Scenario
    from doorlab.controllers import run_controller
    from doorlab.geometry import default_door_geometry
    from doorlab.metrics import compute_metrics

    scenario = Scenario(controller=controller, doors=doors)
    scenario.station.inner_loop.kind = inner_loop
    if knots is not None:
        scenario.ik.knots = knots
    result, arc = run_controller(scenario)
    metrics = compute_metrics(result, scenario, default_door_geometry())
    return scenario, result, arc, metrics


@pytest.fixture(scope="session")
def episode():
    """episode(controller, doors, knots=None, inner_loop="stiffness") -> (scenario, result, arc,
    metrics), memoized."""

    def get(controller: str, doors: str, knots: int | None = None, inner_loop: str = "stiffness"):
        return _run(controller, doors, knots, inner_loop)

    return get
