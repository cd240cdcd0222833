"""``doorlab bench``: every controller over the same N cupboards, through the sweep's runner
(:func:`doorlab.sweep.execution.execute_runs`: local processes or a Dask cluster, the table
written as episodes land, ``resume``, the progress bar), then the card
(:mod:`doorlab.bench.card`).
"""

from __future__ import annotations

import copy
import shlex
import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from doorlab.bench.card import BENCH_JSON, FIGURES, INDEX_HTML, definition, machine, write_card
from doorlab.bench.distribution import (
    AXES,
    BenchDistribution,
    describe_distribution,
    distribution_dict,
    plan_bench,
    validate_distribution,
)
from doorlab.bench.measures import COLUMNS, bench_episode, open_threshold
from doorlab.bench.stats import summarize
from doorlab.config import Scenario, validate
from doorlab.errors import ConfigError
from doorlab.sweep.results import RESULTS_CSV, RESULTS_PARQUET

BENCH_FILES = (RESULTS_PARQUET, RESULTS_CSV, BENCH_JSON, INDEX_HTML, FIGURES)
"""What a benchmark writes into its folder (and a resumed one rewrites)."""
DEFAULT_EPISODES = 100


def bench_base(scenario: Scenario | None = None) -> Scenario:
    """A benchmark's base scenario: ``scenario`` (default: the defaults) with the real run's
    safety limits checked at every tick (``station.safety.enabled``), so that "no safety stop"
    means what it says; a copy."""
    base = copy.deepcopy(scenario) if scenario is not None else Scenario()
    base.station.safety.enabled = True
    return validate(base)


@dataclass(frozen=True)
class BenchResult:
    """What :func:`run_bench` produced.

    Attributes:
        document: ``bench.json``'s content (:mod:`doorlab.bench.card`).
        frame: The table, one row per episode.
        out: The folder written (None: nothing written).
    """

    document: dict
    frame: pd.DataFrame
    out: Path | None


def controller_names(controllers: Sequence[str]) -> dict[str, str]:
    """Name -> spec of each controller, loaded and checked (a plug-in: imported, before
    anything runs; a relative FILE made absolute against the working directory).

    Raises:
        ConfigError, PluginError: Unknown, broken, listed twice, or two of one name.
    """
    from doorlab.config_checks import absolute_controller
    from doorlab.episode.controllers import controller_name

    names: dict[str, str] = {}
    for spec in controllers:
        spec = absolute_controller(spec, Path.cwd())  # the same file for every worker
        name = controller_name(spec)
        if name in names:
            raise ConfigError(
                f"controller {spec!r} is named {name!r} as {names[name]!r} is: a benchmark "
                "tells controllers apart by name (list each once)"
            )
        names[name] = spec
    return names


def run_bench(
    controllers: Sequence[str] | None = None,
    out_dir: str | Path | None = None,
    *,
    episodes: int = DEFAULT_EPISODES,
    seed: int = 0,
    base: Scenario | None = None,
    distribution: BenchDistribution | None = None,
    jobs: int = 1,
    scheduler: str | None = None,
    scheduler_timeout_s: float | None = None,
    resume: bool = False,
    force: bool = False,
    progress: bool = False,
    command: str | None = None,
) -> BenchResult:
    """Runs each controller over the same ``episodes`` cupboards and writes the card.

    Args:
        controllers: Built-ins' names or plug-ins' specs (default: every built-in).
        out_dir: The folder: ``bench.json``, ``index.html``, ``figures/``, the table
            ``results.parquet`` and ``results.csv`` (None: write nothing).
        episodes: Cupboards per controller. seed: Of their draws.
        base: Every field an episode does not draw (default: :func:`bench_base`; a given
            one is taken as is).
        distribution: What an episode draws (default: :class:`BenchDistribution`'s).
        jobs, scheduler, scheduler_timeout_s, resume, force, progress: As
            :func:`doorlab.sweep.run_sweep`'s.
        command: The command line the card says reproduces it (default: one built from the
            arguments).

    Returns:
        The card's document, the table and the folder.

    Raises:
        ConfigError, PluginError: Bad arguments, a controller that cannot be used.
        OutputError: ``out_dir`` exists (without ``resume`` or ``force``) or cannot be
            written.
        KeyboardInterrupt: After writing the table of the episodes finished so far.
    """
    from doorlab.config import CONTROLLERS
    from doorlab.sweep.execution import execute_runs

    specs = controller_names(list(controllers) if controllers else list(CONTROLLERS))
    base = bench_base() if base is None else validate(copy.deepcopy(base))
    distribution = validate_distribution(distribution or BenchDistribution())
    runs = plan_bench(
        list(specs.values()), episodes=episodes, seed=seed, base=base, distribution=distribution
    )
    executed = execute_runs(
        runs,
        out_dir,
        axes=list(AXES),
        worker=bench_episode,
        jobs=jobs,
        scheduler=scheduler,
        scheduler_timeout_s=scheduler_timeout_s,
        resume=resume,
        force=force,
        progress=progress,
        label="bench",
        files=BENCH_FILES,
        extra_columns=COLUMNS,
    )
    rows = [_plain(r) for r in executed.frame.to_dict("records")]
    document = {
        "bench": {
            "episodes": episodes,
            "seed": seed,
            "controllers": list(specs),
            "specs": {n: s for n, s in specs.items() if n != s},
            "command": command or _command(list(specs.values()), episodes, seed=seed),
        },
        "definition": definition(_threshold_deg(runs)),
        "distribution": {
            **distribution_dict(distribution),
            "draws": describe_distribution(distribution),
        },
        "base_scenario": _base_yaml(base),
        "controllers": summarize(rows, list(specs)),
        "cost": _cost(rows, executed, specs),
        "machine": machine(),
    }
    if executed.out is not None:
        _write(executed.out, document, rows)
    return BenchResult(document, executed.frame, executed.out)


def _plain(row: dict) -> dict:
    """A table row with pandas' missing values as None."""
    return {k: (None if _missing(v) else v) for k, v in row.items()}


def _missing(value: object) -> bool:
    try:
        return bool(pd.isna(value))
    except (TypeError, ValueError):
        return False


def _threshold_deg(runs) -> float:
    import math

    return math.degrees(open_threshold(runs[0].scenario))


def _base_yaml(base: Scenario) -> str:
    from pydrake.common.yaml import yaml_dump_typed

    return yaml_dump_typed(base)


def _command(specs: list[str], episodes: int, seed: int) -> str:
    words = ["doorlab", "bench"]
    for spec in specs:
        words += ["--controller", spec]
    words += ["--episodes", str(episodes), "--seed", str(seed)]
    return shlex.join(words)


def _cost(rows: list[dict], executed, specs: dict[str, str]) -> dict:
    """What the benchmark cost: per controller the seconds of one worker per episode, on the
    wall clock (``run_wall_time_s``: IK, simulation, metrics; the machine's load inflates
    it) and in CPU time (``episode_cpu_s``: what a core of its own gives), the run's wall time
    and throughput."""
    per: dict[str, dict] = {}
    for name in specs:
        mine = [r for r in rows if r.get("controller") == name]
        per[name] = {}
        for key, column in (("wall", "run_wall_time_s"), ("cpu", "episode_cpu_s")):
            seconds = [r[column] for r in mine if r.get(column) is not None]
            per[name][key] = {
                "median": statistics.median(seconds) if seconds else None,
                "mean": statistics.fmean(seconds) if seconds else None,
                "n": len(seconds),
            }
    rate = None
    if executed.ran and executed.wall_time_s > 0 and executed.workers:
        rate = executed.ran / executed.wall_time_s / executed.workers
    return {
        "executor": executed.executor,
        "workers": executed.workers,
        "episodes_run": executed.ran,
        "wall_time_s": executed.wall_time_s,
        "episodes_per_second_per_core": rate,
        "seconds_per_episode": per,
    }


def _write(out: Path, document: dict, rows: list[dict]) -> None:
    """bench.json, index.html and the figures, each atomically, recorded as doorlab's."""
    import json

    from doorlab.runtime.folders import record_written, remove_written
    from doorlab.sweep.results import _atomic

    remove_written(out, FIGURES)  # a resumed card's old figures (a user's stay)
    path = out / BENCH_JSON
    text = json.dumps(_clean(document), indent=2) + "\n"
    _atomic(path, lambda tmp: Path(tmp).write_text(text))
    record_written(out, [path])  # doorlab's at once: a --resume may replace it
    write_card(out, document, rows)


def _clean(value):
    """JSON-ready: NaN as null, numpy scalars as Python's."""
    import math

    import numpy as np

    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
