"""The sweep page ``DIR/index.html``: metrics against each axis, heatmaps over each pair of grid
axes, and the table of every run. Built from the results table only (never simulates).
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pandas as pd

from doorlab.episode.plugins import display_name
from doorlab.outputs.pages import (
    Figures,
    format_number,
    machine_rows,
    metric_header,
    metric_unit,
    render,
)
from doorlab.runtime.folders import record_written, remove_written, write_json
from doorlab.sweep.figures import headline_metrics, plot_heatmaps, plot_metrics_vs_axis
from doorlab.sweep.spec import Axis, SweepSpec

TITLE = "doorlab sweep"


def _axis_values(axis: Axis) -> str:
    unit = f" {axis.unit}" if axis.unit else ""
    if axis.values is not None:
        shown = ", ".join(
            format_number(v * axis.display_scale)
            if isinstance(v, (int, float)) and not isinstance(v, bool)
            else str(v)
            for v in axis.values
        )
        return f"{shown}{unit}"
    spacing = "log-uniform" if axis.log else "uniform"
    low, high = axis.low * axis.display_scale, axis.high * axis.display_scale
    return f"{spacing} in [{format_number(low)}, {format_number(high)}]{unit}"


def _cell(value: object, key: str | None = None, axis: Axis | None = None) -> dict:
    return {"status": "", "note": "", **_shown(value, key, axis)}


def _shown(value: object, key: str | None, axis: Axis | None) -> dict:
    if isinstance(value, (list, tuple, np.ndarray)):
        return {
            "value": "[" + ", ".join(format_number(float(v)) for v in value) + "]",
            "text": False,
        }
    if value is None or (not isinstance(value, str) and pd.isna(value)):
        return {"value": "\u2013", "text": False}
    if isinstance(value, bool):
        return {"value": "yes" if value else "no", "text": False}
    if isinstance(value, (int, np.integer)) and axis is None and key is None:
        return {"value": str(int(value)), "text": False}  # the run number
    if isinstance(value, (int, float)):
        scale = axis.display_scale if axis is not None else metric_unit(key or "")[1]
        return {"value": format_number(float(value) * scale), "text": False}
    return {"value": str(value), "text": True}


def _table(frame: pd.DataFrame, spec: SweepSpec, metrics: list[str]) -> dict:
    headers = [
        {"name": "run", "text": False},
        {"name": "controller", "text": True},
        {"name": "doors", "text": True},
    ]
    headers += [{"name": axis.label, "text": False} for axis in spec.axes]
    headers += [{"name": "status", "text": True}]
    headers += [{"name": metric_header(k), "text": False} for k in metrics]
    headers += [{"name": "run time [s]", "text": False}]
    rows = []
    for record in frame.to_dict("records"):
        status = str(record["status"])
        cells = [_cell(record["run"]), _cell(record["controller"]), _cell(record["doors"])]
        cells += [_cell(record[axis.field], axis=axis) for axis in spec.axes]
        cells.append(
            {
                "value": status,
                "text": True,
                "status": "status-ok" if status == "ok" else "status-bad",
                "note": record.get("error") or "",
            }
        )
        cells += [_cell(record.get(k), k) for k in metrics]
        cells.append(_cell(record.get("run_wall_time_s"), "run_wall_time_s"))
        has_metrics = not pd.isna(record.get(metrics[0])) if metrics else True
        css = "" if status == "ok" else ("warn" if has_metrics else "failed")
        rows.append({"run": record["run"], "cells": cells, "css": css})
    return {"headers": headers, "rows": rows}


def build_sweep_page(
    frame: pd.DataFrame,
    spec: SweepSpec,
    out_dir: Path,
    *,
    wall_time_s: float | None = None,
    executor: str | None = None,
    total_runs: int | None = None,
) -> Path:
    """Writes ``index.html``, ``figures/*.png`` and ``sweep.json`` (what was swept) into
    ``out_dir``.

    Args:
        frame: The results table. spec: The sweep. out_dir: Existing folder.
        wall_time_s: Wall-clock time of this invocation [s] (header).
        executor: Where the runs ran (header). total_runs: Runs the sweep plans (header).

    Returns:
        The path of ``index.html``.
    """
    out_dir = Path(out_dir)
    figures_dir = out_dir / "figures"
    remove_written(out_dir, "figures")  # the last page's figures; a user's files there stay
    figures = Figures(figures_dir)
    metrics = headline_metrics(frame)
    connect = spec.is_grid or len(spec.axes) == 1
    sections = []
    for i, axis in enumerate(spec.axes):
        if frame.empty:
            break
        fig = plot_metrics_vs_axis(frame, axis, metrics, connect=connect)
        other = [a.field for a in spec.axes if a is not axis]
        how = (
            f"a line per controller and door state through the median over {', '.join(other)} "
            "(dots: the single runs)"
            if other and connect
            else "a line per controller and door state"
            if connect
            else "a dot per run"
        )
        caption = (
            f"Headline metrics against {axis.label}: {how}; x: a run that finished not ok "
            "(e.g. slipped), triangle at the bottom: a run without metrics (ik_failed, "
            "diverged, safety_stop, error)."
        )
        sections.append({"title": axis.label, "figure": figures.add(f"axis_{i}", fig, caption)})
    heatmaps = []
    grid_axes = [a for a in spec.axes if a.values is not None and len(a.values) > 1]
    if spec.is_grid and not frame.empty:
        for x_axis, y_axis in itertools.combinations(grid_axes, 2):
            fig = plot_heatmaps(frame, x_axis, y_axis, metrics)
            name = f"heatmap_{x_axis.field}_{y_axis.field}".replace(".", "_")
            caption = (
                f"{y_axis.label} against {x_axis.label}: each headline metric, a row per "
                "controller and door state (median over any other axes); a red x marks a "
                "cell with a run that is not ok."
            )
            heatmaps.append(figures.add(name, fig, caption))

    counts = frame["status"].value_counts() if not frame.empty else pd.Series(dtype=int)
    total = total_runs if total_runs is not None else len(frame)
    meta = [
        *machine_rows(),
        ("executor", executor or "n/a"),
        ("wall time", f"{format_number(wall_time_s)} s" if wall_time_s is not None else "n/a"),
        (
            "runs",
            f"{len(frame)} of {total} in the table ("
            + ", ".join(f"{n} {s}" for s, n in counts.items())
            + ")",
        ),
    ]
    failed = frame[frame["status"] != "ok"]
    failures = "; ".join(
        f"run {r['run']} ({r['controller']}, {r['doors']}): {r['status']}"
        for r in failed.head(12).to_dict("records")
    ) + (f"; and {len(failed) - 12} more" if len(failed) > 12 else "")
    design = (
        "the full grid"
        if spec.is_grid
        else f"{spec.samples} random draws (seed {spec.seed}) of the axes"
    )
    document = render(
        "sweep.html.j2",
        title=TITLE,
        meta=meta,
        failures=failures if len(failed) else "",
        design=design,
        axes=[{"name": a.label, "shown": _axis_values(a)} for a in spec.axes],
        controllers=", ".join(display_name(c) for c in spec.controllers),
        doors=", ".join(spec.doors),
        axis_sections=sections,
        heatmaps=heatmaps,
        table=_table(frame, spec, metrics),
    )
    index = out_dir / "index.html"
    index.write_text(document, encoding="utf-8")
    write_json(
        out_dir / "sweep.json",
        {
            "controllers": spec.controllers,
            "doors": spec.doors,
            "samples": spec.samples,
            "seed": spec.seed,
            "axes": [
                {
                    "field": a.field,
                    "values": list(a.values) if a.values is not None else None,
                    "low": a.low,
                    "high": a.high,
                    "log": a.log,
                    "unit": a.unit,
                }
                for a in spec.axes
            ],
        },
    )
    record_written(out_dir, [index, out_dir / "sweep.json", *figures.paths])
    return index
