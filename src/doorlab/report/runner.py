"""Runs the report: :func:`run_report` runs the experiments (:mod:`doorlab.report.experiments`)
through one executor (:mod:`doorlab.runtime.executor`: local worker processes, or a Dask cluster),
each worker writing a run folder with :func:`doorlab.outputs.runs.run_to_folder` and shipping its
files back, then :func:`doorlab.report.page.build_page` writes the page. The whole report folder is
written atomically (staging folder, renamed at the end).
"""

from __future__ import annotations

import dataclasses
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from doorlab.config import Scenario, validate
from doorlab.errors import ConfigError
from doorlab.report.experiments import (
    ArmCase,
    RobustnessCase,
    RunRecord,
    make_arm_cases,
    make_experiments,
    make_plugin_experiments,
    make_robustness_cases,
)
from doorlab.runtime.interrupts import completed


def _write_json(path: Path, data: dict) -> None:
    from doorlab.runtime.folders import write_json

    write_json(path, data)


def _record_failure(
    name: str, run_dir: Path, scenario: Scenario | None, error: BaseException, elapsed: float
) -> RunRecord:
    """Writes a run folder holding only metrics.json with status ``error``."""
    message = f"{type(error).__name__}: {error}"
    run_dir.mkdir(parents=True, exist_ok=True)
    base = {}
    if scenario is not None:
        from doorlab.episode.plugins import display_name

        base = {"controller": display_name(scenario.controller), "doors": scenario.doors}
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

    from doorlab.outputs.runs import run_to_folder

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
    not ok (the robustness runs do not count: the problem set's plans are expected to fail
    some), ETA."""

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
    robustness: bool = False,
    scheduler_timeout_s: float | None = None,
    arm: bool = False,
    arm_band: bool = True,
    controllers: Sequence[str] | None = None,
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
            processes (:mod:`doorlab.runtime.executor`).
        scheduler_timeout_s: Each step of connecting to ``scheduler`` [s] (default
            :data:`doorlab.runtime.executor.CONNECT_TIMEOUT_S`).
        robustness: Also run the robustness grid (:func:`make_robustness_cases` on ``base``,
            reusing the experiments' identical runs; no replay) and add its section (default:
            not; ``doorlab report --robustness``).
        arm: Also run the "On the arm" cases (:func:`make_arm_cases` on ``base``, reusing
            identical runs; no replay) and add its section (default: not; ``doorlab report
            --arm``).
        arm_band: With ``arm``, also each plan under the band's other models of the arm
            (:func:`doorlab.report.experiments.arm_model_names`): the verdicts with their band.
        controllers: The controllers the report compares (built-ins' names, plug-ins'
            specs; default: every built-in): the robustness grid and "On the arm" run each;
            a plug-in also runs with the doors open and closed beside the problem set's
            experiments (:func:`doorlab.report.experiments.make_plugin_experiments`; not with
            ``experiments`` given).

    Returns:
        0 if every experiment's status is ``ok``, 1 otherwise (failed runs are on the page).
        The robustness runs do not count: the problem set's plans are expected to fail at some yaw
        errors, and the section reports that.

    Raises:
        ConfigError: ``jobs`` < 1, duplicate or unsafe experiment names, invalid ``base``.
        OutputError: ``out_dir`` exists (without ``force``) or cannot be written.
    """
    from doorlab.runtime.executor import CONNECT_TIMEOUT_S, check_scheduler, open_executor
    from doorlab.runtime.folders import staged_output

    if scheduler is not None:
        check_scheduler(scheduler)
    if not isinstance(jobs, int) or jobs < 1:
        raise ConfigError(f"jobs must be an integer >= 1, got {jobs!r}")
    if base is not None:
        validate(base)
    if controllers is not None:  # a plug-in's relative FILE: the same file for every worker
        from doorlab.config_checks import absolute_controller

        controllers = [absolute_controller(c, Path.cwd()) for c in controllers]
    if experiments is None:
        experiments = (*make_experiments(base), *make_plugin_experiments(controllers or (), base))
    experiments = tuple(experiments)
    names = [name for name, _ in experiments]
    if len(set(names)) != len(names):
        raise ConfigError(f"experiment names must be unique, got {names}")
    for name in names:
        if not name or name.startswith(".") or "/" in name or "\\" in name:
            raise ConfigError(f"experiment name {name!r} is not a plain folder name")

    cases: tuple[RobustnessCase, ...] = ()
    extra: tuple[tuple[str, Scenario], ...] = ()
    if robustness:
        cases, extra = make_robustness_cases(base, experiments, controllers=controllers)
        clash = sorted(set(names) & {name for name, _ in extra})
        if clash:
            raise ConfigError(f"experiment names clash with the robustness runs: {clash}")
    arm_cases: tuple[ArmCase, ...] = ()
    if arm:
        arm_cases, arm_extra = make_arm_cases(
            base, (*experiments, *extra), band=arm_band, controllers=controllers
        )
        clash = sorted(set(names) & {name for name, _ in arm_extra})
        if clash:
            raise ConfigError(f"experiment names clash with the arm runs: {clash}")
        extra = (*extra, *arm_extra)
    experiment_names = set(names)

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
                bar = _Progress(len(everything), experiments=experiment_names, enabled=progress)
                work_dir = None
                if scheduler is None:  # local workers: their temporary folders in ours
                    work_dir = staging / ".work"
                    work_dir.mkdir()
                futures = {
                    pool.submit(
                        _run_experiment,
                        name,
                        scenario,
                        name in experiment_names,
                        None if work_dir is None else str(work_dir),
                    ): (name, scenario)
                    for name, scenario in everything
                }
                for future in completed(futures):  # raises a Ctrl-C Python dropped
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
            bar = _Progress(len(everything), experiments=experiment_names, enabled=progress)
        total = time.perf_counter() - start
        ordered = [records[name] for name in names]
        bar.close(f"runs done; {bar.failed} of {len(names)} experiments not ok; writing the page")
        # Imported here: a worker process imports this module for _run_experiment only.
        from doorlab.report.page import build_page

        grid = [(case, records[case.run]) for case in cases] if robustness else None
        on_arm = [(case, records[case.run]) for case in arm_cases] if arm else None
        build_page(
            ordered,
            staging,
            total_wall_time_s=total,
            jobs=jobs,
            robustness=grid,
            arm=on_arm,
            base=base,
        )
    if progress:
        sys.stderr.write(f"report written to {out_dir} in {time.perf_counter() - start:.0f} s\n")
    return 0 if all(r.status == "ok" for r in ordered) else 1
