"""The report's experiment set as data: :data:`EXPERIMENTS` (the three controllers with the
doors open and closed, IK with 2, 5 and 10 knots), the robustness grid
(:func:`make_robustness_cases`) and :class:`RunRecord`, what a run left.

The page (:mod:`doorlab.report.page`) reads these; :mod:`doorlab.report.runner` runs them.
This module builds no page and runs nothing, so the page's modules may import it.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from doorlab.config import Scenario

IK_KNOTS = (2, 5, 10)
"""Knot counts of the problem set's task 1 question 1."""


def make_experiments(base: Scenario | None = None) -> tuple[tuple[str, Scenario], ...]:
    """The problem set's experiment set, each a copy of ``base`` with its controller and doors.

    ``door_angles`` is reset to None in every experiment so that ``doors`` decides the initial
    hinge angles; every other setting of ``base`` (physics, timeline, gains) is kept.

    Args:
        base: The scenario the experiments vary (default: ``Scenario()``).

    Returns:
        (name, scenario) pairs: ik_2_open, ik_5_open, ik_10_open, ik_10_closed, velocity_open,
        velocity_closed, impedance_open, impedance_closed.
    """
    base = base if base is not None else Scenario()

    def variant(controller: str, doors: str, knots: int | None = None) -> Scenario:
        scenario = copy.deepcopy(base)
        scenario.controller = controller
        scenario.doors = doors
        scenario.door_angles = None
        if knots is not None:
            scenario.ik.knots = knots
        return scenario

    return (
        *((f"ik_{k}_open", variant("ik", "open", k)) for k in IK_KNOTS),
        ("ik_10_closed", variant("ik", "closed", 10)),
        ("velocity_open", variant("velocity", "open")),
        ("velocity_closed", variant("velocity", "closed")),
        ("impedance_open", variant("impedance", "open")),
        ("impedance_closed", variant("impedance", "closed")),
    )


EXPERIMENTS: tuple[tuple[str, Scenario], ...] = make_experiments()
"""The problem set's eight runs on the default scenario (see :func:`make_experiments`)."""


@dataclass(frozen=True)
class RobustnessCase:
    """One cell of the report's robustness grid: a controller, doors closed, one yaw error.

    Attributes:
        run: Name of the experiment (run folder) holding it: one of the problem set's
            experiments when its scenario is the very same case, else
            ``robust_<controller>_yaw_<m|p><deg>``.
        controller: Registry name.
        yaw_error_rad: ``station.cupboard_yaw_error`` [rad].
    """

    run: str
    controller: str
    yaw_error_rad: float


def make_robustness_cases(
    base: Scenario | None = None,
    experiments: Sequence[tuple[str, Scenario]] = (),
    yaw_errors_deg: Sequence[float] | None = None,
) -> tuple[tuple[RobustnessCase, ...], tuple[tuple[str, Scenario], ...]]:
    """The robustness grid: every controller of the registry on every yaw error, doors closed.

    Args:
        base: The scenario the cases vary (:func:`doorlab.robustness.case_scenario`).
        experiments: Runs already in the report: a case whose scenario equals one of them
            reuses that run instead of running it twice.
        yaw_errors_deg: The yaw errors [deg] (default: the acceptance grid, -10 to +10).

    Returns:
        (cases in (controller, yaw) order, the (name, scenario) experiments still to run).
    """
    import math

    from doorlab.controllers import REGISTRY
    from doorlab.robustness import ACCEPTANCE_YAW_ERRORS_DEG, case_scenario

    base = base if base is not None else Scenario()
    yaws = ACCEPTANCE_YAW_ERRORS_DEG if yaw_errors_deg is None else tuple(yaw_errors_deg)
    cases, new = [], []
    for controller in REGISTRY:
        for yaw_deg in yaws:
            scenario = case_scenario(base, controller, math.radians(yaw_deg))
            same = [name for name, existing in experiments if existing == scenario]
            if same:
                name = same[0]
            else:
                sign = "m" if yaw_deg < 0 else "p"
                name = f"robust_{controller}_yaw_{sign}{abs(yaw_deg):g}".replace(".", "_")
                new.append((name, scenario))
            cases.append(RobustnessCase(name, controller, math.radians(yaw_deg)))
    return tuple(cases), tuple(new)


@dataclass(frozen=True)
class RunRecord:
    """One experiment's run folder and how the run went.

    Attributes:
        name: Experiment name (the folder's name), e.g. ``ik_10_open``.
        run_dir: The run folder (``metrics.json``, ``log.npz``, plots, ``replay.html``).
        status: Run status (:data:`doorlab.metrics.STATUSES`, or ``error`` when the worker
            raised); the page re-reads it from ``metrics.json``.
        message: Why the run failed ("" when it did not).
        elapsed_s: Wall-clock time of the whole run, plots and replay included [s].
    """

    name: str
    run_dir: Path
    status: str = "unknown"
    message: str = ""
    elapsed_s: float = float("nan")
