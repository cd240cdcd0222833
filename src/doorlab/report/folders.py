"""Reading the run folders of a report: metrics, logs and trackings, and each run's label and
line style on the page's figures. Reading never simulates.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from doorlab.cell.geometry import DoorGeometry, true_door_geometry
from doorlab.config import Scenario
from doorlab.episode.metrics import Kinematics, Tracking, compute_tracking
from doorlab.episode.result import EpisodeResult
from doorlab.report.experiments import EXPERIMENTS, RunRecord


@dataclass
class LoadedRun:
    """A run folder, loaded: metrics, logs, trackings (None where the run has no logs)."""

    record: RunRecord
    metrics: dict
    status: str
    error: str
    label: str
    result: EpisodeResult | None = None
    scenario: Scenario | None = None
    geometry: DoorGeometry | None = None
    tracking: Tracking | None = None
    tracking_cmd: Tracking | None = None

    @property
    def name(self) -> str:
        return self.record.name

    @property
    def has_logs(self) -> bool:
        return self.tracking is not None


def _label(name: str, metrics: dict) -> str:
    """A plot label like "IK 10 knots, open" from the metrics (falls back to the name)."""
    controller = metrics.get("controller")
    doors = metrics.get("doors")
    if not controller or not doors:
        return name
    title = {"ik": "IK", "velocity": "velocity", "impedance": "impedance"}.get(
        controller, str(controller)
    )
    knots = metrics.get("knots")
    if controller == "ik" and knots:
        title += f" {knots} knots"
    return f"{title}, {doors}"


CONTROLLER_COLORS = {
    ("ik", 2): "tab:purple",
    ("ik", 5): "tab:brown",
    ("ik", 10): "tab:green",
    ("velocity", None): "tab:blue",
    ("impedance", None): "tab:red",
    ("adaptive", None): "tab:gray",
    ("diffik", None): "tab:pink",
    ("osc", None): "tab:orange",
}
"""Line colour of each controller (IK by knot count) on every figure of the page."""

_EXTRA_COLORS = ("tab:olive", "tab:cyan", "black")


def line_style(run: LoadedRun, index: int) -> dict:
    """The same colour for a controller on every figure; dashed when the doors are closed."""
    controller = run.metrics.get("controller")
    knots = run.metrics.get("knots") if controller == "ik" else None
    color = CONTROLLER_COLORS.get((controller, knots))
    if color is None:
        color = _EXTRA_COLORS[index % len(_EXTRA_COLORS)]
    return {"color": color, "ls": "--" if run.metrics.get("doors") == "closed" else "-"}


def load_run(record: RunRecord, kinematics: Kinematics) -> LoadedRun:
    from pydrake.common.yaml import yaml_load_typed

    folder = Path(record.run_dir)
    metrics: dict = {}
    try:
        metrics = json.loads((folder / "metrics.json").read_text())
    except (OSError, ValueError) as e:
        status = record.status if record.status not in ("ok", "unknown") else "missing"
        message = record.message or f"cannot read {folder / 'metrics.json'}: {e}"
        return LoadedRun(record, {}, status, message, record.name)
    status = str(metrics.get("status", "unknown"))
    error = str(metrics.get("error") or record.message or "")
    if not error and status == "slipped" and metrics.get("slip_time_s") is not None:
        error = f"the handle slipped out of the gripper at t = {metrics['slip_time_s']:.2f} s"
    elif not error and status == "speed_limit":
        error = "a joint exceeded its data-sheet speed limit"
    run = LoadedRun(record, metrics, status, error, _label(record.name, metrics))
    log = folder / "log.npz"
    if not log.is_file():
        return run
    try:
        result = EpisodeResult.load(log)
        yaml_path = folder / "scenario.yaml"
        text = yaml_path.read_text() if yaml_path.is_file() else result.scenario_yaml
        scenario = yaml_load_typed(schema=Scenario, data=text) if text else Scenario()
        geometry = true_door_geometry(scenario)
        run.result, run.scenario, run.geometry = result, scenario, geometry
        run.tracking = compute_tracking(result, geometry, kinematics=kinematics)
        run.tracking_cmd = compute_tracking(
            result, geometry, source="commanded", kinematics=kinematics
        )
    except (OSError, ValueError, KeyError, RuntimeError) as e:
        note = f"its log could not be read ({type(e).__name__}: {e})"
        run.error = f"{run.error}; {note}" if run.error else note
        run.result = run.tracking = run.tracking_cmd = None
    return run


def discover_runs(report_dir: Path) -> list[RunRecord]:
    """Run records of an existing report folder (``runs/<name>/``), in experiment order.

    Folders named like :data:`EXPERIMENTS` come first in that order, then any others by name;
    the robustness grid's own runs (``robust_*``) are not experiments and are left out.
    """
    runs_dir = Path(report_dir) / "runs"
    folders = {
        p.name: p
        for p in runs_dir.iterdir()
        if p.is_dir() and not p.name.startswith((".", "robust_"))
    }
    order = [name for name, _ in EXPERIMENTS if name in folders]
    order += sorted(set(folders) - set(order))
    return [RunRecord(name, folders[name]) for name in order]
