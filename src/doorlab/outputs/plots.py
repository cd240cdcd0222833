"""Plots of an episode's logs: the problem set's figures, one function per figure.

Every function takes result objects (:class:`~doorlab.episode.result.EpisodeResult`,
:class:`~doorlab.episode.metrics.Tracking`) and RETURNS a :class:`matplotlib.figure.Figure`; none of
them simulates. Figures are built with ``matplotlib.figure.Figure`` directly (no pyplot global
state, no GUI backend), so they are safe in worker processes and tests.

Units on the axes: time [s], positions in the xy plane [m], radial error [mm], orientation
error [deg], joint positions [rad], joint velocities [rad/s], torques [N m], hinge angle [deg].
Where time is on the x axis, the door-opening arc window is shaded (full-episode plots) or its
ends are marked (tracking plots, which cover only the arc window).

Line labels are the keys of the mappings passed in; tests find lines by label.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, LogLocator, MaxNLocator, NullLocator

from doorlab.cell.geometry import DoorGeometry
from doorlab.episode.metrics import Kinematics, Tracking, compute_tracking, hinge_estimate_error
from doorlab.episode.result import EpisodeResult

MM_PER_M = 1000.0
"""Millimetres per metre (radial errors are plotted in mm)."""

DPI = 100
"""Resolution of the saved PNG files [dots per inch]."""

MEASURED_LABEL = "measured q"
COMMANDED_LABEL = "commanded q_ref"
"""Labels of the two curves of the per-run error plots: FK of q_measured and of q_commanded."""

TITLE_Y = 1.0
"""Fixed title height in axes coordinates: matplotlib's automatic title placement measures
every tick label and takes a quarter of the drawing time."""

PNG_COMPRESS_LEVEL = 4
"""zlib level of the PNG files: 4 is about twice as fast as the default 6, files ~5 % larger."""

LOG_FLOOR_MM = 1e-4
"""Smallest |error| drawn on the logarithmic panels [mm] (exact zeros have no logarithm)."""

RUN_PLOT_NAMES = (
    "radial_error",
    "orientation_error",
    "q_path",
    "joint_velocities",
    "external_torques",
    "joint_positions",
    "door_angle",
)
"""PNG files written by :func:`save_run_plots` (``<name>.png``)."""

HINGE_PLOT_NAME = "hinge_estimate_error"
"""The PNG :func:`save_run_plots` adds for a plan that estimates the hinge (the adaptive plan:
its plan log has ``hinge_x``): :func:`plot_hinge_convergence` of the run."""

_SINGLE_MARGINS = {"left": 0.1, "right": 0.98, "top": 0.92, "bottom": 0.11}
_ARC_SPAN_STYLE = {"color": "0.5", "alpha": 0.13, "lw": 0}
_ARC_EDGE_STYLE = {"color": "0.35", "ls": ":", "lw": 1.2}


def _style(styles: Mapping[str, dict] | None, label: str, **defaults) -> dict:
    """Line keyword arguments: ``defaults`` overridden by ``styles[label]``."""
    return {**defaults, **(styles.get(label, {}) if styles else {})}


def _finish(ax: Axes, *, xlabel: str, ylabel: str, legend: bool = True) -> None:
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.4)
    if legend and ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize="small", loc="best")


def _shade_arc(ax: Axes, windows: np.ndarray | list) -> None:
    """Shades each distinct arc window [t0, t1] [s]; the first one gets a legend entry."""
    seen: list[tuple[float, float]] = []
    for t0, t1 in np.atleast_2d(np.asarray(windows, float)):
        key = (round(float(t0), 6), round(float(t1), 6))
        if key in seen:
            continue
        ax.axvspan(t0, t1, label="arc window" if not seen else None, **_ARC_SPAN_STYLE)
        seen.append(key)


def _mark_arc_ends(ax: Axes, curves: Mapping[str, Tracking]) -> None:
    """Dotted vertical lines at the start and end of the arc window(s) [s]."""
    ends = sorted(
        {round(float(t), 6) for tr in curves.values() if len(tr.t) for t in (tr.t[0], tr.t[-1])}
    )
    for i, t in enumerate(ends):
        ax.axvline(t, label="arc start / end" if i == 0 else None, **_ARC_EDGE_STYLE)


def _error_figure(
    curves: Mapping[str, Tracking],
    values,
    *,
    unit: str,
    quantity: str,
    title: str,
    styles: Mapping[str, dict] | None,
) -> Figure:
    """Two panels sharing t: the error (linear, top) and |error| (log scale, bottom)."""
    fig = Figure(figsize=(8.0, 5.6))
    fig.subplots_adjust(left=0.1, right=0.98, top=0.94, bottom=0.09, hspace=0.08)
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=(3, 2))
    for label, tracking in curves.items():
        y = values(tracking)
        (line,) = top.plot(tracking.t, y, label=label, **_style(styles, label, lw=1.4))
        bottom.plot(
            tracking.t,
            np.maximum(np.abs(y), LOG_FLOOR_MM),
            color=line.get_color(),
            ls=line.get_linestyle(),
            lw=1.2,
        )
    for ax in (top, bottom):
        _mark_arc_ends(ax, curves)
    top.axhline(0.0, color="0.3", lw=0.8)
    bottom.set_yscale("log")
    # Decades only, plain labels: minor ticks and mathtext labels cost most of the drawing time.
    bottom.yaxis.set_major_locator(LogLocator(base=10.0, numticks=6))
    bottom.yaxis.set_minor_locator(NullLocator())
    bottom.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    _finish(top, xlabel="", ylabel=f"{quantity} [{unit}]")
    _finish(bottom, xlabel="time t [s]", ylabel=f"|{quantity}| [{unit}], log", legend=False)
    top.set_title(title, y=TITLE_Y)
    return fig


def plot_radial_error(
    curves: Mapping[str, Tracking],
    *,
    title: str = "Radial tracking error of Q over the arc",
    styles: Mapping[str, dict] | None = None,
) -> Figure:
    """Signed radial error of Q [mm] vs time [s] for several labelled trackings.

    The top panel shows the signed error (positive: Q outside the handle arc), the bottom
    panel its magnitude on a log scale, so curves orders of magnitude apart stay readable.

    Args:
        curves: Label -> tracking over the arc window.
        title: Figure title.
        styles: Optional label -> matplotlib line keyword arguments (e.g. ``{"ls": "--"}``).
    """
    return _error_figure(
        curves,
        lambda tr: MM_PER_M * np.asarray(tr.radial_error),
        unit="mm",
        quantity="radial error",
        title=title,
        styles=styles,
    )


def plot_orientation_error(
    curves: Mapping[str, Tracking],
    *,
    title: str = "Orientation tracking error of L7 over the arc",
    styles: Mapping[str, dict] | None = None,
) -> Figure:
    """Orientation error angle of L7 [deg] vs time [s] for several labelled trackings.

    Args:
        curves: Label -> tracking over the arc window (errors in rad, plotted in deg).
        title: Figure title.
        styles: Optional label -> matplotlib line keyword arguments.
    """
    return _error_figure(
        curves,
        lambda tr: np.degrees(np.asarray(tr.orientation_error)),
        unit="deg",
        quantity="orientation error",
        title=title,
        styles=styles,
    )


def arc_angle_deg(p_WQ: np.ndarray, geometry: DoorGeometry) -> np.ndarray:
    """Angle of Q about the hinge, measured from the closed handle, (n,) [deg].

    0 at the closed door's handle, growing as the left door opens (the door's opening angle
    when Q is on the handle).
    """
    d = geometry.p_W_hinge[:2] - np.asarray(p_WQ)[:, :2]
    return np.degrees(np.arctan2(d[:, 0], d[:, 1]) - geometry.theta0)


def plot_q_path(
    curves: Mapping[str, Tracking],
    geometry: DoorGeometry,
    *,
    title: str = "Position of Q in the xy plane of W",
    styles: Mapping[str, dict] | None = None,
) -> Figure:
    """Q's xy path against the handle arc and the hinge, with a zoom on the deviation.

    Left panel: the paths in W's xy plane [m], equal aspect, the handle arc and the hinge
    (star). Right panel (the zoom): the radial deviation of Q from the arc [mm] against Q's
    angle about the hinge [deg], which shows whether the error is uniform along the arc.

    Args:
        curves: Label -> tracking over the arc window.
        geometry: The door's hinge and handle arc.
        title: Title of the left panel.
        styles: Optional label -> matplotlib line keyword arguments.
    """
    fig = Figure(figsize=(11.0, 4.8))
    fig.subplots_adjust(left=0.07, right=0.99, top=0.93, bottom=0.11, wspace=0.22)
    path_ax, zoom_ax = fig.subplots(1, 2, width_ratios=(1, 1.15))
    arc = geometry.arc_points(200)
    path_ax.plot(arc[:, 0], arc[:, 1], color="0.55", lw=4, alpha=0.6, label="handle arc")
    zoom_ax.axhline(0.0, color="0.55", lw=4, alpha=0.6, label="handle arc")
    for label, tracking in curves.items():
        p = np.asarray(tracking.p_WQ)
        (line,) = path_ax.plot(p[:, 0], p[:, 1], label=label, **_style(styles, label, lw=1.4))
        zoom_ax.plot(
            arc_angle_deg(p, geometry),
            MM_PER_M * np.asarray(tracking.radial_error),
            label=label,
            color=line.get_color(),
            ls=line.get_linestyle(),
            lw=1.4,
        )
    hinge = geometry.p_W_hinge
    path_ax.plot(hinge[0], hinge[1], "*", color="tab:red", markersize=16, label="door hinge")
    path_ax.plot(
        geometry.p_W_handle[0],
        geometry.p_W_handle[1],
        "o",
        color="0.2",
        ms=5,
        label="handle (door closed)",
    )
    path_ax.set_aspect("equal", adjustable="datalim")
    path_ax.set_title(title, y=TITLE_Y)
    _finish(path_ax, xlabel="x_W [m]", ylabel="y_W [m]")
    zoom_ax.set_title("Zoom: radial deviation of Q from the arc", y=TITLE_Y)
    _finish(
        zoom_ax,
        xlabel="angle of Q about the hinge from the closed handle [deg]",
        ylabel="radial error [mm] (+ outside)",
    )
    return fig


def _joint_lines(ax: Axes, t: np.ndarray, values: np.ndarray, *, prefix: str, **kwargs) -> None:
    for j in range(values.shape[1]):
        ax.plot(t, values[:, j], label=f"{prefix}{j + 1}", lw=1.2, **kwargs)


def _episode_axes(result: EpisodeResult, title: str, ylabel: str) -> tuple[Figure, Axes]:
    fig = Figure(figsize=(8.0, 4.5))
    fig.subplots_adjust(**_SINGLE_MARGINS)
    ax = fig.subplots()
    _shade_arc(ax, result.arc_window)
    ax.set_title(title, y=TITLE_Y)
    ax.set_ylabel(ylabel)
    return fig, ax


def plot_joint_velocities(result: EpisodeResult, *, title: str = "Joint velocities") -> Figure:
    """Measured joint velocities of the 7 arm joints [rad/s] vs time [s], arc window shaded."""
    fig, ax = _episode_axes(result, title, "v [rad/s]")
    _joint_lines(ax, result.t, np.asarray(result.v_measured), prefix="joint ")
    _finish(ax, xlabel="time t [s]", ylabel="joint velocity [rad/s]")
    ax.legend(fontsize="small", ncol=4, loc="best")
    return fig


def plot_external_torques(
    result: EpisodeResult, *, title: str = "External (contact) joint torques"
) -> Figure:
    """External joint torques tau_external of the 7 arm joints [N m] vs time [s]."""
    fig, ax = _episode_axes(result, title, "tau_ext [N m]")
    _joint_lines(ax, result.t, np.asarray(result.tau_external), prefix="joint ")
    _finish(ax, xlabel="time t [s]", ylabel="external torque tau_ext [N m]")
    ax.legend(fontsize="small", ncol=4, loc="best")
    return fig


def plot_joint_positions(
    result: EpisodeResult, *, title: str = "Joint positions: commanded (dashed) vs measured"
) -> Figure:
    """Commanded q_ref (dashed) and measured q (solid) [rad] vs time [s], one panel per joint."""
    fig = Figure(figsize=(9.0, 8.0))
    fig.subplots_adjust(left=0.1, right=0.98, top=0.92, bottom=0.06, hspace=0.3, wspace=0.26)
    axes = fig.subplots(4, 2, sharex=True).ravel()
    q_cmd = np.asarray(result.q_commanded)
    q_meas = np.asarray(result.q_measured)
    for j in range(q_meas.shape[1]):
        ax = axes[j]
        _shade_arc(ax, result.arc_window)
        (line,) = ax.plot(result.t, q_meas[:, j], lw=1.3, label=f"measured q{j + 1}")
        ax.plot(
            result.t,
            q_cmd[:, j],
            "--",
            lw=1.3,
            color="k",
            alpha=0.7,
            label=f"commanded q_ref{j + 1}",
        )
        ax.set_title(f"joint {j + 1}", fontsize="medium", y=TITLE_Y)
        ax.yaxis.set_major_locator(MaxNLocator(nbins=4))  # fewer ticks: legible and faster
        _finish(ax, xlabel="time t [s]" if j >= 5 else "", ylabel=f"q{j + 1} [rad]", legend=False)
    axes[5].xaxis.set_tick_params(labelbottom=True)  # its lower neighbour is the legend
    key = axes[-1]
    key.axis("off")
    key.legend(
        handles=[
            axes[0].lines[0],
            axes[0].lines[1],
            axes[0].patches[0] if axes[0].patches else axes[0].lines[0],
        ],
        labels=["measured q (solid)", "commanded q_ref (dashed)", "arc window"],
        loc="center",
    )
    fig.suptitle(title)
    return fig


def plot_door_angle(
    results: Mapping[str, EpisodeResult],
    *,
    geometry: DoorGeometry | None = None,
    title: str = "Left door hinge angle",
    styles: Mapping[str, dict] | None = None,
) -> Figure:
    """Left hinge angle [deg] vs time [s] for several runs (negative = open).

    Args:
        results: Label -> episode.
        geometry: When given, the hinge angle the arc plan asks for (the door following the
            handle arc from closed) is drawn dotted over each distinct arc window.
        title: Figure title.
        styles: Optional label -> matplotlib line keyword arguments.
    """
    fig = Figure(figsize=(8.0, 4.5))
    fig.subplots_adjust(**_SINGLE_MARGINS)
    ax = fig.subplots()
    _shade_arc(ax, [r.arc_window for r in results.values()])
    for label, result in results.items():
        if result.door_angles is None:  # the real cell: no hinge sensor, Q's estimate
            angle, label = result.door_angle_estimated, f"{label} (estimated from Q)"
        else:
            angle = result.door_angles[:, 0]
        ax.plot(result.t, np.degrees(angle), label=label, **_style(styles, label, lw=1.4))
    if geometry is not None and results:
        windows = {tuple(np.round(r.arc_window, 6)) for r in results.values()}
        for i, (t0, t1) in enumerate(sorted(windows)):
            ax.plot(
                [t0, t1],
                [0.0, -math.degrees(geometry.sweep)],
                ":",
                color="k",
                lw=1.2,
                label="arc plan (door from closed)" if i == 0 else None,
            )
    _finish(ax, xlabel="time t [s]", ylabel="left hinge angle [deg] (negative = open)")
    ax.set_title(title, y=TITLE_Y)
    return fig


def plot_external_torque_norm(
    results: Mapping[str, EpisodeResult],
    *,
    title: str = "Norm of the external joint torques",
    styles: Mapping[str, dict] | None = None,
) -> Figure:
    """Euclidean norm of the 7 external joint torques [N m] vs time [s] for several runs.

    Args:
        results: Label -> episode.
        title: Figure title.
        styles: Optional label -> matplotlib line keyword arguments.
    """
    fig = Figure(figsize=(8.0, 4.5))
    fig.subplots_adjust(**_SINGLE_MARGINS)
    ax = fig.subplots()
    _shade_arc(ax, [r.arc_window for r in results.values()])
    for label, result in results.items():
        ax.plot(
            result.t,
            np.linalg.norm(result.tau_external, axis=1),
            label=label,
            **_style(styles, label, lw=1.3),
        )
    _finish(ax, xlabel="time t [s]", ylabel="|tau_ext| [N m]")
    ax.set_title(title, y=TITLE_Y)
    return fig


def plot_hinge_convergence(
    results: Mapping[str, tuple[EpisodeResult, DoorGeometry]],
) -> Figure:
    """The adaptive plan's hinge estimate error against time, one line per episode.

    Args:
        results: {label: (episode of the adaptive plan, its TRUE door geometry)}.

    Returns:
        A matplotlib Figure (log-scale error [mm] against time in the arc [s]).
    """
    fig = Figure(figsize=(7, 4), constrained_layout=True)
    ax = fig.subplots()
    for label, (result, geometry) in results.items():
        error = hinge_estimate_error(result, geometry)
        t = result.plan_log["t"] - result.arc_window[0]
        ax.semilogy(t, 1e3 * error, label=label)
    ax.axhline(10.0, color="k", lw=0.8, ls="--", label="acceptance: 10 mm")
    ax.set(
        xlabel="time since the arc started [s]",
        ylabel="|hinge estimate - true hinge| [mm]",
        title="Adaptive plan: hinge estimate convergence (nan until the fit is trusted)",
    )
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="upper right", fontsize="small")
    return fig


def run_label(result: EpisodeResult) -> str:
    """A short description of the run from its scenario ("ik, 10 knots, doors open")."""
    from pydrake.common.yaml import yaml_load_typed

    from doorlab.config import Scenario

    if not result.scenario_yaml:
        return ""
    try:
        scenario = yaml_load_typed(schema=Scenario, data=result.scenario_yaml)
    except (RuntimeError, ValueError, TypeError):
        return ""
    knots = f", {scenario.ik.knots} knots" if scenario.controller == "ik" else ""
    from doorlab.episode.plugins import display_name

    return f"{display_name(scenario.controller)}{knots}, doors {scenario.doors}"


def save_figure(fig: Figure, path: Path, *, dpi: int = DPI) -> Path:
    """Writes ``fig`` as a PNG; returns ``path``.

    Figures made with ``Figure()`` are not registered anywhere (no pyplot), so dropping the
    last reference frees them: "closing" needs nothing more.
    """
    path = Path(path)
    fig.savefig(path, dpi=dpi, format="png", pil_kwargs={"compress_level": PNG_COMPRESS_LEVEL})
    return path


def save_run_plots(
    result: EpisodeResult,
    geometry: DoorGeometry,
    out_dir: Path,
    *,
    kinematics: Kinematics | None = None,
) -> list[Path]:
    """Writes the problem set's plots of one run as PNG files in ``out_dir``.

    The error and path plots show both the forward kinematics of the measured joint
    positions ("measured q") and of the commanded ones ("commanded q_ref", as the problem set did).

    Args:
        result: The episode's logs.
        geometry: The true door geometry (where the handle really moves).
        out_dir: An existing folder.
        kinematics: Reusable forward kinematics (built if not given).

    Returns:
        The paths written, in the order of :data:`RUN_PLOT_NAMES`, then
        :data:`HINGE_PLOT_NAME` for a plan that estimates the hinge.
    """
    out_dir = Path(out_dir)
    kinematics = kinematics or Kinematics()
    curves = {
        MEASURED_LABEL: compute_tracking(
            result, geometry, source="measured", kinematics=kinematics
        ),
        COMMANDED_LABEL: compute_tracking(
            result, geometry, source="commanded", kinematics=kinematics
        ),
    }
    styles = {COMMANDED_LABEL: {"ls": "--"}}
    label = run_label(result)
    suffix = f" ({label})" if label else ""
    figures = {
        "radial_error": lambda: plot_radial_error(
            curves, styles=styles, title=f"Radial tracking error of Q{suffix}"
        ),
        "orientation_error": lambda: plot_orientation_error(
            curves, styles=styles, title=f"Orientation tracking error of L7{suffix}"
        ),
        "q_path": lambda: plot_q_path(
            curves, geometry, styles=styles, title=f"Q in the xy plane{suffix}"
        ),
        "joint_velocities": lambda: plot_joint_velocities(
            result, title=f"Joint velocities{suffix}"
        ),
        "external_torques": lambda: plot_external_torques(
            result, title=f"External joint torques{suffix}"
        ),
        "joint_positions": lambda: plot_joint_positions(
            result, title=f"Joint positions: commanded (dashed) vs measured{suffix}"
        ),
        "door_angle": lambda: plot_door_angle(
            {label or "left door": result},
            geometry=geometry,
            title=f"Left door hinge angle{suffix}",
        ),
    }
    paths = [save_figure(figures[name](), out_dir / f"{name}.png") for name in RUN_PLOT_NAMES]
    if "hinge_x" in result.plan_log:  # a plan that estimates the hinge (adaptive)
        arc = int(np.argmin(np.abs(result.plan_starts - result.arc_window[0])))
        figure = plot_hinge_convergence({result.plan_names[arc]: (result, geometry)})
        paths.append(save_figure(figure, out_dir / f"{HINGE_PLOT_NAME}.png"))
    return paths
