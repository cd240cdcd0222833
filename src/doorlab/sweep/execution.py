"""Running a sweep: every planned run through one executor, a row per run, written as it lands.

A failing run (slipped, ik_failed, diverged, an exception in the worker, a worker that died) is
a row with its status and error, never the end of the sweep. The table is rewritten atomically
after every finished run, so Ctrl-C (or a killed process) leaves a consistent table of the runs
that finished; ``resume`` skips the runs already in it (by their scenario's key) and re-runs
those that ended with ``error`` (an exception may be transient: a lost worker).
"""

from __future__ import annotations

import concurrent.futures
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from doorlab.config import Scenario
from doorlab.errors import ConfigError, IkError, OutputError, RunStopped, SimulationError
from doorlab.runtime.interrupts import completed
from doorlab.sweep.results import (
    RESULTS_CSV,
    RESULTS_PARQUET,
    make_table,
    read_table,
    write_table,
)
from doorlab.sweep.spec import PlannedRun, SweepSpec, load_spec, plan_runs

PAGE_FILES = ("index.html", "figures", "sweep.json")
TABLE_WRITE_SHARE = 0.1
"""Most of the sweep's time spent rewriting the table: after a write that took d seconds, the
next waits until 10 d have passed (the last one is always written). Small tables are written
after every run; a table of many thousand rows finished at a high rate is not rewritten for
every row. The first write does not count: it imports the Parquet writer (half a second on
a loaded machine, which kept the next rows off the disk for 5 s)."""


_local = threading.local()


def _kinematics():
    """This thread's forward kinematics (a Dask worker may run runs in several threads; a
    Kinematics holds one Context, so threads must not share it)."""
    from doorlab.episode.metrics import Kinematics

    if not hasattr(_local, "kinematics"):
        _local.kinematics = Kinematics()
    return _local.kinematics


def run_one(scenario: Scenario, measure: Callable | None = None) -> dict:
    """Worker: runs one scenario and returns its row (status, error, metrics); never raises.

    Args:
        scenario: The run.
        measure: ``measure(result, scenario, metrics) -> dict``: more columns from the
            episode's logs, for a run that produced metrics (a benchmark's, e.g.
            :func:`doorlab.bench.measures.episode_columns`); module-level, so that it pickles.

    Returns:
        ``status``, ``error``, ``run_wall_time_s`` [s] and every key of ``metrics.json`` the
        run produced (none for ik_failed, diverged, safety_stop, controller_error and error),
        and ``measure``'s columns.
    """
    from doorlab.cell.geometry import true_door_geometry
    from doorlab.episode.controllers import run_controller
    from doorlab.episode.metrics import compute_metrics
    from doorlab.episode.plugins import display_name
    from doorlab.outputs.runs import status_message

    start = time.perf_counter()
    base = {"controller": display_name(scenario.controller), "doors": scenario.doors}
    try:
        result, _ = run_controller(scenario)
        metrics = compute_metrics(
            result, scenario, true_door_geometry(scenario), kinematics=_kinematics()
        )
        row = {**metrics.to_dict(), "error": status_message(metrics)}
        if measure is not None:
            row.update(measure(result, scenario, metrics))
    except (IkError, SimulationError, RunStopped) as e:  # results of the run, not errors
        status = "ik_failed" if isinstance(e, IkError) else getattr(e, "status", "diverged")
        row = {**base, "status": status, "error": str(e)}
        partial = getattr(e, "result", None)  # a stopped run's logs up to its stop
        if measure is not None and partial is not None:
            try:
                row.update(measure(partial, scenario, None))
            except Exception as m:  # the row keeps its status, and says why it has no more
                row["error"] += f" (its logs could not be measured: {type(m).__name__}: {m})"
    except Exception as e:  # a run's bug must not end the sweep
        row = {**base, "status": "error", "error": f"{type(e).__name__}: {e}"}
    row["run_wall_time_s"] = time.perf_counter() - start
    return row


SWEEP_FILES = (RESULTS_PARQUET, RESULTS_CSV, *PAGE_FILES)
"""What a sweep writes into its folder (and a resumed sweep rewrites)."""


def _check_dir(
    out_dir: Path, *, resume: bool, force: bool, files: Sequence[str] = SWEEP_FILES
) -> pd.DataFrame | None:
    """Checks ``out_dir`` may be written (writing nothing); returns the table to resume from.

    A new sweep needs a missing or empty folder, or with ``force`` one holding nothing but
    an earlier sweep's files, unchanged (:func:`doorlab.runtime.folders.check_replaceable`); a
    resumed one rewrites only its own files, so those must be doorlab's and unchanged.
    """
    from doorlab.runtime.folders import check_replaceable, foreign_file

    if out_dir.exists() and not out_dir.is_dir():
        raise OutputError(f"--out {str(out_dir)!r} is a file, not a folder")
    existing = out_dir.is_dir() and any(out_dir.iterdir())
    if existing and resume:
        found = foreign_file(out_dir, only=files)
        if found is not None:
            raise OutputError(
                f"--out {str(out_dir)!r} holds {found[0]!r}, {found[1]}, and --resume would "
                "overwrite it; move it away or choose another --out"
            )
        try:
            return read_table(out_dir)
        except (OSError, ValueError) as e:
            raise OutputError(f"cannot resume from {out_dir / RESULTS_PARQUET}: {e}") from None
    if existing and not force:
        raise OutputError(
            f"--out {str(out_dir)!r} already exists; pass --resume to continue its runs or "
            "--force to start over"
        )
    check_replaceable(out_dir, force=force)
    return None


def _make_dir(out_dir: Path, *, resume: bool, force: bool) -> None:
    """Creates ``out_dir`` (empty, with a manifest: it replaces an earlier sweep's folder), or
    with ``resume`` keeps it."""
    from doorlab.runtime.folders import staged_output

    if resume and out_dir.is_dir():
        return
    with staged_output(out_dir, force=force):
        pass


def _row(run: PlannedRun, outcome: dict) -> dict:
    from doorlab.episode.plugins import display_name

    return {
        **outcome,
        "run": run.index,
        "key": run.key,
        "controller": display_name(run.scenario.controller),
        "doors": run.scenario.doors,
        **run.values,
    }


def run_sweep(
    spec: SweepSpec | str | Path,
    out_dir: str | Path | None = None,
    *,
    jobs: int = 1,
    scheduler: str | None = None,
    scheduler_timeout_s: float | None = None,
    resume: bool = False,
    force: bool = False,
    progress: bool = False,
    page: bool = True,
) -> pd.DataFrame:
    """Runs every run of ``spec`` and returns the results table (one row per run).

    Args:
        spec: The sweep, or the path of its SPEC file (see :func:`doorlab.sweep.load_spec`).
        out_dir: Folder for ``results.parquet``, ``results.csv`` and ``index.html`` (None:
            write nothing, return the table).
        jobs: Local worker processes (ignored with ``scheduler``).
        scheduler: Dask scheduler address ``tcp://HOST:PORT`` (None: local processes).
        scheduler_timeout_s: Each step of connecting to it [s] (default
            :data:`doorlab.runtime.executor.CONNECT_TIMEOUT_S`).
        resume: Keep the rows of ``out_dir``'s table and run only the missing runs.
        force: Start over in an existing ``out_dir``.
        progress: Show a progress bar (counts, failures, ETA) on stderr.
        page: Write ``index.html`` at the end.

    Returns:
        The table, in sweep order (see :mod:`doorlab.sweep.results`).

    Raises:
        ConfigError: Bad ``jobs``/``scheduler``. OutputError: ``out_dir`` exists (without
            ``resume`` or ``force``) or cannot be written.
        KeyboardInterrupt: After writing the table of the runs finished so far.
    """
    if not isinstance(spec, SweepSpec):
        spec = load_spec(spec)
    runs = plan_runs(spec)
    executed = execute_runs(
        runs,
        out_dir,
        axes=[axis.field for axis in spec.axes],
        jobs=jobs,
        scheduler=scheduler,
        scheduler_timeout_s=scheduler_timeout_s,
        resume=resume,
        force=force,
        progress=progress,
    )
    if executed.out is not None and page:
        from doorlab.sweep.page import build_sweep_page

        build_sweep_page(
            executed.frame,
            spec,
            executed.out,
            wall_time_s=executed.wall_time_s,
            executor=executed.executor,
            total_runs=len(runs),
        )
    return executed.frame


@dataclass(frozen=True)
class ExecutedRuns:
    """What :func:`execute_runs` did.

    Attributes:
        frame: The table of every run (resumed rows included), in run order.
        out: The folder written (None: nothing written).
        executor: What ran them (e.g. "2 local worker processes"; "none" if every run was
            in the table already).
        wall_time_s: From the start to the last row [s].
        workers: Worker processes or threads that ran them (0 if none ran).
        ran: How many runs ran now (the others came from the table).
    """

    frame: pd.DataFrame
    out: Path | None
    executor: str
    wall_time_s: float
    workers: int
    ran: int


def execute_runs(
    runs: Sequence[PlannedRun],
    out_dir: str | Path | None,
    *,
    axes: Sequence[str],
    worker: Callable[[Scenario], dict] = run_one,
    jobs: int = 1,
    scheduler: str | None = None,
    scheduler_timeout_s: float | None = None,
    resume: bool = False,
    force: bool = False,
    progress: bool = False,
    label: str = "sweep",
    files: Sequence[str] = SWEEP_FILES,
    extra_columns: dict[str, str] | None = None,
) -> ExecutedRuns:
    """Runs planned runs through one executor into a results table: the machinery of
    ``doorlab sweep`` and ``doorlab bench`` (the folder's rules, the table written as rows
    land, ``resume``, the progress bar, Ctrl-C).

    Args:
        runs: The runs (their ``values`` are the table's axis columns).
        out_dir: The folder for the table (None: write nothing).
        axes: The axis columns, in order.
        worker: ``worker(scenario) -> row`` in the worker processes (default :func:`run_one`;
            a module-level function or a ``functools.partial`` of one, so that it pickles).
        jobs, scheduler, scheduler_timeout_s, resume, force, progress: As :func:`run_sweep`.
        label: The progress bar's and the messages' name of the command.
        files: The top-level names the command writes into ``out_dir`` (what ``resume``
            may overwrite).
        extra_columns: More columns the worker's rows hold, name -> pandas dtype.

    Raises:
        ConfigError, OutputError, KeyboardInterrupt: As :func:`run_sweep`.
    """
    from doorlab.runtime.executor import CONNECT_TIMEOUT_S, check_scheduler, open_executor

    if scheduler is not None:
        check_scheduler(scheduler)
    elif not isinstance(jobs, int) or isinstance(jobs, bool) or jobs < 1:
        raise ConfigError(f"jobs must be an integer >= 1, got {jobs!r}")
    out = Path(out_dir) if out_dir is not None else None
    previous = _check_dir(out, resume=resume, force=force, files=files) if out is not None else None

    rows: dict[int, dict] = {}
    if previous is not None:
        by_key = {run.key: run for run in runs}
        for record in previous.to_dict("records"):
            run = by_key.get(record.get("key"))
            if run is not None and record.get("status") != "error":
                record = {k: (None if _missing(v) else v) for k, v in record.items()}
                rows[run.index] = {**record, "run": run.index}
    todo = [run for run in runs if run.index not in rows]

    last_write, write_duration, writes = -float("inf"), 0.0, 0

    def table() -> pd.DataFrame:
        return make_table(list(rows.values()), axes, extra_columns)

    def save(*, now: bool) -> None:
        nonlocal last_write, write_duration, writes
        due = time.monotonic() - last_write >= write_duration / TABLE_WRITE_SHARE
        if out is not None and (now or due):
            begin = time.monotonic()
            write_table(table(), out)
            last_write = time.monotonic()
            if writes:  # the first write imports the Parquet writer: not the table's cost
                write_duration = last_write - begin
            writes += 1

    bar = None
    failures = sum(r.get("status") != "ok" for r in rows.values())
    start = time.perf_counter()
    description, workers = "none (every run was in the table)", 0
    started = False  # the folder is ours to write from here on
    try:
        if not todo and out is not None:
            _make_dir(out, resume=resume, force=force)
            started = True
            save(now=True)
        if todo:
            # The executor first: a scheduler that cannot be reached leaves nothing written.
            with open_executor(
                jobs=min(jobs, len(todo)),
                scheduler=scheduler,
                timeout_s=scheduler_timeout_s or CONNECT_TIMEOUT_S,
            ) as executor:
                if out is not None:
                    _make_dir(out, resume=resume, force=force)
                    started = True
                    save(now=True)
                description, workers = executor.description, executor.jobs
                bar = _progress_bar(len(runs), initial=len(rows), enabled=progress, label=label)
                if bar is not None:
                    bar.write(f"doorlab {label}: {len(todo)} runs on {description}")
                futures = {executor.submit(worker, run.scenario): run for run in todo}
                for future in completed(futures):  # raises a Ctrl-C Python dropped
                    run = futures[future]
                    try:
                        error = future.exception()
                    except concurrent.futures.CancelledError:  # a cluster that lost the task
                        error = RuntimeError("the run was cancelled (its worker was lost)")
                    if isinstance(error, KeyboardInterrupt):
                        raise KeyboardInterrupt
                    if error is not None:  # the worker died or could not run the task
                        outcome = {
                            "status": "error",
                            "error": f"{type(error).__name__}: {error}",
                            "run_wall_time_s": float("nan"),
                        }
                    else:
                        outcome = future.result()
                    rows[run.index] = _row(run, outcome)
                    failures += outcome["status"] != "ok"
                    save(now=len(rows) == len(runs))
                    if bar is not None:
                        bar.set_postfix_str(f"{failures} not ok", refresh=False)
                        bar.update(1)
    finally:
        if bar is not None:
            bar.close()
        if out is not None and started:
            write_table(table(), out)  # the finished runs, whatever ended the loop
    return ExecutedRuns(table(), out, description, time.perf_counter() - start, workers, len(todo))


def _missing(value: object) -> bool:
    try:
        return bool(pd.isna(value))
    except (TypeError, ValueError):
        return False


def _progress_bar(total: int, *, initial: int, enabled: bool, label: str = "sweep"):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(
        total=total, initial=initial, unit="run", file=sys.stderr, dynamic_ncols=True, desc=label
    )
