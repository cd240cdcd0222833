"""The seed's experiment set, run in parallel, and one self-contained HTML page answering it.

:func:`run_report` runs :data:`EXPERIMENTS` (the three controllers with the doors open and
closed, IK with 2, 5 and 10 knots) in worker processes, each writing a run folder with
:func:`doorlab.runs.run_to_folder`, then :func:`build_page` writes

- ``index.html``: one page (images as base64 data URIs, inline CSS, no JavaScript, nothing
  fetched) with what was run, the seed's six questions, their figures and answers GENERATED from
  the measured metrics, a metrics table of every run, overlay plots and links to each run's
  folder and 3-D replay;
- ``summary.json``: every run's metrics;
- ``figures/*.png``: the page's figures.

:func:`build_page` only READS run folders (``metrics.json``, ``log.npz``, ``scenario.yaml``),
so a page can be rebuilt without simulating. Errors are computed over the arc window from the
measured joint positions (forward kinematics), as in :mod:`doorlab.metrics`.

The whole report folder is written atomically (staging folder, renamed at the end).
"""

from __future__ import annotations

import base64
import concurrent.futures
import copy
import datetime
import html
import json
import math
import multiprocessing
import os
import platform
import shutil
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import TextIO

import numpy as np

from doorlab.config import Scenario, validate
from doorlab.errors import ConfigError
from doorlab.geometry import DoorGeometry, true_door_geometry
from doorlab.metrics import Kinematics, Tracking, compute_tracking
from doorlab.simulation import EpisodeResult

# ---------------------------------------------------------------------------------------------
# The experiment set.

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


# ---------------------------------------------------------------------------------------------
# Running.


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


def _record_failure(name: str, run_dir: Path, scenario: Scenario | None, error: BaseException,
                    elapsed: float) -> RunRecord:
    """Writes a run folder holding only metrics.json with status ``error``."""
    message = f"{type(error).__name__}: {error}"
    run_dir.mkdir(parents=True, exist_ok=True)
    base = {}
    if scenario is not None:
        base = {"controller": scenario.controller, "doors": scenario.doors}
    _write_json(run_dir / "metrics.json", {**base, "status": "error", "error": message})
    return RunRecord(name, run_dir, "error", message, elapsed)


def _run_experiment(name: str, scenario: Scenario, run_dir: str) -> RunRecord:
    """Worker: runs one experiment into ``run_dir``; never raises for a failed run."""
    from doorlab.runs import run_to_folder

    start = time.perf_counter()
    folder = Path(run_dir)
    try:
        outcome = run_to_folder(scenario, folder, replay=True)
    except Exception as e:  # one failed run must not lose the others
        return _record_failure(name, folder, scenario, e, time.perf_counter() - start)
    return RunRecord(name, folder, outcome.status, outcome.message, time.perf_counter() - start)


class _Progress:
    """A text progress bar on a stream; one line per update when the stream is not a TTY."""

    WIDTH = 28

    def __init__(self, total: int, *, enabled: bool, stream: TextIO | None = None) -> None:
        self.total = total
        self.done = 0
        self.failed = 0
        self.enabled = enabled
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.start = time.perf_counter()
        self._show("starting")

    def _show(self, text: str) -> None:
        if not self.enabled:
            return
        filled = int(round(self.WIDTH * self.done / max(self.total, 1)))
        bar = "#" * filled + "-" * (self.WIDTH - filled)
        elapsed = time.perf_counter() - self.start
        line = f"[{bar}] {self.done}/{self.total}  {elapsed:5.0f} s  {text}"
        if self.tty:
            self.stream.write("\r\033[K" + line)
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def update(self, record: RunRecord) -> None:
        self.done += 1
        self.failed += record.status != "ok"
        self._show(f"{record.name}: {record.status} ({record.elapsed_s:.1f} s)")

    def close(self, text: str) -> None:
        self._show(text)
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()


def run_report(
    out_dir: Path,
    *,
    jobs: int,
    force: bool = False,
    base: Scenario | None = None,
    progress: bool = True,
    experiments: Sequence[tuple[str, Scenario]] | None = None,
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

    Returns:
        0 if every run's status is ``ok``, 1 otherwise (failed runs are on the page).

    Raises:
        ConfigError: ``jobs`` < 1, duplicate or unsafe experiment names, invalid ``base``.
        OutputError: ``out_dir`` exists (without ``force``) or cannot be written.
    """
    from doorlab.runs import commit_output, prepare_output

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

    staging = prepare_output(Path(out_dir), force=force)
    try:
        runs_dir = staging / "runs"
        runs_dir.mkdir()
        start = time.perf_counter()
        records: dict[str, RunRecord] = {}
        bar = _Progress(len(experiments), enabled=progress)
        if experiments:
            context = multiprocessing.get_context("spawn")  # pydrake and fork do not mix
            pool = concurrent.futures.ProcessPoolExecutor(
                max_workers=min(jobs, len(experiments)), mp_context=context
            )
            try:
                futures = {
                    pool.submit(_run_experiment, name, scenario, str(runs_dir / name)): (
                        name, scenario,
                    )
                    for name, scenario in experiments
                }
                for future in concurrent.futures.as_completed(futures):
                    name, scenario = futures[future]
                    try:
                        record = future.result()
                    except Exception as e:  # e.g. a worker process died
                        record = _record_failure(
                            name, runs_dir / name, scenario, e, time.perf_counter() - start
                        )
                    records[name] = record
                    bar.update(record)
            except BaseException:
                pool.shutdown(wait=False, cancel_futures=True)
                raise
            pool.shutdown(wait=True)
        total = time.perf_counter() - start
        ordered = [records[name] for name in names]
        bar.close(f"runs done; {bar.failed} not ok; writing the page")
        build_page(ordered, staging, total_wall_time_s=total, jobs=jobs)
        commit_output(staging, Path(out_dir))
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    if progress:
        sys.stderr.write(f"report written to {out_dir} in {time.perf_counter() - start:.0f} s\n")
    return 0 if all(r.status == "ok" for r in ordered) else 1


# ---------------------------------------------------------------------------------------------
# Reading run folders.


@dataclass
class _Run:
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
}
"""Line colour of each controller (IK by knot count) on every figure of the page."""

_EXTRA_COLORS = ("tab:orange", "tab:pink", "tab:olive", "tab:cyan", "tab:gray")


def _line_style(run: _Run, index: int) -> dict:
    """The same colour for a controller on every figure; dashed when the doors are closed."""
    controller = run.metrics.get("controller")
    knots = run.metrics.get("knots") if controller == "ik" else None
    color = CONTROLLER_COLORS.get((controller, knots))
    if color is None:
        color = _EXTRA_COLORS[index % len(_EXTRA_COLORS)]
    return {"color": color, "ls": "--" if run.metrics.get("doors") == "closed" else "-"}


def _load_run(record: RunRecord, kinematics: Kinematics) -> _Run:
    from pydrake.common.yaml import yaml_load_typed

    folder = Path(record.run_dir)
    metrics: dict = {}
    try:
        metrics = json.loads((folder / "metrics.json").read_text())
    except (OSError, ValueError) as e:
        status = record.status if record.status not in ("ok", "unknown") else "missing"
        message = record.message or f"cannot read {folder / 'metrics.json'}: {e}"
        return _Run(record, {}, status, message, record.name)
    status = str(metrics.get("status", "unknown"))
    error = str(metrics.get("error") or record.message or "")
    if not error and status == "slipped" and metrics.get("slip_time_s") is not None:
        error = f"the handle slipped out of the gripper at t = {metrics['slip_time_s']:.2f} s"
    elif not error and status == "speed_limit":
        error = "a joint exceeded its data-sheet speed limit"
    run = _Run(record, metrics, status, error, _label(record.name, metrics))
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


# ---------------------------------------------------------------------------------------------
# Number formatting: every number tied to a metric is a <span class="num"> carrying the run and
# the metrics.json key, so tests can check the printed value against the folder.

SIGNIFICANT_DIGITS = 3
"""Significant digits of the numbers on the page."""

_DEG_PER_RAD = 180.0 / math.pi


def format_number(value: float | None, digits: int = SIGNIFICANT_DIGITS) -> str:
    """``value`` with ``digits`` significant digits, positional (no exponent); "n/a" if absent."""
    if value is None or not isinstance(value, (int, float)) or not math.isfinite(value):
        return "n/a"
    if value == 0:
        return "0"
    text = np.format_float_positional(
        float(value), precision=digits, unique=False, fractional=False, trim="k"
    )
    return text.rstrip(".")


def metric_unit(key: str) -> tuple[str, float]:
    """Display unit and scale of a metrics.json key: ``_m`` -> mm, ``_rad`` -> deg, ..."""
    if key.endswith("_rad_s"):
        return "rad/s", 1.0
    if key.endswith("_m"):
        return "mm", 1000.0
    if key.endswith("_rad"):
        return "deg", _DEG_PER_RAD
    if key.endswith("_Nm"):
        return "N m", 1.0
    if key.endswith("_s"):
        return "s", 1.0
    return "", 1.0


def _metric_header(key: str) -> str:
    unit, _ = metric_unit(key)
    name = key
    for suffix in ("_rad_s", "_Nm", "_m", "_rad", "_s"):
        if name.endswith(suffix):
            name = name[: -len(suffix)]
            break
    name = name.replace("_cmd", " (cmd)").replace("_", " ")
    return f"{name} [{unit}]" if unit else name


def _span(text: str, *, run: str = "", key: str = "", unit: str = "") -> str:
    attrs = ' class="num"'
    if run:
        attrs += f' data-run="{html.escape(run)}"'
    if key:
        attrs += f' data-key="{html.escape(key)}"'
    if unit:
        attrs += f' data-unit="{html.escape(unit)}"'
    shown = f"{text} {unit}" if unit else text
    return f"<span{attrs}>{html.escape(shown)}</span>"


# ---------------------------------------------------------------------------------------------
# The page.

QUESTIONS: tuple[tuple[str, int, str], ...] = (
    (
        "t1q1", 1,
        "With the doors open, generate tracking error plots for trajectories with 2, 5 and 10 "
        "knot points. How does the number of knot points affect tracking error?",
    ),
    (
        "t1q2", 1,
        "Zoom in to the xy position plot of Q. Is the magnitude of tracking error consistent "
        "along the arc with the doors open? Why do you think the error is (in)consistent? What "
        "happens if the doors are closed?",
    ),
    (
        "t2q1", 2,
        "Generate tracking error plots with the doors open. How does the tracking error compare "
        "with the trajectory generated from IK? (Hint: tracking error should be smaller)",
    ),
    (
        "t2q2", 2,
        "Zoom in to the xy position plot of Q. Is the magnitude of tracking error consistent "
        "along the arc with the doors open? Why do you think the error is (in)consistent? What "
        "happens if the doors are closed? (Hint: error along the arc should be smaller and more "
        "consistent).",
    ),
    (
        "t3q1", 3,
        "Generate tracking error plots with the doors open. How does the tracking error compare "
        "with the other approaches?",
    ),
    (
        "t3q2", 3,
        "Generate tracking error plots with the doors closed. How does closing the door affect "
        "tracking error?",
    ),
)
"""The seed's six questions, quoted: (id, task, text)."""

TASK_TITLES = {
    1: "Task 1: pointwise IK and a cubic joint spline",
    2: "Task 2: Jacobian pseudo-inverse velocity mapping",
    3: "Task 3: Jacobian-transpose impedance",
}

_CSS = """
html { overflow-x: hidden; }
body { font-family: "DejaVu Sans", Helvetica, Arial, sans-serif; color: #1b1b1b;
       max-width: 1180px; margin: 0 auto; padding: 1em 1.5em 3em; line-height: 1.45; }
h1 { font-size: 1.6em; border-bottom: 2px solid #333; padding-bottom: .2em; }
h2 { font-size: 1.3em; margin-top: 2em; border-bottom: 1px solid #999; }
h3 { font-size: 1.08em; margin-top: 1.6em; }
table { border-collapse: collapse; margin: .6em 0; font-size: .86em; }
#metrics-table { font-size: .68em; }
#metrics-table th, #metrics-table td { padding: .2em .2em; }
.wide { width: calc(100vw - 2em); position: relative; left: 50%; transform: translateX(-50%); }
th, td { border: 1px solid #999; padding: .25em .5em; text-align: right; vertical-align: top; }
th { background: #eceff3; text-align: center; }
td.text, th.text { text-align: left; }
tr.failed td { background: #fdeaea; }
tr.warn td { background: #fff6dc; }
.scroll { overflow-x: auto; }
blockquote { margin: .6em 0; padding: .4em .9em; border-left: 4px solid #6a8fbf;
             background: #f3f6fa; }
.answer { background: #f7f7f2; border: 1px solid #ddd8c4; padding: .5em .9em; }
.answer p { margin: .45em 0; }
.contradiction { color: #9b1c1c; font-weight: bold; }
.status-ok { color: #17651d; font-weight: bold; }
.status-bad { color: #9b1c1c; font-weight: bold; }
figure { margin: .8em 0; display: inline-block; max-width: 100%; vertical-align: top; }
figure img { max-width: 100%; border: 1px solid #ccc; }
figcaption { font-size: .86em; color: #444; max-width: 820px; }
.meta td, .meta th { text-align: left; }
code { background: #f0f0f0; padding: 0 .2em; }
"""


class _Figures:
    """Writes the page's figures to ``figures/`` and returns them as embedded HTML."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.folder.mkdir(parents=True, exist_ok=True)
        self.paths: list[Path] = []

    def embed(self, name: str, fig, caption: str) -> str:
        from doorlab.plots import save_figure

        path = save_figure(fig, self.folder / f"{name}.png")
        self.paths.append(path)
        data = base64.b64encode(path.read_bytes()).decode("ascii")
        return (
            f'<figure><img src="data:image/png;base64,{data}" alt="{html.escape(caption)}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>\n"
        )


class _Page:
    """The loaded runs and the helpers the answers use."""

    def __init__(self, runs: list[_Run], figures: _Figures) -> None:
        self.runs = {run.name: run for run in runs}
        self.order = [run.name for run in runs]
        self.figures = figures
        self.styles = {run.label: _line_style(run, i) for i, run in enumerate(runs)}

    # -- access ----------------------------------------------------------------------------
    def logged(self, *names: str) -> list[_Run]:
        """The named runs that have logs, in the order given."""
        return [self.runs[n] for n in names if n in self.runs and self.runs[n].has_logs]

    def value(self, name: str, key: str) -> float | None:
        value = self.runs[name].metrics.get(key)
        return float(value) if isinstance(value, (int, float)) else None

    def num(self, name: str, key: str) -> str:
        """A metric of run ``name`` in display units, tagged for tests."""
        unit, scale = metric_unit(key)
        value = self.value(name, key)
        text = format_number(None if value is None else value * scale)
        return _span(text, run=name, key=key, unit=unit)

    def missing(self, *names: str) -> str:
        """A sentence naming the runs among ``names`` that have no logs ("" if none)."""
        parts = []
        for name in names:
            run = self.runs.get(name)
            if run is None:
                parts.append(f"<code>{name}</code> was not run")
            elif not run.has_logs:
                reason = f": {html.escape(run.error)}" if run.error else ""
                parts.append(
                    f"<code>{name}</code> produced no logs (status "
                    f"<b>{html.escape(run.status)}</b>{reason})"
                )
        if not parts:
            return ""
        return "<p>Not answered from data: " + "; ".join(parts) + ".</p>"

    def status_note(self, *names: str) -> str:
        """A sentence flagging runs that finished with a status other than ok."""
        parts = [
            f"<code>{n}</code> finished with status <b>{html.escape(self.runs[n].status)}</b>"
            + (f" ({html.escape(self.runs[n].error)})" if self.runs[n].error else "")
            for n in names
            if n in self.runs and self.runs[n].has_logs and self.runs[n].status != "ok"
        ]
        return "<p>Note: " + "; ".join(parts) + ".</p>" if parts else ""

    # -- figures ---------------------------------------------------------------------------
    def tracking_figures(self, key: str, runs: list[_Run], what: str) -> str:
        from doorlab.plots import plot_orientation_error, plot_radial_error

        if not runs:
            return ""
        curves = {run.label: run.tracking for run in runs}
        return self.figures.embed(
            f"{key}_radial_error",
            plot_radial_error(
                curves, title=f"Radial tracking error of Q: {what}", styles=self.styles
            ),
            f"Radial error of Q (measured q, FK) over the arc window [mm]: {what}. "
            "Bottom panel: |error| on a log scale.",
        ) + self.figures.embed(
            f"{key}_orientation_error",
            plot_orientation_error(
                curves, title=f"Orientation error of L7: {what}", styles=self.styles
            ),
            f"Orientation error angle of L7 (measured q) over the arc window [deg]: {what}.",
        )

    def path_figure(self, key: str, runs: list[_Run], what: str) -> str:
        from doorlab.plots import plot_q_path

        if not runs:
            return ""
        curves = {run.label: run.tracking for run in runs}
        return self.figures.embed(
            f"{key}_q_path",
            plot_q_path(
                curves, runs[0].geometry, title=f"Q in the xy plane: {what}", styles=self.styles
            ),
            f"Q's path (measured q) against the handle arc and the hinge: {what}. Right: the "
            "zoom, Q's radial deviation from the arc [mm] along the arc.",
        )

    def door_figure(self, key: str, runs: list[_Run], what: str) -> str:
        from doorlab.plots import plot_door_angle

        if not runs:
            return ""
        return self.figures.embed(
            f"{key}_door_angle",
            plot_door_angle(
                {run.label: run.result for run in runs}, geometry=runs[0].geometry,
                title=f"Left hinge angle: {what}", styles=self.styles,
            ),
            f"Left door hinge angle [deg] (negative = open): {what}; dotted: the door angle "
            "the arc plan implies.",
        )

    def torque_figure(self, key: str, runs: list[_Run], what: str) -> str:
        from doorlab.plots import plot_external_torque_norm

        if not runs:
            return ""
        return self.figures.embed(
            f"{key}_external_torque_norm",
            plot_external_torque_norm(
                {run.label: run.result for run in runs}, title=f"|tau_ext|: {what}",
                styles=self.styles,
            ),
            f"Norm of the external (contact) joint torques [N m]: {what}.",
        )


def _order_phrase(values: Sequence[float], *, falling: str = "falls", rising: str = "grows") -> str:
    """Describes a sequence by its actual order: monotone falling/rising or not monotone."""
    diffs = np.diff(np.asarray(values, float))
    if len(diffs) and np.all(diffs < 0):
        return falling
    if len(diffs) and np.all(diffs > 0):
        return rising
    return "changes, not monotonically,"


def _ratio_phrase(a: float | None, b: float | None) -> str:
    """'3.2 times smaller than' / 'larger than' / 'equal to' for a vs b (both > 0)."""
    if a is None or b is None or not (math.isfinite(a) and math.isfinite(b)):
        return "not comparable with"
    if a == b:
        return "equal to"
    if a < b:
        ratio = b / a if a > 0 else math.inf
        return f"{_span(format_number(ratio))} times smaller than" if math.isfinite(ratio) else (
            "smaller than"
        )
    ratio = a / b if b > 0 else math.inf
    return f"{_span(format_number(ratio))} times larger than" if math.isfinite(ratio) else (
        "larger than"
    )


def _signed_range_mm(tracking: Tracking, *, skip: float = 0.05) -> tuple[float, float]:
    """(min, max) of the signed radial error [mm] for tau >= skip (after the start transient)."""
    mask = tracking.tau >= skip
    e = 1000.0 * tracking.radial_error[mask if np.any(mask) else slice(None)]
    return float(np.min(e)), float(np.max(e))


def _knot_profile(run: _Run) -> tuple[float, list[float]] | None:
    """(max |e| at the knots [mm], peak |e| per knot segment [mm]) of an IK run."""
    knots = run.scenario.ik.knots if run.scenario else None
    if not knots or knots < 2:
        return None
    tau = run.tracking.tau
    e = np.abs(1000.0 * run.tracking.radial_error)
    knot_taus = np.linspace(0.0, 1.0, knots)
    at_knots = [float(e[int(np.argmin(np.abs(tau - k)))]) for k in knot_taus]
    peaks = []
    for a, b in zip(knot_taus[:-1], knot_taus[1:], strict=True):
        mask = (tau >= a) & (tau <= b)
        peaks.append(float(np.max(e[mask])) if np.any(mask) else float("nan"))
    return max(at_knots), peaks


def _tau_of_max(tracking: Tracking) -> float:
    """Arc parameter tau in [0, 1] where |radial error| is largest."""
    return float(tracking.tau[int(np.argmax(np.abs(tracking.radial_error)))])


def _side(tracking: Tracking) -> str:
    """ "outside" or "inside": where Q is at its largest radial error."""
    e = tracking.radial_error
    return "inside" if len(e) and e[int(np.argmax(np.abs(e)))] < 0 else "outside"


def _door_lag_deg(run: _Run) -> float | None:
    """Largest lag of the left door behind the arc plan over the arc [deg] (metrics.py)."""
    lag = run.metrics.get("door_lag_max_rad")
    return None if lag is None else math.degrees(lag)


def _closed_sentence(page: _Page, closed: str, opened: str, *, explain: bool = True) -> str:
    """What closing the doors did for one controller: door, error, torques, grip."""
    c = page.runs[closed]
    geometry = c.geometry
    planned = math.degrees(geometry.sweep) if geometry else float("nan")
    opening = page.value(closed, "door_opening_arc_end_rad")
    parts = [
        f"With the doors closed ({html.escape(c.label)}) the door had opened by "
        f"{page.num(closed, 'door_opening_arc_end_rad')} at the arc's end, of the "
        f"{_span(format_number(planned))} deg the arc asks for "
        f"({page.num(closed, 'door_opening_rad')} at the episode's end, after the hold)"
    ]
    if opening is not None and math.isfinite(planned):
        share = 100.0 * math.degrees(opening) / planned
        parts[0] += f", i.e. {_span(format_number(share))} % of the sweep."
    else:
        parts[0] += "."
    held = c.metrics.get("handle_held")
    slip = page.value(closed, "slip_time_s")
    if slip is not None:
        parts.append(
            f"The handle slipped out of the gripper at t = {page.num(closed, 'slip_time_s')} "
            "(the metrics' status is <b>slipped</b>)."
        )
    elif held is not None:
        parts.append("The gripper kept the handle to the end." if held else
                     "The gripper did not hold the handle at the end.")
    lag = _door_lag_deg(c)
    if lag is not None:
        parts.append(
            f"Over the arc the door trails the plan's hinge angle by up to "
            f"{_span(format_number(lag))} deg."
        )
    if opened in page.runs and page.runs[opened].has_logs:
        a = page.value(closed, "max_radial_error_m")
        b = page.value(opened, "max_radial_error_m")
        parts.append(
            f"Its max radial error is {page.num(closed, 'max_radial_error_m')}, "
            f"{_ratio_phrase(a, b)} the {page.num(opened, 'max_radial_error_m')} with the doors "
            f"open (RMS {page.num(closed, 'rms_radial_error_m')} vs "
            f"{page.num(opened, 'rms_radial_error_m')}); max orientation error "
            f"{page.num(closed, 'max_orientation_error_rad')} vs "
            f"{page.num(opened, 'max_orientation_error_rad')}."
        )
        if not explain:
            pass
        elif slip is not None:
            parts.append(
                "Once the handle has slipped, Q no longer moves with the door, so the errors "
                "after the slip say little about the controller."
            )
        elif a is not None and b is not None and a < b:
            parts.append(
                "Holding the handle, the gripper is carried by the door on the handle's circle: "
                "Q can leave the arc only as far as the grasp gives, so the radial error cannot "
                "grow as in free space"
                + ("; the lag shows up along the arc instead (the door angle)."
                   if lag is not None and lag > 1.0 else ".")
            )
        elif a is not None and b is not None and a > b:
            parts.append(
                "The door's inertia and hinge damping load the arm through the handle, and the "
                "arm yields to that load."
            )
        parts.append(
            f"The peak external joint torque is {page.num(closed, 'peak_external_torque_Nm')} "
            f"vs {page.num(opened, 'peak_external_torque_Nm')} with the doors open: the door "
            "pushes back on the arm through the handle."
        )
    return "<p>" + " ".join(parts) + "</p>"


def _answer_t1q1(page: _Page) -> tuple[str, str]:
    names = [f"ik_{k}_open" for k in IK_KNOTS]
    runs = page.logged(*names)
    figs = page.tracking_figures("t1q1", runs, "IK, doors open, 2 / 5 / 10 knots")
    text = page.missing(*names)
    if runs:
        knots = [r.scenario.ik.knots for r in runs]
        max_e = [page.value(r.name, "max_radial_error_m") for r in runs]
        phrase = (_order_phrase(max_e) + " as knots are added") if len(runs) > 1 else "is"
        listing = ", ".join(
            f"{page.num(r.name, 'max_radial_error_m')} with {k} knots"
            for r, k in zip(runs, knots, strict=True)
        )
        rms = ", ".join(page.num(r.name, "rms_radial_error_m") for r in runs)
        ori = ", ".join(page.num(r.name, "max_orientation_error_rad") for r in runs)
        text += (
            f"<p>The max radial error of Q {phrase}: {listing} "
            f"(RMS {rms}; max orientation error {ori}).</p>"
        )
        cmd = ", ".join(page.num(r.name, "max_radial_error_cmd_m") for r in runs)
        gaps = [
            abs((page.value(r.name, "max_radial_error_m") or 0)
                - (page.value(r.name, "max_radial_error_cmd_m") or 0))
            for r in runs
        ]
        share = max(
            g / m for g, m in zip(gaps, max_e, strict=True) if m and m > 0
        ) if any(m for m in max_e) else float("nan")
        text += (
            f"<p>From the commanded q_ref alone (what the seed plotted) the max radial errors are "
            f"{cmd}: the measured and commanded maxima differ by at most "
            f"{_span(format_number(100 * share))} %, so "
            + ("the error is the plan's own: between knots the cubic spline interpolates joint "
               "angles, and the forward kinematics of interpolated joint angles is not a circle "
               "in the task space. The inner loop adds little." if share < 0.25 else
               "a large part of the error comes from the inner loop's lag, not from the plan.")
            + "</p>"
        )
        if len(runs) >= 2 and all(m and m > 0 for m in max_e):
            sweep = math.degrees(runs[0].geometry.sweep)
            steps = [sweep / (k - 1) for k in knots]
            orders = [
                (i, math.log(max_e[i] / max_e[i + 1]) / math.log(steps[i] / steps[i + 1]))
                for i in range(len(runs) - 1)
                if steps[i] != steps[i + 1]
            ]
            spacing = ", ".join(
                f"{_span(format_number(s))} deg with {k} knots"
                for s, k in zip(steps, knots, strict=True)
            )
            steps_text = "; ".join(
                f"from {knots[i]} to {knots[i + 1]} knots the error scales like the segment "
                f"length to the power {_span(format_number(o, 2))}"
                for i, o in orders
            )
            text += (
                f"<p>More knots shorten each interpolated segment of the arc ({spacing}): "
                f"{steps_text}. A power near 2 is the chord-like bulge of the spline between "
                "knots (a sagitta scales with the square of the chord); a power near 0 means the "
                "error has reached a floor that more knots do not remove"
                + ("; a negative power means more knots made the error larger"
                   if any(o < 0 for _, o in orders) else "")
                + ".</p>"
            )
        tol = runs[-1].scenario.ik.position_tolerance
        last = max_e[-1]
        if last is not None and tol and last < 3 * tol:
            text += (
                f"<p>With {knots[-1]} knots the max error "
                f"({page.num(runs[-1].name, 'max_radial_error_m')}) is within 3 times the IK "
                f"position tolerance ({_span(format_number(1000 * tol))} mm, a box around each "
                "knot's arc point): more knots cannot push the error far below that tolerance."
                "</p>"
            )
        text += page.status_note(*names)
    return figs, text


def _answer_t1q2(page: _Page) -> tuple[str, str]:
    names = [f"ik_{k}_open" for k in IK_KNOTS]
    runs = page.logged(*names)
    figs = page.path_figure("t1q2", runs, "IK, doors open, 2 / 5 / 10 knots")
    pair = page.logged("ik_10_open", "ik_10_closed")
    if len(pair) == 2:
        figs += page.path_figure("t1q2_closed", pair, "IK 10 knots, doors open vs closed")
    closed = page.logged("ik_10_closed")
    if closed:
        figs += page.door_figure("t1q2", closed, "IK 10 knots, doors closed")
    text = page.missing(*names, "ik_10_closed")
    bulging, floor = [], []
    for run in runs:
        profile = _knot_profile(run)
        if profile is None:
            continue
        at_knots, peaks = profile
        worst = max(peaks)
        sign = _side(run.tracking)
        k = run.scenario.ik.knots
        segments = "segment" if k == 2 else f"{k - 1} segments"
        ratio = worst / max(at_knots, 1e-9)
        consistent = ratio <= 3.0
        (floor if consistent else bulging).append(run)
        text += (
            f"<p>{html.escape(run.label)}: |error| is at most "
            f"{_span(format_number(at_knots))} mm at the {k} knots and peaks at "
            f"{_span(format_number(worst))} mm between them (largest excursion {sign} the arc). "
            + (
                f"The peaks of the {segments} range from {_span(format_number(min(peaks)))} to "
                f"{_span(format_number(max(peaks)))} mm. " if k > 2 else ""
            )
            + ("The error is <b>not consistent</b> along the arc: small at the knots, a bulge "
               f"between them ({_span(format_number(ratio))} times larger)." if not consistent
               else "The error is <b>roughly consistent</b> along the arc: the peaks between "
               f"knots are within {_span(format_number(ratio))} times the error at the knots.")
            + "</p>"
        )
    if runs:
        tol = runs[0].scenario.ik.position_tolerance if runs[0].scenario else float("nan")
        why = (
            "<p>Why: IK puts Q on the arc only at the knots; between them the plan is a cubic "
            "spline in joint space, whose forward kinematics is not the circle, so the error "
            "bulges between knots, more for longer segments."
        )
        if bulging:
            why += (
                " With " + ", ".join(html.escape(r.label) for r in bulging)
                + " this bulge dominates."
            )
        if floor:
            why += (
                " With " + ", ".join(html.escape(r.label) for r in floor)
                + " the bulge has shrunk below the error the IK leaves at the knots themselves: "
                f"each knot may sit anywhere in a box of &plusmn;{_span(format_number(1000 * tol))}"
                " mm around its arc point (the IK position tolerance), so the error wanders "
                "from knot to knot rather than growing between them."
            )
        text += why + "</p>"
    if closed:
        text += _closed_sentence(page, "ik_10_closed", "ik_10_open")
        text += page.status_note("ik_10_closed")
    return figs, text


def _reference_ik(page: _Page) -> _Run | None:
    """The IK run the other controllers are compared with: the most knots, doors open."""
    runs = page.logged(*(f"ik_{k}_open" for k in reversed(IK_KNOTS)))
    return runs[0] if runs else None


def _answer_t2q1(page: _Page) -> tuple[str, str]:
    iks = page.logged(*(f"ik_{k}_open" for k in reversed(IK_KNOTS)))
    figs = page.tracking_figures(
        "t2q1", page.logged("velocity_open") + iks[:2], "velocity plan vs IK, doors open"
    )
    text = page.missing("velocity_open", "ik_10_open")
    ref = _reference_ik(page)
    if page.logged("velocity_open") and ref is not None:
        v = page.value("velocity_open", "max_radial_error_m")
        sentences = [
            f"{_ratio_phrase(v, page.value(ik.name, 'max_radial_error_m'))} the "
            f"{page.num(ik.name, 'max_radial_error_m')} of {html.escape(ik.label)}"
            for ik in iks
        ]
        tau_max = _tau_of_max(page.runs["velocity_open"].tracking)
        where = (
            f" (reached at {_span(format_number(100 * tau_max))} % of the arc: the start "
            "transient, while the arm picks up speed)" if tau_max < 0.1 else ""
        )
        text += (
            "<p>The velocity plan's max radial error is "
            f"{page.num('velocity_open', 'max_radial_error_m')}{where}: "
            + "; ".join(sentences) + ". "
            f"RMS: {page.num('velocity_open', 'rms_radial_error_m')} vs "
            f"{page.num(ref.name, 'rms_radial_error_m')} ({html.escape(ref.label)}). Max "
            f"orientation error: {page.num('velocity_open', 'max_orientation_error_rad')} vs "
            f"{page.num(ref.name, 'max_orientation_error_rad')}.</p>"
        )
        larger = [
            ik for ik in iks
            if v is not None and v >= (page.value(ik.name, "max_radial_error_m") or math.inf)
        ]
        if v is not None and not larger:
            text += (
                "<p>This agrees with the seed's hint (the error should be smaller): the "
                "velocity plan closes the loop on Q's task-space error at every control "
                "step, q_dot = J<sup>+</sup> (K<sub>w</sub> &theta; n, K<sub>v</sub> e), "
                "so it follows the arc itself rather than a joint-space interpolation of "
                "a few points on it.</p>"
            )
        elif larger:
            text += (
                '<p class="contradiction">This contradicts the seed\'s hint: here the velocity '
                "plan's max radial error is not smaller than that of "
                + ", ".join(html.escape(ik.label) for ik in larger) + ".</p>"
            )
        text += page.status_note("velocity_open", ref.name)
    return figs, text


def _answer_t2q2(page: _Page) -> tuple[str, str]:
    ref = _reference_ik(page)
    pair = page.logged("velocity_open") + ([ref] if ref else [])
    figs = page.path_figure("t2q2", pair, "velocity plan vs " + (ref.label if ref else "IK"))
    oc = page.logged("velocity_open", "velocity_closed")
    if len(oc) == 2:
        figs += page.path_figure("t2q2_closed", oc, "velocity plan, doors open vs closed")
    if page.logged("velocity_closed"):
        figs += page.door_figure("t2q2", page.logged("velocity_closed"),
                                 "velocity plan, doors closed")
    text = page.missing("velocity_open", "ik_10_open", "velocity_closed")
    if page.logged("velocity_open"):
        run = page.runs["velocity_open"]
        lo, hi = _signed_range_mm(run.tracking)
        text += (
            f"<p>Along the arc (after the first 5 % of it) the velocity plan's signed radial "
            f"error stays between {_span(format_number(lo))} and {_span(format_number(hi))} mm, "
            f"a spread of {_span(format_number(hi - lo))} mm"
        )
        if ref is not None:
            ilo, ihi = _signed_range_mm(ref.tracking)
            spread, ispread = hi - lo, ihi - ilo
            text += (
                f"; for {html.escape(ref.label)} it spans {_span(format_number(ilo))} to "
                f"{_span(format_number(ihi))} mm (spread {_span(format_number(ispread))} mm). "
            )
            if spread < ispread:
                text += (
                    "The velocity plan's error is smaller and more consistent along the arc, as "
                    "the seed's hint says: there are no knots, the error is corrected "
                    "continuously, and what remains varies slowly (the inner loop's lag and the "
                    "arm's changing configuration).</p>"
                )
            else:
                text += (
                    '</p><p class="contradiction">This contradicts the seed\'s hint: the '
                    "velocity plan's error along the arc does not vary less than that of "
                    f"{html.escape(ref.label)} here.</p>"
                )
        else:
            text += ".</p>"
    if page.logged("velocity_closed"):
        text += _closed_sentence(page, "velocity_closed", "velocity_open")
        text += page.status_note("velocity_closed")
    return figs, text


def _answer_t3q1(page: _Page) -> tuple[str, str]:
    ref = _reference_ik(page)
    names = ("impedance_open", "velocity_open", ref.name if ref else "ik_10_open")
    runs = page.logged(*names)
    figs = page.tracking_figures("t3q1", runs, "the three controllers, doors open")
    text = page.missing(*names)
    if page.logged("impedance_open") and len(runs) >= 2:
        ranked = sorted(runs, key=lambda r: page.value(r.name, "max_radial_error_m") or math.inf)
        text += (
            "<p>Ranked by max radial error, doors open: "
            + " &lt; ".join(
                f"{html.escape(r.label)} ({page.num(r.name, 'max_radial_error_m')})" for r in ranked
            )
            + ". By RMS: "
            + ", ".join(
                f"{html.escape(r.label)} {page.num(r.name, 'rms_radial_error_m')}" for r in runs
            )
            + ". By max orientation error: "
            + ", ".join(
                f"{html.escape(r.label)} {page.num(r.name, 'max_orientation_error_rad')}"
                for r in runs
            )
            + ".</p>"
        )
        imp = page.runs["impedance_open"]
        kv = imp.scenario.impedance.kv if imp.scenario else float("nan")
        e = page.value("impedance_open", "max_radial_error_m")
        if e is not None:
            text += (
                "<p>The impedance plan commands no joint positions along the path (q_ref = the "
                "measured q) and no feedforward for the motion: Q is pulled towards its moving "
                "reference only by a Cartesian spring of K<sub>v</sub> = "
                f"{_span(format_number(kv))} N/m, which has to drag the arm against the inner "
                "loop's joint damping (D<sub>q</sub> q&#775;, and the stiffness term acting on a "
                "q_ref one control period old). So Q lags its reference and drifts "
                f"{_side(imp.tracking)} the arc: the max error of "
                f"{page.num('impedance_open', 'max_radial_error_m')} is a spring force of about "
                f"{_span(format_number(kv * e))} N. The position-commanding plans do not need a "
                "force to move, so their error does not scale with 1/K<sub>v</sub>.</p>"
            )
        text += page.status_note(*names)
    return figs, text


def _answer_t3q2(page: _Page) -> tuple[str, str]:
    pair = page.logged("impedance_open", "impedance_closed")
    figs = page.tracking_figures("t3q2", pair, "impedance plan, doors open vs closed")
    closed_all = page.logged("ik_10_closed", "velocity_closed", "impedance_closed")
    figs += page.door_figure("t3q2", closed_all, "doors closed, the three controllers")
    figs += page.torque_figure("t3q2", pair, "impedance plan, doors open vs closed")
    text = page.missing("impedance_open", "impedance_closed")
    if page.logged("impedance_closed"):
        text += _closed_sentence(page, "impedance_closed", "impedance_open", explain=False)
        a = page.value("impedance_closed", "max_radial_error_m")
        b = page.value("impedance_open", "max_radial_error_m")
        if a is not None and b is not None:
            effect = "raises" if a > b else ("lowers" if a < b else "does not change")
            text += (
                f"<p>So closing the door {effect} the impedance plan's max radial error "
                f"({page.num('impedance_open', 'max_radial_error_m')} open, "
                f"{page.num('impedance_closed', 'max_radial_error_m')} closed). "
            )
            if page.value("impedance_closed", "slip_time_s") is not None:
                text += (
                    "But the handle slipped out of the gripper during the closed-door run, so "
                    "this comparison does not isolate the door's effect.</p>"
                )
            elif a < b:
                lag = _door_lag_deg(page.runs["impedance_closed"])
                text += (
                    "With the doors open the soft spring lets Q drift off the arc while it "
                    "lags; with the door closed the hinge holds the handle, and so Q, on the "
                    "circle, and the same lag appears along the arc instead: the door trails the "
                    f"plan by up to {_span(format_number(lag))} deg (door angle plot), while the "
                    "orientation error "
                    + ("grows" if (page.value("impedance_closed", "max_orientation_error_rad") or 0)
                       > (page.value("impedance_open", "max_orientation_error_rad") or 0)
                       else "does not grow")
                    + ". The radial error measures only the distance from the circle.</p>"
                )
            else:
                text += (
                    "With a soft task-space spring, the force the door needs at the handle "
                    "(its inertia and hinge damping) shows up as position error, force = "
                    "K<sub>v</sub> &times; error.</p>"
                )
        others = [r for r in closed_all if r.name != "impedance_closed"]
        if others:
            text += (
                "<p>Doors closed, all controllers: "
                + ", ".join(
                    f"{html.escape(r.label)} {page.num(r.name, 'max_radial_error_m')} max radial "
                    f"error, door at the arc's end {page.num(r.name, 'door_opening_arc_end_rad')}"
                    for r in closed_all
                )
                + ".</p>"
            )
        text += _contact_paragraph(page)
        text += _damping_paragraph(page.runs["impedance_closed"])
        text += page.status_note("impedance_closed", "impedance_open")
    return figs, text


def _damping_paragraph(run: _Run) -> str:
    """The inner loop's damping behind the impedance plan's lag (issue 12's trade-off)."""
    from doorlab.metrics import joint_damping_ratios

    if run.result is None or run.scenario is None:
        return ""
    i0 = int(np.argmin(np.abs(run.result.t - run.result.arc_window[0])))
    zeta = joint_damping_ratios(run.scenario, run.result.q_measured[i0])
    if zeta is None:
        return (
            "<p>This run used the original station's inverse-dynamics PID: with q_ref = q its "
            "derivative term damps almost nothing, so the impedance plan's J<sup>T</sup> F "
            "meets only the arm's inertia.</p>"
        )
    return (
        "<p>Why the door trails: with q_ref = q the stiffness loop's damping D<sub>q</sub> "
        "q&#775; is all that resists the plan's J<sup>T</sup> F. This run's joint damping "
        f"ratios at the grasp are {_span(format_number(float(zeta.min())))}-"
        f"{_span(format_number(float(zeta.max())))} (motors' reflected inertia included); "
        "more damping leaves the door further behind at the arc's end, less lets the "
        "position plans ring. The measured trade-off over D<sub>q</sub> is in the README "
        "(<code>benchmarks/inner_loop_sweep.py</code>, <code>station.inner_loop.dq_scale</code>)."
        "</p>"
    )


def _contact_paragraph(page: _Page) -> str:
    """Why the three controllers press on the closed door as hard as they do (from the logs)."""
    runs = page.logged("ik_10_closed", "velocity_closed", "impedance_closed")
    key = "peak_external_torque_arc_Nm"
    values = [(r, page.value(r.name, key)) for r in runs]
    values = [(r, v) for r, v in values if v is not None]
    if len(values) < 2:
        return ""
    ranked = sorted(values, key=lambda rv: rv[1])
    text = (
        "<p><b>Contact torques.</b> Peak |external joint torque| during the arc, doors closed "
        "(the grasp before the arc, the same for all, is left out): "
        + " &lt; ".join(f"{html.escape(r.label)} {page.num(r.name, key)}" for r, _ in ranked)
        + ". "
    )
    imp = page.runs.get("impedance_closed")
    if imp is None or imp.result is None or imp.tracking is None or imp.geometry is None:
        return text + "</p>"
    lowest = ranked[0][0].name == "impedance_closed"
    text += (
        "The impedance plan is the softest controller, and it does press the lightest. "
        if lowest
        else "The impedance plan is the softest controller, yet it does not press the lightest. "
    )
    # Where the impedance plan pressed hardest: its spring's stretch and twist.
    result, tracking = imp.result, imp.tracking
    norms = np.linalg.norm(result.tau_external[result.window(*result.arc_window)], axis=1)
    i = min(int(np.argmax(norms)), len(tracking.t) - 1)
    p_ref = np.array([imp.geometry.p_WQ_ref(s) for s in tracking.tau])
    stretch = float(np.linalg.norm(tracking.p_WQ[i] - p_ref[i]))
    kv = imp.scenario.impedance.kv if imp.scenario is not None else float("nan")
    kw = imp.scenario.impedance.kw if imp.scenario is not None else float("nan")
    theta = float(tracking.orientation_error[i])
    text += (
        f"At its peak (t = {_span(format_number(float(tracking.t[i])))} s) it trails its "
        f"reference by {_span(format_number(1e3 * stretch))} mm and "
        f"{_span(format_number(float(np.degrees(theta))))} deg, so its task-space spring pulls "
        f"with K<sub>v</sub>&nbsp;|e| = {_span(format_number(kv * stretch))} N and twists with "
        f"K<sub>&omega;</sub>&nbsp;&theta; = {_span(format_number(kw * theta))} N m. "
        "That lag comes from the inner loop's joint damping D<sub>q</sub>, which is all the "
        "spring works against when q_ref = q. "
    )
    if page.value("impedance_open", "max_radial_error_m") is not None:
        text += (
            "Dragged that way in free space, the soft arm drifts "
            f"{page.num('impedance_open', 'max_radial_error_m')} off the handle's circle "
            "(impedance, open); with the door closed the hinge holds Q on the circle instead, "
            "and that holding force is the contact torque. "
        )
    text += (
        "The position-controlled plans (IK, velocity) stay within about a millimetre of the "
        "circle in free space, so the door carries little more than its own inertia and hinge "
        "damping, plus the plan's own mismatch: IK's knots may sit up to 1 mm off the arc, and "
        "the stiff arm pushes that mismatch into the door.</p>"
    )
    return text


_ANSWERS = {
    "t1q1": _answer_t1q1,
    "t1q2": _answer_t1q2,
    "t2q1": _answer_t2q1,
    "t2q2": _answer_t2q2,
    "t3q1": _answer_t3q1,
    "t3q2": _answer_t3q2,
}


def _metrics_table(page: _Page, out_dir: Path) -> str:
    from doorlab.metrics import DoorMetrics

    keys: list[str] = [f.name for f in DoorMetrics.__dataclass_fields__.values()]
    for run in page.runs.values():
        for key in run.metrics:
            if key not in keys and key != "error":
                keys.append(key)
    text_keys = {"controller", "doors", "status"}
    head = '<th class="text">run</th>' + "".join(
        f'<th class="{"text" if k in text_keys else ""}">{html.escape(_metric_header(k))}</th>'
        for k in keys
    )
    rows = []
    for name in page.order:
        run = page.runs[name]
        link = os.path.relpath(run.record.run_dir, out_dir)
        cells = [f'<td class="text"><a href="{html.escape(link)}/">{html.escape(name)}</a></td>']
        for key in keys:
            value = run.metrics.get(key)
            if key == "status":
                css = "status-ok" if value == "ok" else "status-bad"
                shown = html.escape(str(value if value is not None else run.status))
                if run.error:
                    shown += f"<br><small>{html.escape(run.error)}</small>"
                cells.append(f'<td class="text"><span class="{css}">{shown}</span></td>')
            elif isinstance(value, bool):
                cells.append(f"<td>{'yes' if value else 'no'}</td>")
            elif isinstance(value, (int, float)):
                unit, scale = metric_unit(key)
                if key == "knots":
                    cells.append(f"<td>{value}</td>")
                else:
                    cells.append(f"<td>{format_number(value * scale)}</td>")
            elif value is None:
                cells.append("<td>&ndash;</td>")
            else:
                cells.append(f'<td class="text">{html.escape(str(value))}</td>')
        css = "" if run.status == "ok" else (' class="warn"' if run.has_logs else ' class="failed"')
        rows.append(f'<tr data-run="{html.escape(name)}"{css}>' + "".join(cells) + "</tr>")
    return (
        '<div class="scroll wide"><table id="metrics-table"><thead><tr>' + head
        + "</tr></thead><tbody>" + "\n".join(rows) + "</tbody></table></div>\n"
    )


def _runs_table(page: _Page, out_dir: Path) -> str:
    rows = []
    for name in page.order:
        run = page.runs[name]
        folder = os.path.relpath(run.record.run_dir, out_dir)
        replay = Path(run.record.run_dir) / "replay.html"
        replay_link = (
            f'<a href="{html.escape(folder)}/replay.html">3-D replay</a>' if replay.is_file()
            else "&ndash;"
        )
        plots = " ".join(
            f'<a href="{html.escape(folder)}/{p.name}">{p.stem.replace("_", " ")}</a>'
            for p in sorted(Path(run.record.run_dir).glob("*.png"))
        ) or "&ndash;"
        css = "status-ok" if run.status == "ok" else "status-bad"
        elapsed = run.record.elapsed_s
        rows.append(
            f'<tr data-run="{html.escape(name)}">'
            f'<td class="text"><a href="{html.escape(folder)}/">{html.escape(name)}</a></td>'
            f'<td class="text">{html.escape(run.label)}</td>'
            f'<td class="text"><span class="{css}">{html.escape(run.status)}</span>'
            + (f"<br><small>{html.escape(run.error)}</small>" if run.error else "")
            + "</td>"
            f"<td>{format_number(elapsed) if math.isfinite(elapsed) else '&ndash;'}</td>"
            f'<td class="text">{replay_link}</td><td class="text">{plots}</td></tr>'
        )
    return (
        '<table id="runs-table"><thead><tr><th class="text">run</th><th class="text">what</th>'
        '<th class="text">status</th><th>run time [s]</th><th class="text">replay</th>'
        '<th class="text">plots of the run</th></tr></thead><tbody>'
        + "\n".join(rows) + "</tbody></table>\n"
    )


def _overlays(page: _Page) -> str:
    out = []
    for doors in ("open", "closed"):
        runs = [r for r in page.runs.values() if r.has_logs and r.metrics.get("doors") == doors]
        if not runs:
            continue
        what = f"doors {doors}"
        out.append(f"<h3>Doors {doors}</h3>\n")
        out.append(page.tracking_figures(f"overlay_{doors}", runs, what))
        out.append(page.path_figure(f"overlay_{doors}", runs, what))
        out.append(page.door_figure(f"overlay_{doors}", runs, what))
        out.append(page.torque_figure(f"overlay_{doors}", runs, what))
    return "".join(out) or "<p>No run produced logs.</p>\n"


def _drake_version() -> str:
    try:
        return metadata.version("drake")
    except metadata.PackageNotFoundError:
        return "unknown"


def build_page(
    runs: Iterable[RunRecord],
    out_dir: Path,
    *,
    total_wall_time_s: float | None = None,
    jobs: int | None = None,
    title: str = "doorlab: opening the cupboard's left door three ways",
) -> Path:
    """Writes ``index.html``, ``summary.json`` and ``figures/*.png`` from run folders.

    Reads each run's ``metrics.json`` (status, error, metrics), ``log.npz`` and
    ``scenario.yaml``; never simulates. Runs without logs appear with their status and error.

    Args:
        runs: The runs, in page order.
        out_dir: Existing folder to write into (the run folders may be inside it; links to
            them are relative).
        total_wall_time_s: Wall-clock time of the whole report [s], shown in the header.
        jobs: Worker processes used, shown in the header.
        title: Page title.

    Returns:
        The path of ``index.html``.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    records = list(runs)
    kinematics = Kinematics()
    loaded = [_load_run(record, kinematics) for record in records]
    page = _Page(loaded, _Figures(out_dir / "figures"))
    now = datetime.datetime.now().astimezone()
    n_ok = sum(run.status == "ok" for run in loaded)

    sections = []
    for task in (1, 2, 3):
        sections.append(f"<h2>{html.escape(TASK_TITLES[task])}</h2>\n")
        task_questions = [(qid, text) for qid, qtask, text in QUESTIONS if qtask == task]
        for number, (qid, question) in enumerate(task_questions, start=1):
            figs, answer = _ANSWERS[qid](page)
            sections.append(
                f'<section id="{qid}"><h3>Question {task}.{number}</h3>\n'
                f"<blockquote>{html.escape(question)}</blockquote>\n{figs}"
                f'<div class="answer" id="answer-{qid}"><b>Answer (generated from the metrics)'
                f"</b>{answer or '<p>No run needed by this question produced logs.</p>'}</div>"
                "</section>\n"
            )

    failed = [run for run in loaded if run.status != "ok"]
    failure_box = ""
    if failed:
        failure_box = (
            '<p class="status-bad">Runs not ok: '
            + "; ".join(
                f"{html.escape(run.name)}: {html.escape(run.status)}"
                + (f" ({html.escape(run.error)})" if run.error else "")
                for run in failed
            )
            + ".</p>\n"
        )
    wall = (
        f"{format_number(total_wall_time_s)} s" if total_wall_time_s is not None
        else "not measured (page rebuilt from existing run folders)"
    )
    meta_rows = [
        ("drake", _drake_version()),
        ("date", now.isoformat(timespec="seconds")),
        ("machine", f"{os.cpu_count()} cores, {platform.machine()}, {platform.system()} "
                    f"{platform.release()}, Python {platform.python_version()}"),
        ("worker processes", str(jobs) if jobs is not None else "n/a"),
        ("total wall time", wall),
        ("runs", f"{len(loaded)} ({n_ok} ok, {len(loaded) - n_ok} not ok)"),
    ]
    meta = '<table class="meta">' + "".join(
        f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in meta_rows
    ) + "</table>\n"

    body = (
        f"<h1>{html.escape(title)}</h1>\n{meta}{failure_box}"
        "<p>Every run follows the seed's timeline: hold, move to the handle, close the gripper, "
        "then the door-opening arc. Tracking errors are taken over the arc window from the "
        "<em>measured</em> joint positions through forward kinematics (the seed plotted the "
        "commanded ones; both are in the metrics table). Radial error: horizontal distance of Q "
        "from the hinge axis minus the handle radius (positive outside the arc). Orientation "
        "error: the angle between L7's orientation and its reference. Numbers are given to "
        f"{SIGNIFICANT_DIGITS} significant digits.</p>\n"
        "<h2>Runs</h2>\n" + _runs_table(page, out_dir)
        + "".join(sections)
        + "<h2>Metrics of every run</h2>\n"
        "<p>All keys of each run's <code>metrics.json</code>; lengths in mm, angles in deg; "
        "(cmd): from the commanded q_ref instead of the measured q.</p>\n"
        + _metrics_table(page, out_dir)
        + "<h2>Overlays: the controllers on the same axes</h2>\n" + _overlays(page)
    )
    document = (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        f"<title>{html.escape(title)}</title><style>{_CSS}</style></head>\n<body>\n{body}"
        "</body></html>\n"
    )
    index = out_dir / "index.html"
    index.write_text(document, encoding="utf-8")

    summary = {
        "title": title,
        "drake_version": _drake_version(),
        "date": now.isoformat(timespec="seconds"),
        "cpu_count": os.cpu_count(),
        "jobs": jobs,
        "total_wall_time_s": total_wall_time_s,
        "runs": [
            {
                "name": run.name,
                "dir": os.path.relpath(run.record.run_dir, out_dir),
                "elapsed_s": run.record.elapsed_s,
                **run.metrics,
                "status": run.status,
                **({"error": run.error} if run.error else {}),
            }
            for run in loaded
        ],
    }
    _write_json(out_dir / "summary.json", summary)
    return index


def discover_runs(report_dir: Path) -> list[RunRecord]:
    """Run records of an existing report folder (``runs/<name>/``), in experiment order.

    Folders named like :data:`EXPERIMENTS` come first in that order, then any others by name.
    """
    runs_dir = Path(report_dir) / "runs"
    folders = {p.name: p for p in runs_dir.iterdir() if p.is_dir() and not p.name.startswith(".")}
    order = [name for name, _ in EXPERIMENTS if name in folders]
    order += sorted(set(folders) - set(order))
    return [RunRecord(name, folders[name]) for name in order]

