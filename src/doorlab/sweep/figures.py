"""Figures of a sweep, from its results table (no simulation): metrics against each axis, and
heatmaps over each pair of grid axes. Functions take the table and return matplotlib figures.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.transforms import blended_transform_factory

from doorlab.sweep.spec import Axis

HEADLINE_METRICS = (
    "door_opening_arc_end_rad",
    "peak_external_torque_arc_Nm",
    "max_radial_error_m",
    "max_orientation_error_rad",
)
"""The metrics the sweep page plots (the table has all of them), first is the primary."""

METRIC_TITLES = {
    "door_opening_arc_end_rad": "door opened at the arc's end",
    "door_lag_max_rad": "largest door lag behind the plan",
    "door_opening_rad": "door opened at the episode's end",
    "final_door_angle_rad": "final left hinge angle",
    "peak_external_torque_arc_Nm": "peak |external torque| in the arc",
    "max_radial_error_m": "max radial error of Q",
    "max_orientation_error_rad": "max orientation error of L7",
}

GROUP_COLORS = (
    "tab:blue",
    "tab:red",
    "tab:green",
    "tab:purple",
    "tab:orange",
    "tab:brown",
    "tab:pink",
    "tab:olive",
    "tab:cyan",
    "tab:gray",
)
FAILED_MARKER = {"marker": "x", "color": "black", "s": 46, "linewidths": 1.6, "zorder": 5}


def metric_display(key: str) -> tuple[str, float]:
    """(unit, scale) a metric is shown in: lengths in mm, angles in deg."""
    from doorlab.outputs.pages import metric_unit

    return metric_unit(key)


def metric_label(key: str) -> str:
    """Axis label of a metric, e.g. ``door opened during the arc [deg]``."""
    unit, _ = metric_display(key)
    title = METRIC_TITLES.get(key, key.replace("_", " "))
    return f"{title} [{unit}]" if unit else title


def headline_metrics(frame: pd.DataFrame) -> list[str]:
    """The headline metrics present in the table."""
    return [k for k in HEADLINE_METRICS if k in frame.columns]


def groups(frame: pd.DataFrame) -> list[tuple[str, str]]:
    """(controller, doors) pairs of the table, in table order."""
    pairs = frame[["controller", "doors"]].astype(str).drop_duplicates()
    return list(pairs.itertuples(index=False, name=None))


def _numeric(values: Sequence) -> bool:
    return all(
        isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
        for v in values
    )


def _positions(axis: Axis, column: pd.Series) -> tuple[np.ndarray, list[str] | None]:
    """x positions of a column's values, and tick labels for a categorical axis."""
    values = list(column)
    if _numeric(values):
        return np.asarray(values, float) * axis.display_scale, None
    categories = [_key(v) for v in (axis.values or values)]
    categories = list(dict.fromkeys(categories))
    return np.array([categories.index(_key(v)) for v in values], float), categories


def plot_metrics_vs_axis(
    frame: pd.DataFrame, axis: Axis, metrics: Sequence[str], *, connect: bool = True
) -> Figure:
    """Each metric against one axis: a line per controller and door state (the median over
    the other axes, their runs as dots), failed runs marked x (at the bottom if they have no
    metrics).

    Args:
        frame: The results table. axis: The axis. metrics: Metric columns, one panel each.
        connect: Draw lines (a grid, or random draws of one axis); else points only.
    """
    cols = min(len(metrics), 2)
    rows = math.ceil(len(metrics) / cols)
    fig = Figure(figsize=(6.0 * cols, 3.6 * rows), layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    x_all, categories = _positions(axis, frame[axis.field])
    frame = frame.assign(_x=x_all)
    failed = frame["status"] != "ok"
    for ax, key in zip(axes, metrics, strict=False):
        unit, scale = metric_display(key)
        y_all = frame[key].astype(float) * scale
        for i, (controller, doors) in enumerate(groups(frame)):
            color = GROUP_COLORS[i % len(GROUP_COLORS)]
            mine = (frame["controller"] == controller) & (frame["doors"] == doors)
            ls = "--" if doors == "closed" else "-"
            ok = mine & ~failed & y_all.notna()
            label = f"{controller}, doors {doors}"
            points = pd.DataFrame({"x": frame["_x"][mine], "y": y_all[mine]}).dropna()
            if len(points):
                line = points.groupby("x")["y"].median().sort_index()
                if connect:
                    ax.plot(
                        line.index,
                        line.values,
                        ls,
                        color=color,
                        marker="o",
                        ms=4,
                        lw=1.5,
                        label=label,
                    )
                else:
                    ax.scatter([], [], color=color, label=label)
                if len(points) > len(line) or not connect:
                    ax.scatter(points["x"], points["y"], s=10, color=color, alpha=0.35)
            elif not ok.any():
                ax.plot([], [], ls, color=color, label=f"{label} (no metrics)")
        bad = failed & y_all.notna()
        if bad.any():
            ax.scatter(frame["_x"][bad], y_all[bad], label="not ok (slipped, ...)", **FAILED_MARKER)
        lost = failed & y_all.isna()
        if lost.any():
            transform = blended_transform_factory(ax.transData, ax.transAxes)
            ax.scatter(
                frame["_x"][lost],
                np.full(int(lost.sum()), 0.06),
                transform=transform,
                marker="v",
                color="black",
                s=40,
                zorder=5,
                label="no metrics (ik_failed, diverged, safety_stop, error)",
            )
        if categories is not None:
            ax.set_xticks(range(len(categories)), categories)
        elif axis.log:
            ax.set_xscale("log")
        ax.set_xlabel(axis.label)
        ax.set_ylabel(metric_label(key))
        ax.grid(True, alpha=0.3)
    for ax in axes[len(metrics) :]:
        ax.set_visible(False)
    handles, labels = axes[0].get_legend_handles_labels()
    for ax in axes[1 : len(metrics)]:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(
        handles, labels, loc="outside lower center", ncols=min(len(labels), 3), fontsize="small"
    )
    fig.suptitle(f"Headline metrics against {axis.label}")
    return fig


def plot_heatmaps(
    frame: pd.DataFrame, x_axis: Axis, y_axis: Axis, metrics: Sequence[str]
) -> Figure:
    """Heatmaps of each metric over a pair of grid axes: a row per controller and door state,
    a column per metric; the median over any other axes; x marks a cell with a failed run.
    """
    pairs = groups(frame)
    fig = Figure(figsize=(4.2 * len(metrics), 3.4 * len(pairs) + 0.6), layout="constrained")
    axes = fig.subplots(len(pairs), len(metrics), squeeze=False)
    xs = [repr(v) for v in x_axis.values]
    ys = [repr(v) for v in y_axis.values]
    keys = frame.assign(_xk=frame[x_axis.field].map(_key), _yk=frame[y_axis.field].map(_key))
    for r, (controller, doors) in enumerate(pairs):
        mine = keys[(keys["controller"] == controller) & (keys["doors"] == doors)]
        for c, key in enumerate(metrics):
            ax = axes[r, c]
            unit, scale = metric_display(key)
            grid = np.full((len(ys), len(xs)), np.nan)
            bad = np.zeros_like(grid, dtype=bool)
            for (xv, yv), cell in mine.groupby(["_xk", "_yk"]):
                if xv not in xs or yv not in ys:
                    continue
                i, j = ys.index(yv), xs.index(xv)
                values = cell[key].astype(float) * scale
                grid[i, j] = float(values.median()) if values.notna().any() else np.nan
                bad[i, j] = bool((cell["status"] != "ok").any())
            image = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis")
            fig.colorbar(image, ax=ax, label=f"[{unit}]" if unit else None, shrink=0.9)
            small = len(xs) * len(ys) <= 64
            for i in range(len(ys)):
                for j in range(len(xs)):
                    if bad[i, j]:
                        ax.text(
                            j,
                            i,
                            "x",
                            ha="center",
                            va="center",
                            color="red",
                            fontsize=14,
                            fontweight="bold",
                        )
                    elif small and np.isfinite(grid[i, j]):
                        bright = image.norm(grid[i, j]) > 0.6  # viridis is light on top
                        ax.text(
                            j,
                            i,
                            f"{grid[i, j]:.3g}",
                            ha="center",
                            va="center",
                            color="black" if bright else "white",
                            fontsize=7,
                        )
            ax.set_xticks(range(len(xs)), [_tick(x_axis, v) for v in x_axis.values], fontsize=7)
            ax.set_yticks(range(len(ys)), [_tick(y_axis, v) for v in y_axis.values], fontsize=7)
            ax.set_xlabel(x_axis.label, fontsize=8)
            ax.set_ylabel(y_axis.label, fontsize=8)
            title = METRIC_TITLES.get(key, key)
            ax.set_title(f"{controller}, {doors}: {title}", fontsize=8)
    fig.suptitle(f"{y_axis.field} x {x_axis.field} (x: a run not ok)")
    return fig


def _key(value: object) -> str:
    """A hashable key of an axis value (list values come back from Parquet as arrays)."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        value = value.item()
    return repr(value)


def _tick(axis: Axis, value: object) -> str:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return f"{value * axis.display_scale:.3g}"
    return str(value)
