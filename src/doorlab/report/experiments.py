"""The seed's experiment set and :func:`run_report`: the runs in parallel, then the page.

:func:`run_report` runs :data:`EXPERIMENTS` (the three controllers with the doors open and
closed, IK with 2, 5 and 10 knots) through one executor (:mod:`doorlab.executor`: local worker
processes, or a Dask cluster), each worker writing a run folder with
:func:`doorlab.runs.run_to_folder` and shipping its files back, then
:func:`doorlab.report.page.build_page` writes the page. The whole report folder is written
atomically (staging folder, renamed at the end).
"""

from __future__ import annotations

import concurrent.futures
import copy
import dataclasses
import shutil
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from doorlab.config import Scenario, validate
from doorlab.errors import ConfigError

IK_KNOTS = (2, 5, 10)
"""Knot counts of the seed's task 1 question 1."""


def make_experiments(base: Scenario | None = None) -> tuple[tuple[str, Scenario], ...]:
    """The seed's experiment set, each a copy of ``base`` with its controller and doors.

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
"""The seed's eight runs on the default scenario (see :func:`make_experiments`)."""


@dataclass(frozen=True)
class RobustnessCase:
    """One cell of the report's robustness grid: a controller, doors closed, one yaw error.

    Attributes:
        run: Name of the experiment (run folder) holding it: a seed experiment when its
            scenario is the very same case, else ``robust_<controller>_yaw_<m|p><deg>``.
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


def _write_json(path: Path, data: dict) -> None:
    from doorlab.runs import write_json

    write_json(path, data)


def _record_failure(
    name: str, run_dir: Path, scenario: Scenario | None, error: BaseException, elapsed: float
) -> RunRecord:
    """Writes a run folder holding only metrics.json with status ``error``."""
    message = f"{type(error).__name__}: {error}"
    run_dir.mkdir(parents=True, exist_ok=True)
    base = {}
    if scenario is not None:
        base = {"controller": scenario.controller, "doors": scenario.doors}
    _write_json(run_dir / "metrics.json", {**base, "status": "error", "error": message})
    return RunRecord(name, run_dir, "error", message, elapsed)


def _run_experiment(
    name: str, scenario: Scenario, replay: bool = True, work_dir: str | None = None
) -> tuple[RunRecord, dict[str, bytes]]:
    """Worker: runs one experiment; returns its record and its run folder's files.

    The folder is written in a temporary directory and shipped back as bytes, so a worker on
    another machine (a Dask cluster) needs no shared file system. Never raises for a failed
    run.

    Args:
        name, scenario, replay: The experiment, and whether to write its replay.
        work_dir: Where the temporary directory goes (a local worker: inside the report's
            staging folder, so a worker killed by Ctrl-C or SIGTERM leaves nothing behind
            once its parent removes that folder); None: the machine's temporary directory.
    """
    import tempfile

    from doorlab.runs import run_to_folder

    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="doorlab_run_", dir=work_dir) as tmp:
        folder = Path(tmp) / name
        try:
            outcome = run_to_folder(scenario, folder, replay=replay)
            record = RunRecord(
                name, folder, outcome.status, outcome.message, time.perf_counter() - start
            )
        except Exception as e:  # one failed run must not lose the others
            record = _record_failure(name, folder, scenario, e, time.perf_counter() - start)
        files = {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}
    return record, files


def _write_run(record: RunRecord, files: dict[str, bytes], run_dir: Path) -> RunRecord:
    """Writes a worker's run folder files into ``run_dir``; the record now points there."""
    run_dir.mkdir(parents=True, exist_ok=True)
    for file_name, data in files.items():
        (run_dir / file_name).write_bytes(data)
    return dataclasses.replace(record, run_dir=run_dir)


class _Progress:
    """The report's progress bar (tqdm on stderr): runs done, how many of the experiments are
    not ok (the robustness runs do not count: the seed's plans are expected to fail some), ETA.
    """

    def __init__(self, total: int, *, experiments: set[str], enabled: bool) -> None:
        from tqdm import tqdm

        self.experiments = experiments
        self.failed = 0
        self.bar = tqdm(
            total=total,
            unit="run",
            desc="report",
            file=sys.stderr,
            disable=not enabled,
            dynamic_ncols=True,
        )

    def update(self, record: RunRecord) -> None:
        self.failed += record.name in self.experiments and record.status != "ok"
        self.bar.set_postfix_str(
            f"{self.failed} of {len(self.experiments)} experiments not ok; "
            f"last {record.name}: {record.status}",
            refresh=False,
        )
        self.bar.update(1)

    def close(self, text: str) -> None:
        self.bar.set_postfix_str(text)
        self.bar.close()


def run_report(
    out_dir: Path,
    *,
    jobs: int,
    force: bool = False,
    base: Scenario | None = None,
    progress: bool = True,
    experiments: Sequence[tuple[str, Scenario]] | None = None,
    scheduler: str | None = None,
    robustness: bool = True,
    scheduler_timeout_s: float | None = None,
) -> int:
    """Runs the experiments in parallel and writes the report folder atomically.

    Args:
        out_dir: The report folder to create (``index.html``, ``summary.json``, ``figures/``,
            ``runs/<name>/``).
        jobs: Worker processes (>= 1).
        force: Replace ``out_dir`` if it exists.
        base: The scenario the experiments vary (see :func:`make_experiments`); validated.
        progress: Show a progress bar on stderr.
        experiments: (name, scenario) pairs to run instead of ``make_experiments(base)``.
        scheduler: Run on this Dask cluster (``tcp://HOST:PORT``) instead of ``jobs`` local
            processes (:mod:`doorlab.executor`).
        scheduler_timeout_s: Each step of connecting to ``scheduler`` [s] (default
            :data:`doorlab.executor.CONNECT_TIMEOUT_S`).
        robustness: Also run the robustness grid (:func:`make_robustness_cases` on ``base``,
            reusing the experiments' identical runs; no replay) and add its section.

    Returns:
        0 if every experiment's status is ``ok``, 1 otherwise (failed runs are on the page).
        The robustness runs do not count: the seed's plans are expected to fail at some yaw
        errors, and the section reports that.

    Raises:
        ConfigError: ``jobs`` < 1, duplicate or unsafe experiment names, invalid ``base``.
        OutputError: ``out_dir`` exists (without ``force``) or cannot be written.
    """
    from doorlab.executor import CONNECT_TIMEOUT_S, check_scheduler, open_executor
    from doorlab.runs import staged_output

    if scheduler is not None:
        check_scheduler(scheduler)
    if not isinstance(jobs, int) or jobs < 1:
        raise ConfigError(f"jobs must be an integer >= 1, got {jobs!r}")
    if base is not None:
        validate(base)
    experiments = tuple(experiments) if experiments is not None else make_experiments(base)
    names = [name for name, _ in experiments]
    if len(set(names)) != len(names):
        raise ConfigError(f"experiment names must be unique, got {names}")
    for name in names:
        if not name or name.startswith(".") or "/" in name or "\\" in name:
            raise ConfigError(f"experiment name {name!r} is not a plain folder name")

    cases: tuple[RobustnessCase, ...] = ()
    extra: tuple[tuple[str, Scenario], ...] = ()
    if robustness:
        cases, extra = make_robustness_cases(base, experiments)
        clash = sorted(set(names) & {name for name, _ in extra})
        if clash:
            raise ConfigError(f"experiment names clash with the robustness runs: {clash}")
    seed_names = set(names)

    with staged_output(Path(out_dir), force=force) as staging:
        runs_dir = staging / "runs"
        runs_dir.mkdir()
        start = time.perf_counter()
        records: dict[str, RunRecord] = {}
        everything = (*experiments, *extra)
        bar = None
        if everything:
            with open_executor(
                jobs=min(jobs, len(everything)),
                scheduler=scheduler,
                timeout_s=scheduler_timeout_s or CONNECT_TIMEOUT_S,
            ) as pool:
                # The bar once connected: a scheduler that cannot be reached is one line.
                bar = _Progress(len(everything), experiments=seed_names, enabled=progress)
                work_dir = None
                if scheduler is None:  # local workers: their temporary folders in ours
                    work_dir = staging / ".work"
                    work_dir.mkdir()
                futures = {
                    pool.submit(
                        _run_experiment,
                        name,
                        scenario,
                        name in seed_names,
                        None if work_dir is None else str(work_dir),
                    ): (name, scenario)
                    for name, scenario in everything
                }
                for future in concurrent.futures.as_completed(futures):
                    name, scenario = futures[future]
                    try:
                        record = _write_run(*future.result(), runs_dir / name)
                    except Exception as e:  # e.g. a worker process died
                        record = _record_failure(
                            name, runs_dir / name, scenario, e, time.perf_counter() - start
                        )
                    records[name] = record
                    bar.update(record)
            if (staging / ".work").is_dir():
                shutil.rmtree(staging / ".work")  # empty: each worker removed its own folder
        if bar is None:
            bar = _Progress(len(everything), experiments=seed_names, enabled=progress)
        total = time.perf_counter() - start
        ordered = [records[name] for name in names]
        bar.close(f"runs done; {bar.failed} of {len(names)} experiments not ok; writing the page")
        from doorlab.report.page import build_page

        grid = [(case, records[case.run]) for case in cases] if robustness else None
        build_page(ordered, staging, total_wall_time_s=total, jobs=jobs, robustness=grid)
    if progress:
        sys.stderr.write(f"report written to {out_dir} in {time.perf_counter() - start:.0f} s\n")
    return 0 if all(r.status == "ok" for r in ordered) else 1
