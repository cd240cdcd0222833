"""Shared, session-cached real runs for the plots, replay and report tests.

Each helper simulates at most once per test session (results are cached at module level, so
several test modules importing them share the runs). Runs use a SHORT timeline to stay fast.
Not a conftest: import the helpers explicitly.
"""

from __future__ import annotations

import atexit
import copy
import functools
import shutil
import tempfile
from pathlib import Path

from doorlab.config import Scenario
from doorlab.episode.result import EpisodeResult

SHORT_RUNS = ("ik_2_open", "velocity_open", "velocity_closed")
"""Experiments run into folders for the report tests (replay only for the last one)."""


def short_scenario(
    controller: str = "velocity", doors: str = "closed", knots: int = 10
) -> Scenario:
    """The default scenario with a short timeline (about 10 s simulated instead of 24 s)."""
    scenario = Scenario(controller=controller, doors=doors)
    scenario.ik.knots = knots
    timeline = scenario.timeline
    timeline.arc_duration = 2.0
    timeline.approach_duration = 2.0
    timeline.hold_duration = 0.5
    timeline.extra_time = 0.5
    return scenario


def short_experiment(name: str) -> tuple[str, Scenario]:
    """(name, short scenario) for an experiment name like ``ik_2_open`` or ``velocity_closed``."""
    parts = name.split("_")
    if parts[0] == "ik":
        return name, short_scenario("ik", parts[2], int(parts[1]))
    return name, short_scenario(parts[0], parts[1])


@functools.cache
def _root() -> Path:
    """A temporary folder for the session's runs, removed when the process exits."""
    root = Path(tempfile.mkdtemp(prefix="doorlab_report_tests_"))
    atexit.register(shutil.rmtree, root, ignore_errors=True)
    return root


@functools.cache
def short_result() -> tuple[EpisodeResult, Scenario]:
    """One real short episode (velocity plan, doors closed) and its scenario."""
    from doorlab.episode.controllers import run_controller

    scenario = short_scenario()
    result, _ = run_controller(scenario)
    return result, copy.deepcopy(scenario)


@functools.cache
def short_run_folders() -> dict[str, Path]:
    """Run folders of :data:`SHORT_RUNS` written by ``run_to_folder`` (name -> folder)."""
    from doorlab.outputs.runs import run_to_folder

    runs_dir = _root() / "report" / "runs"
    runs_dir.mkdir(parents=True)
    folders = {}
    for name in SHORT_RUNS:
        _, scenario = short_experiment(name)
        run_to_folder(scenario, runs_dir / name, replay=name == SHORT_RUNS[-1])
        folders[name] = runs_dir / name
    return folders


FAILED_RUN = "ik_5_open"
FAILED_ERROR = "IK found no solution at knot 3 (residual 0.012 m)"


@functools.cache
def short_report() -> Path:
    """A report folder: the short runs plus a hand-written ``ik_failed`` run, page built.

    Returns:
        The report folder (``index.html``, ``summary.json``, ``runs/``).
    """
    import json

    from doorlab.report import RunRecord, build_page

    folders = short_run_folders()
    report_dir = next(iter(folders.values())).parent.parent
    failed = report_dir / "runs" / FAILED_RUN
    failed.mkdir()
    (failed / "metrics.json").write_text(
        json.dumps(
            {"controller": "ik", "doors": "open", "status": "ik_failed", "error": FAILED_ERROR}
        )
    )
    records = [RunRecord(name, folder) for name, folder in folders.items()]
    records.insert(1, RunRecord(FAILED_RUN, failed))
    build_page(records, report_dir, total_wall_time_s=12.5, jobs=1)
    return report_dir


@functools.cache
def single_run_report() -> Path:
    """A report page built from the one short episode of :func:`short_result` (no re-run).

    The run folder is written by hand (log, metrics, scenario) the way ``run_to_folder``
    writes it, so this costs one simulation shared with the plot and replay tests.
    """
    from doorlab.cell.geometry import default_door_geometry
    from doorlab.episode.metrics import compute_metrics
    from doorlab.report import RunRecord, build_page
    from doorlab.runtime.folders import write_json

    result, scenario = short_result()
    report_dir = _root() / "single"
    folder = report_dir / "runs" / "velocity_closed"
    folder.mkdir(parents=True)
    geometry = default_door_geometry(scenario.arc.angle_end_deg)
    result.save(folder / "log.npz")
    write_json(folder / "metrics.json", compute_metrics(result, scenario, geometry).to_dict())
    (folder / "scenario.yaml").write_text(result.scenario_yaml)
    build_page([RunRecord("velocity_closed", folder)], report_dir, total_wall_time_s=1.0, jobs=1)
    return report_dir


ROBUST_YAW_DEG = 5.0
"""Yaw error of the fixture's short adaptive robustness run [deg]."""


@functools.cache
def robustness_report() -> tuple[Path, list]:
    """A report page with a robustness section built from three small cases, no re-run of
    the shared short runs: ``velocity_closed`` reused at yaw 0, one short adaptive run at
    :data:`ROBUST_YAW_DEG` and a hand-written ``ik_failed`` run at -10 deg.

    Returns:
        (report folder, [(RobustnessCase, RunRecord)] of the section).
    """
    import json
    import math

    from doorlab.outputs.runs import run_to_folder
    from doorlab.report import RobustnessCase, RunRecord, build_page
    from doorlab.studies.robustness import case_scenario

    folders = short_run_folders()
    report_dir = _root() / "robust"
    runs_dir = report_dir / "runs"
    runs_dir.mkdir(parents=True)
    yaw = math.radians(ROBUST_YAW_DEG)
    adaptive = runs_dir / "robust_adaptive_yaw_p5"
    run_to_folder(
        case_scenario(short_scenario("adaptive"), "adaptive", yaw), adaptive, replay=False
    )
    failed = runs_dir / "robust_ik_yaw_m10"
    failed.mkdir()
    (failed / "metrics.json").write_text(
        json.dumps(
            {"controller": "ik", "doors": "closed", "status": "ik_failed", "error": FAILED_ERROR}
        )
    )
    grid = [
        (
            RobustnessCase("robust_ik_yaw_m10", "ik", math.radians(-10.0)),
            RunRecord("robust_ik_yaw_m10", failed),
        ),
        (
            RobustnessCase("velocity_closed", "velocity", 0.0),
            RunRecord("velocity_closed", folders["velocity_closed"]),
        ),
        (
            RobustnessCase("robust_adaptive_yaw_p5", "adaptive", yaw),
            RunRecord("robust_adaptive_yaw_p5", adaptive),
        ),
    ]
    build_page(
        [RunRecord("velocity_closed", folders["velocity_closed"])],
        report_dir,
        total_wall_time_s=3.0,
        jobs=1,
        robustness=grid,
    )
    return report_dir, grid
