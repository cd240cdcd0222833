"""A self-contained HTML 3-D replay of an episode, drawn from its LOGGED plant positions.

No simulation runs here: a bare plant holding the same cell (:func:`doorlab.cell.station.add_cell`)
is posed at the logged ``plant_positions`` once per animation frame, Drake's
``MeshcatVisualizer`` records the poses into a Meshcat animation, and Meshcat's
``StaticHtml()`` writes the scene, the animation and the viewer's JavaScript into one HTML file
that opens offline (use the viewer's "Animation" controls to play, pause and scrub).

Meshcat starts a local websocket server (ports 7000-7099) per instance. To avoid leaking
ports when many replays are written in one process, one Meshcat per thread is created lazily
and reused: its scene and recording are deleted before and after each replay.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path

import numpy as np
from pydrake.geometry import (
    Meshcat,
    MeshcatParams,
    MeshcatVisualizer,
    MeshcatVisualizerParams,
    Role,
)
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.systems.framework import DiagramBuilder

from doorlab.cell.station import add_cell
from doorlab.config import Scenario
from doorlab.episode.result import EpisodeResult
from doorlab.errors import ConfigError

_log = logging.getLogger(__name__)

CAMERA_POSITION_W = np.array([-0.45, -0.8, 1.15])
"""Initial camera position of the replay [m]: behind and to the right of the robot, above it."""
CAMERA_TARGET_W = np.array([0.7, 0.12, 0.42])
"""Point the initial camera looks at [m]: the left door, between its hinge and handle."""

_local = threading.local()


def _meshcat() -> Meshcat:
    """This thread's reusable Meshcat (Meshcat may only be used by the thread that made it)."""
    meshcat = getattr(_local, "meshcat", None)
    if meshcat is None:
        drake_logger = logging.getLogger("drake")
        level = drake_logger.level
        drake_logger.setLevel(logging.WARNING)  # silence "Meshcat listening for connections"
        try:
            meshcat = Meshcat(MeshcatParams(show_stats_plot=False))
        finally:
            drake_logger.setLevel(level)
        _local.meshcat = meshcat
    return meshcat


def replay_frame_times(result: EpisodeResult, fps: float) -> np.ndarray:
    """Times of the replay's animation frames, k / fps for k = 0.. up to the last log [s]."""
    if not (np.isfinite(fps) and fps > 0):
        raise ConfigError(f"fps must be a finite number > 0, got {fps!r}")
    if len(result.t) == 0:
        return np.zeros(0)
    n = int(np.floor(float(result.t[-1]) * fps + 1e-9)) + 1
    return np.arange(n) / fps


def replay_rows(result: EpisodeResult, frame_times: np.ndarray) -> np.ndarray:
    """Index of the logged row shown at each frame: the last sample at or before the frame."""
    rows = np.searchsorted(result.t, np.asarray(frame_times) + 1e-9, side="right") - 1
    return np.clip(rows, 0, len(result.t) - 1)


def save_replay(
    result: EpisodeResult,
    path: Path,
    *,
    scenario: Scenario,
    fps: float = 30.0,
) -> Path:
    """Writes a self-contained HTML 3-D replay of ``result`` to ``path``.

    Args:
        result: The episode's logs (``plant_positions`` of the whole simulation plant).
        path: The HTML file to write.
        scenario: The scenario that produced the logs (for the cell's collision geometry).
        fps: Animation frames per second [1/s]; the logged rows are subsampled to it.

    Returns:
        ``path``.

    Raises:
        ConfigError: ``fps`` is not positive, or the logs do not match the cell's plant.
    """
    path = Path(path)
    frame_times = replay_frame_times(result, fps)
    meshcat = _meshcat()
    meshcat.Delete()
    meshcat.DeleteRecording()
    try:
        builder = DiagramBuilder()
        plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
        add_cell(plant, arm_collision=scenario.station.arm_collision)
        plant.Finalize()
        positions = np.asarray(result.plant_positions)
        if positions.ndim != 2 or positions.shape[1] != plant.num_positions():
            raise ConfigError(
                f"plant_positions has shape {positions.shape}; the cell's plant has "
                f"{plant.num_positions()} positions"
            )
        params = MeshcatVisualizerParams()
        params.role = Role.kIllustration
        params.publish_period = 1.0 / fps  # the recording's frames per second
        params.delete_on_initialization_event = False
        visualizer = MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, params)
        diagram = builder.Build()
        context = diagram.CreateDefaultContext()
        plant_context = plant.GetMyMutableContextFromRoot(context)
        visualizer_context = visualizer.GetMyContextFromRoot(context)

        visualizer.StartRecording(set_transforms_while_recording=False)
        for t, row in zip(frame_times, replay_rows(result, frame_times), strict=True):
            context.SetTime(float(t))
            plant.SetPositions(plant_context, positions[row])
            visualizer.ForcedPublish(visualizer_context)
        visualizer.StopRecording()
        visualizer.PublishRecording()
        meshcat.SetCameraPose(CAMERA_POSITION_W, CAMERA_TARGET_W)
        html = meshcat.StaticHtml()
        path.write_text(html, encoding="utf-8")
        visualizer.DeleteRecording()
    finally:
        meshcat.DeleteRecording()
        meshcat.Delete()
    _log.info(
        "replay %s: %d frames at %g fps, %.1f MB",
        path,
        len(frame_times),
        fps,
        path.stat().st_size / 1e6,
    )
    return path
