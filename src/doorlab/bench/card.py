"""The benchmark card: ``bench.json`` (the numbers) and ``index.html`` (one self-contained page:
the definition, the distribution, the table, the figures), from the benchmark's table only.

``bench.json``'s keys: ``bench`` (episodes, random seed, controllers and their specs),
``definition`` (success and failure, in words and thresholds), ``distribution`` (its fields and,
in words, ``draws``), ``base_scenario`` (YAML: every field an episode does not draw),
``controllers`` (per controller: ``episodes``, ``successes``, ``success_rate``, ``ci95`` as
[low, high], ``robosuite`` the same under robosuite's definition, ``failures`` by kind,
``statuses``, ``metrics``: each distribution's ``n``, ``mean``, ``q05`` .. ``q95`` in SI units),
and ``cost`` and ``machine`` (how long it took, on what). Every key but ``cost`` and ``machine``
depends on the random seed, the distribution, the base and the controllers only: the same
whatever the jobs, the executor or the machine's load.
"""

from __future__ import annotations

import math
import os
import platform
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from doorlab.bench.measures import (
    FAILURE_KINDS,
    OPEN_TOLERANCE_DEG,
    ROBOSUITE_OPEN_RAD,
    classify,
)
from doorlab.bench.stats import METRICS, QUANTILES

BENCH_JSON = "bench.json"
INDEX_HTML = "index.html"
FIGURES = "figures"
TITLE = "doorlab bench: opening a cupboard door, every controller on the same cupboards"
DISPLAY = {"m": ("mm", 1e3), "rad": ("deg", 180.0 / math.pi), "N": ("N", 1.0), "s": ("s", 1.0)}
"""How the card shows SI units (bench.json keeps SI)."""
KIND_COLORS = {
    None: "tab:green",
    "short": "tab:orange",
    "slip": "tab:red",
    "stop": "tab:purple",
    "error": "black",
}


def definition(threshold_deg: float) -> dict:
    """What success and failure mean (bench.json's ``definition``)."""
    return {
        "success": (
            "the run ended ok (no slip, no safety stop, no joint over its data-sheet speed, no "
            "error), the handle is between the fingers at the episode's end, and the door "
            f"stands open at least the arc's angle less {OPEN_TOLERANCE_DEG:g} deg "
            f"({threshold_deg:.1f} deg) at the episode's end"
        ),
        "open_tolerance_deg": OPEN_TOLERANCE_DEG,
        "open_threshold_deg": threshold_deg,
        "robosuite": (
            f"the hinge exceeded {ROBOSUITE_OPEN_RAD:g} rad at some logged instant of the episode "
            "(robosuite's Door task, _check_success: hinge_qpos > 0.3)"
        ),
        "robosuite_open_rad": ROBOSUITE_OPEN_RAD,
        "failures": {
            "error": "no episode to judge: IK failed, the physics diverged, the controller "
            "raised, or doorlab's worker failed",
            "stop": "a safety stop, or a joint over its data-sheet speed",
            "slip": "the handle left the fingers",
            "short": "the handle held, the door short of the angle at the episode's end",
        },
        "interval": "Wilson's score interval, 95 %",
        "time_to_open": "from the arc's start to the first logged instant the door is open the "
        "success angle (over the episodes that reach it)",
    }


def _shown(key: str, value: float | None) -> str:
    from doorlab.outputs.pages import format_number

    if value is None:
        return "n/a"
    unit, scale = DISPLAY[METRICS[key][1]]
    return format_number(value * scale)


def table_rows(summary: dict[str, dict], cost: dict[str, dict]) -> list[dict]:
    """The card's table: one row per controller, display units."""
    from doorlab.outputs.pages import format_number

    rows = []
    for name, s in summary.items():
        low, high = s["ci95"]
        r_low, r_high = s["robosuite"]["ci95"]
        metrics = {}
        for key in METRICS:
            m = s["metrics"][key]
            metrics[key] = {
                "median": _shown(key, m["q50"]),
                "range": f"{_shown(key, m['q05'])}-{_shown(key, m['q95'])}",
                "n": m["n"],
            }
        seconds = cost.get(name, {}).get("cpu", {}).get("median")
        wall = cost.get(name, {}).get("wall", {}).get("median")
        rows.append(
            {
                "name": name,
                "episodes": s["episodes"],
                "successes": s["successes"],
                "rate": f"{100 * s['success_rate']:.1f} %",
                "ci": f"{100 * low:.1f}-{100 * high:.1f} %",
                "robosuite_rate": f"{100 * s['robosuite']['success_rate']:.1f} %",
                "robosuite_ci": f"{100 * r_low:.1f}-{100 * r_high:.1f} %",
                "failures": [s["failures"][k] for k in FAILURE_KINDS],
                "metrics": metrics,
                "seconds": format_number(seconds) if seconds is not None else "n/a",
                "wall": format_number(wall) if wall is not None else "n/a",
            }
        )
    return rows


def metric_headers() -> list[dict]:
    """The metrics' table headers (display units)."""
    out = []
    for key, (what, unit) in METRICS.items():
        out.append({"key": key, "what": what, "unit": DISPLAY[unit][0]})
    return out


# Figures ------------------------------------------------------------------------------------


def plot_rates(summary: dict[str, dict]):
    """Success rate per controller with its Wilson 95 % interval, both definitions."""
    from matplotlib.figure import Figure

    names = list(summary)
    fig = Figure(figsize=(7.5, 0.55 * len(names) + 1.6))
    ax = fig.add_subplot()
    y = np.arange(len(names))
    for offset, (label, get, color) in enumerate(
        (
            ("doorlab: the arc's angle, handle held, no stop", lambda s: s, "tab:blue"),
            (f"robosuite: hinge > {ROBOSUITE_OPEN_RAD:g} rad", lambda s: s["robosuite"], "0.55"),
        )
    ):
        rates = np.array([get(summary[n])["success_rate"] for n in names])
        ci = np.array([get(summary[n])["ci95"] for n in names])
        pos = y + (0.2 if offset else -0.2)
        ax.barh(pos, 100 * rates, height=0.36, color=color, label=label)
        ax.errorbar(
            100 * rates,
            pos,
            xerr=[100 * (rates - ci[:, 0]), 100 * (ci[:, 1] - rates)],
            fmt="none",
            ecolor="black",
            capsize=3,
            lw=1,
        )
    ax.set_yticks(y, names)
    ax.invert_yaxis()
    ax.set_xlim(0, 100)
    ax.set_xlabel("success rate [%] (bars: 95 % Wilson interval)")
    ax.legend(loc="lower right", fontsize=8)
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    return fig


def plot_failures(summary: dict[str, dict]):
    """Episodes per controller by outcome: success and each failure kind."""
    from matplotlib.figure import Figure

    names = list(summary)
    fig = Figure(figsize=(7.5, 0.45 * len(names) + 1.4))
    ax = fig.add_subplot()
    left = np.zeros(len(names))
    for kind in (None, *FAILURE_KINDS):
        counts = np.array(
            [
                summary[n]["successes"] if kind is None else summary[n]["failures"][kind]
                for n in names
            ],
            dtype=float,
        )
        ax.barh(names, counts, left=left, color=KIND_COLORS[kind], label=kind or "success")
        left += counts
    ax.invert_yaxis()
    ax.set_xlabel("episodes")
    ax.legend(loc="lower right", fontsize=8, ncols=5)
    fig.tight_layout()
    return fig


def plot_distributions(rows: Sequence[dict], names: Sequence[str]):
    """Each metric's distribution per controller: boxes at the quartiles, whiskers at 5 and
    95 % (the table's quantiles), the median a line."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9.0, 6.8))
    axes = fig.subplots(2, 2).ravel()
    for ax, (key, (what, unit)) in zip(axes, METRICS.items(), strict=True):
        shown, scale = DISPLAY[unit]
        data, labels = [], []
        for name in names:
            x = [r.get(key) for r in rows if r.get("controller") == name]
            x = np.array([v for v in x if v is not None and np.isfinite(v)], dtype=float)
            data.append(scale * x if len(x) else np.array([np.nan]))
            labels.append(f"{name}\n(n={len(x)})")
        ax.boxplot(data, whis=(100 * QUANTILES[0], 100 * QUANTILES[-1]), showfliers=False)
        ax.set_xticks(np.arange(1, len(names) + 1), labels, fontsize=7)
        ax.set_title(f"{what} [{shown}]", fontsize=9)
        ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    return fig


def plot_outcomes(rows: Sequence[dict], names: Sequence[str]):
    """Each episode's outcome against the cupboard's yaw error and the hinge's damping."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9.0, 0.5 * len(names) + 2.0))
    axes = fig.subplots(1, 2, sharey=True)
    fields = (
        ("station.cupboard_yaw_error", "cupboard yaw error [deg]", 180.0 / math.pi),
        ("station.hinge_damping", "hinge damping [N m s/rad]", 1.0),
    )
    for ax, (field, label, scale) in zip(axes, fields, strict=True):
        for i, name in enumerate(names):
            mine = [r for r in rows if r.get("controller") == name]
            for kind in (None, *FAILURE_KINDS):
                x = [scale * r[field] for r in mine if classify(r)[2] == kind]
                if x:
                    ax.scatter(x, np.full(len(x), i), s=9, color=KIND_COLORS[kind])
        ax.set_xlabel(label)
        if field == "station.hinge_damping":
            ax.set_xscale("log")
        ax.grid(alpha=0.3)
    axes[0].set_yticks(np.arange(len(names)), names)
    axes[0].invert_yaxis()
    handles = [_dot(KIND_COLORS[kind], kind or "success") for kind in (None, *FAILURE_KINDS)]
    axes[1].legend(handles=handles, fontsize=7, loc="upper right")
    fig.tight_layout()
    return fig


def _dot(color: str, label: str):
    from matplotlib.lines import Line2D

    return Line2D([], [], marker="o", ls="", color=color, label=label, markersize=4)


def machine() -> dict:
    """The machine (bench.json's ``machine``)."""
    from doorlab import __version__
    from doorlab.outputs.pages import drake_version

    return {
        "doorlab": __version__,
        "drake": drake_version(),
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
        "platform": f"{platform.system()} {platform.release()} {platform.machine()}",
    }


def write_card(out_dir: Path, document: dict, rows: Sequence[dict]) -> list[Path]:
    """Writes ``index.html`` (atomically) and ``figures/*.png`` from ``bench.json``'s
    ``document`` and the table's rows, each recorded in the folder's manifest as it is written
    (however the card ends, a ``--resume`` may replace them); returns the files written."""
    from doorlab.outputs.pages import Figures
    from doorlab.runtime.folders import record_written

    figures = Figures(out_dir / FIGURES)
    written: list[Path] = []
    try:
        written.append(_write_page(out_dir, document, rows, figures))
    finally:
        record_written(out_dir, [*figures.paths, *written])
    return [*written, *figures.paths]


def _write_page(out_dir: Path, document: dict, rows: Sequence[dict], figures) -> Path:
    """The figures and ``index.html``; returns the page's path."""
    from doorlab.outputs.pages import format_number, machine_rows, render

    summary = document["controllers"]
    names = list(summary)
    shown = []
    if summary:
        shown = [
            figures.add(
                "success_rates",
                plot_rates(summary),
                "Success rate of each controller over the same cupboards, with its Wilson 95 % "
                "interval: doorlab's definition (the arc's angle reached, the handle held, no "
                f"stop) and robosuite's (the hinge past {ROBOSUITE_OPEN_RAD:g} rad).",
            ),
            figures.add(
                "outcomes",
                plot_failures(summary),
                "Episodes by outcome: success, and each kind of failure (short: the door short "
                "of the angle; slip: the handle lost; stop: a safety stop; error: no episode).",
            ),
            figures.add(
                "distributions",
                plot_distributions(rows, names),
                "Distributions over the episodes: boxes at the quartiles, whiskers at 5 and 95 "
                "%, the line the median (the table's numbers); n episodes with the metric "
                "(time to open: the episodes that opened).",
            ),
            figures.add(
                "outcomes_by_cupboard",
                plot_outcomes(rows, names),
                "Each episode's outcome against its cupboard's yaw error and its hinge's "
                "damping (the other drawn fields vary too).",
            ),
        ]
    cost = document["cost"]
    bench = document["bench"]
    meta = [
        *machine_rows(),
        ("episodes", f"{bench['episodes']} per controller, random seed {bench['seed']}"),
        ("controllers", ", ".join(names) or "none"),
        ("executor", cost["executor"]),
        (
            "wall time",
            f"{format_number(cost['wall_time_s'])} s for {cost['episodes_run']} episodes run now"
            + (
                f" ({format_number(cost['episodes_per_second_per_core'])} episodes per second "
                "per core)"
                if cost.get("episodes_per_second_per_core")
                else ""
            ),
        ),
    ]
    html = render(
        "bench.html.j2",
        title=TITLE,
        meta=meta,
        definition=document["definition"],
        distribution=document["distribution"]["draws"],
        rows=table_rows(summary, cost["seconds_per_episode"]),
        kinds=FAILURE_KINDS,
        metrics=metric_headers(),
        figures=shown,
        reproduce=document["bench"]["command"],
        specs=bench["specs"],
    )
    index = out_dir / INDEX_HTML
    _atomic_text(index, html)
    return index


def _atomic_text(path: Path, text: str) -> None:
    from doorlab.sweep.results import _atomic

    _atomic(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))
