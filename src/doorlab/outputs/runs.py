"""Run one scenario and write its output folder atomically (``doorlab run``).

A run folder holds ``metrics.json``, ``log.npz``, the problem set's plots as PNG and
``replay.html`` (a self-contained 3-D replay). It is assembled in a hidden temporary folder
beside the target and renamed into place at the end
(:func:`doorlab.runtime.folders.staged_output`), so a folder either appears complete or not at
all. An IK or physics failure, a safety stop, is a status in the folder, not an exception; the
exit code of each status is :data:`EXIT_CODES`.
"""

from __future__ import annotations

import concurrent.futures
import concurrent.futures.process
import dataclasses
import multiprocessing
from dataclasses import dataclass
from pathlib import Path

from pydrake.geometry import Meshcat

from doorlab.cell.geometry import true_door_geometry
from doorlab.config import Scenario
from doorlab.episode.metrics import DoorMetrics, Kinematics, compute_metrics
from doorlab.episode.plugins import display_name
from doorlab.errors import IkError, RunStopped, SafetyStop, SimulationError
from doorlab.runtime.folders import staged_output, write_json
from doorlab.runtime.interrupts import (
    end_pool,
    spawning_workers,
    worker_signals,
)

EXIT_CODES = {
    "ok": 0,
    "usage": 2,
    "slipped": 3,
    "speed_limit": 4,
    "diverged": 5,
    "ik_failed": 6,
    "driver_lost": 7,
    "safety_stop": 8,
    "controller_error": 2,
}
"""Exit codes of ``doorlab run`` by status (``usage``: bad input; ``driver_lost``: no status
from the arm's driver, ``doorlab run --hardware``; ``safety_stop``: a command broke a limit of
:mod:`doorlab.cell.safety`; ``controller_error``: a plug-in raised in a tick or sent no valid
command, a broken plug-in as one that does not load is: 2). A signal exits with 128 + its
number (130 for Ctrl-C)."""


@dataclass(frozen=True)
class RunOutcome:
    """What a run produced.

    Attributes:
        status: One of :data:`doorlab.episode.metrics.STATUSES`.
        metrics: The figures (None when the run could not finish: ik_failed, diverged).
        message: Why it failed ("" when it did not).
        out_dir: The folder written.
    """

    status: str
    metrics: DoorMetrics | None
    message: str
    out_dir: Path

    @property
    def exit_code(self) -> int:
        """The CLI exit code of this status."""
        return EXIT_CODES[self.status]


def _warm_plotter() -> None:
    """Plot worker initializer: its signals (doorlab.runtime.interrupts), then import matplotlib and
    the plots while the episode runs."""
    worker_signals()
    import doorlab.outputs.plots  # noqa: F401


def _write_plots(result, scenario: Scenario, out_dir: str) -> None:
    """The run's PNG plots into ``out_dir`` (in the plot worker, or here as a fallback)."""
    from doorlab.outputs import plots

    plots.save_run_plots(result, true_door_geometry(scenario), Path(out_dir))


def _plot_worker() -> concurrent.futures.ProcessPoolExecutor:
    """A process that imports the plotting stack now and draws a run's plots when asked."""
    context = multiprocessing.get_context("spawn")  # pydrake and fork do not mix
    with spawning_workers():
        worker = concurrent.futures.ProcessPoolExecutor(
            max_workers=1, mp_context=context, initializer=_warm_plotter
        )
        worker.submit(int)  # start the process now (the pool spawns it on first use)
    return worker


def _stop_plot_worker(worker: concurrent.futures.ProcessPoolExecutor, *, at_once: bool) -> None:
    """Ends the plot worker; ``at_once``: without waiting for its drawing (and before the
    staging folder it draws into is removed)."""
    end_pool(worker, at_once=at_once)


def run_to_folder(
    scenario: Scenario,
    out_dir: Path,
    *,
    force: bool = False,
    replay: bool = True,
    plots: bool = True,
    meshcat: Meshcat | None = None,
    realtime_rate: float = 0.0,
    parallel: bool = False,
) -> RunOutcome:
    """Runs ``scenario`` and writes its folder; IK and physics failures become a status.

    Args:
        scenario: The run, validated (:func:`doorlab.config.validate`; ``doorlab run`` checks
            the scenario it reads before anything is written, and is the only check).
        out_dir: The folder to create.
        force: Replace ``out_dir`` if it exists.
        replay: Write ``replay.html``. plots: Write the PNG plots.
        meshcat: Also draw the run live in this Meshcat.
        realtime_rate: 0 runs as fast as possible; 1 at wall-clock speed.
        parallel: Draw the plots in a second process (started at once, so its imports
            overlap the episode) while this one writes the replay: faster on an idle
            multi-core machine (``doorlab run``); ``doorlab report`` already runs whole
            experiments in parallel and leaves it off.

    Raises:
        OutputError: ``out_dir`` cannot be written.
    """
    # Plotting and replay are imported when used: they pull in matplotlib and Meshcat, which
    # the pure simulation API does not need.
    out_dir = Path(out_dir)
    with staged_output(out_dir, force=force) as staging:
        worker = _plot_worker() if plots and parallel else None
        try:
            outcome = _run_into(
                scenario,
                staging,
                worker,
                replay=replay,
                plots=plots,
                meshcat=meshcat,
                realtime_rate=realtime_rate,
            )
        except BaseException:
            if worker is not None:  # before the folder it draws into goes
                _stop_plot_worker(worker, at_once=True)
            raise
        if worker is not None:
            _stop_plot_worker(worker, at_once=False)
    return dataclasses.replace(outcome, out_dir=out_dir)


def _run_into(
    scenario: Scenario,
    staging: Path,
    worker: concurrent.futures.ProcessPoolExecutor | None,
    *,
    replay: bool,
    plots: bool,
    meshcat: Meshcat | None,
    realtime_rate: float,
) -> RunOutcome:
    """Runs the episode and writes its files into ``staging`` (see :func:`run_to_folder`)."""
    from doorlab.episode.controllers import simulate_controller

    base = {"controller": display_name(scenario.controller), "doors": scenario.doors}
    try:
        result, _ = simulate_controller(scenario, meshcat=meshcat, realtime_rate=realtime_rate)
    except (IkError, SimulationError, RunStopped) as e:
        status = "ik_failed" if isinstance(e, IkError) else getattr(e, "status", "diverged")
        stop = {"violation": e.violation.to_dict()} if isinstance(e, SafetyStop) else {}
        if getattr(e, "result", None) is not None:  # the logs up to a stop
            e.result.save(staging / "log.npz")
        write_json(staging / "metrics.json", {**base, "status": status, "error": str(e), **stop})
        return RunOutcome(status, None, str(e), staging)
    plotted = None
    if worker is not None:
        try:
            plotted = worker.submit(_write_plots, result, scenario, str(staging))
        except concurrent.futures.process.BrokenProcessPool:
            plotted = None  # the worker could not start: plot here instead
    geometry = true_door_geometry(scenario)
    kinematics = Kinematics()
    metrics = compute_metrics(result, scenario, geometry, kinematics=kinematics)
    result.save(staging / "log.npz")
    write_json(staging / "metrics.json", metrics.to_dict())
    (staging / "scenario.yaml").write_text(result.scenario_yaml)
    if replay:
        from doorlab.outputs.replay import save_replay

        save_replay(result, staging / "replay.html", scenario=scenario)
    if plotted is not None:
        try:
            plotted.result()  # the folder is complete only with the plots
        except concurrent.futures.process.BrokenProcessPool:
            plotted = None
    if plots and plotted is None:
        _write_plots(result, scenario, str(staging))
    return RunOutcome(metrics.status, metrics, status_message(metrics), staging)


def status_message(metrics: DoorMetrics) -> str:
    """Why a finished run is not ok ("" when it is)."""
    if metrics.status == "slipped":
        return (
            f"the handle slipped out of the gripper at t = {metrics.slip_time_s:.2f} s "
            f"(Q ends {1e3 * metrics.handle_distance_m:.0f} mm from it)"
        )
    if metrics.status == "speed_limit":
        return "a joint exceeded its data-sheet speed limit"
    return ""
