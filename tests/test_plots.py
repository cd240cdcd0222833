"""Tests of ``doorlab.outputs.plots``: the figures carry the numbers of the results they are given.

Plots are checked by their data (line x/y arrays, labels, units), not by pixels. The episode is
one real short run, simulated once per session (see ``report_fixtures``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure
from report_fixtures import short_result

from doorlab.cell.geometry import default_door_geometry
from doorlab.episode.metrics import Kinematics, compute_tracking
from doorlab.outputs import plots

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MAX_PNG_BYTES = 150_000
"""Size budget of one plot file [bytes] (the report embeds many of them)."""


@pytest.fixture(scope="module")
def episode():
    """(result, scenario, geometry, measured tracking, commanded tracking)."""
    result, scenario = short_result()
    geometry = default_door_geometry(scenario.arc.angle_end_deg)
    kinematics = Kinematics()
    measured = compute_tracking(result, geometry, source="measured", kinematics=kinematics)
    commanded = compute_tracking(result, geometry, source="commanded", kinematics=kinematics)
    return result, scenario, geometry, measured, commanded


def line(ax, label: str):
    """The one line of ``ax`` labelled ``label``."""
    found = [ln for ln in ax.get_lines() if ln.get_label() == label]
    assert len(found) == 1, f"expected one line labelled {label!r}, got {len(found)}"
    return found[0]


def arc_span_matches(ax, window) -> bool:
    """True if ``ax`` has a shaded patch covering exactly the arc window [s]."""
    for patch in ax.patches:
        extents = patch.get_extents()  # display coordinates
        x0, x1 = ax.transData.inverted().transform([[extents.x0, 0], [extents.x1, 0]])[:, 0]
        if np.allclose([x0, x1], window, atol=0.05):
            return True
    return False


def test_radial_error_lines_are_signed_millimetres(episode):
    """Each curve's y data are 1000 x radial_error over the tracking's t; labels carry [mm]."""
    _, _, _, measured, commanded = episode
    fig = plots.plot_radial_error({"a": measured, "b": commanded})
    assert isinstance(fig, Figure)
    top, bottom = fig.axes
    for label, tracking in (("a", measured), ("b", commanded)):
        ln = line(top, label)
        np.testing.assert_allclose(ln.get_xdata(), tracking.t)
        np.testing.assert_allclose(ln.get_ydata(), 1000.0 * tracking.radial_error)
    assert "[mm]" in top.get_ylabel() and "[mm]" in bottom.get_ylabel()
    assert "[s]" in bottom.get_xlabel()
    assert bottom.get_yscale() == "log"
    assert top.get_legend() is not None


def test_orientation_error_lines_are_degrees(episode):
    """Each curve's y data are the orientation error converted from rad to deg; [deg] shown."""
    _, _, _, measured, _ = episode
    fig = plots.plot_orientation_error({"measured": measured})
    top, bottom = fig.axes
    ln = line(top, "measured")
    np.testing.assert_allclose(ln.get_xdata(), measured.t)
    np.testing.assert_allclose(ln.get_ydata(), np.degrees(measured.orientation_error))
    assert "[deg]" in top.get_ylabel() and "[s]" in bottom.get_xlabel()


def test_q_path_shows_path_arc_hinge_and_zoom(episode):
    """xy panel: Q's path, handle arc, hinge, equal aspect; zoom: radial error vs arc angle."""
    _, _, geometry, measured, _ = episode
    fig = plots.plot_q_path({"run": measured}, geometry)
    path_ax, zoom_ax = fig.axes
    ln = line(path_ax, "run")
    np.testing.assert_allclose(ln.get_xdata(), measured.p_WQ[:, 0])
    np.testing.assert_allclose(ln.get_ydata(), measured.p_WQ[:, 1])
    arc = line(path_ax, "handle arc")
    expected_arc = geometry.arc_points(200)
    np.testing.assert_allclose(arc.get_xdata(), expected_arc[:, 0])
    np.testing.assert_allclose(arc.get_ydata(), expected_arc[:, 1])
    hinge = line(path_ax, "door hinge")
    np.testing.assert_allclose([hinge.get_xdata()[0], hinge.get_ydata()[0]], geometry.p_W_hinge[:2])
    assert hinge.get_marker() == "*"
    assert path_ax.get_aspect() == 1.0
    assert "[m]" in path_ax.get_xlabel() and "[m]" in path_ax.get_ylabel()
    zoom = line(zoom_ax, "run")
    np.testing.assert_allclose(zoom.get_ydata(), 1000.0 * measured.radial_error)
    np.testing.assert_allclose(zoom.get_xdata(), plots.arc_angle_deg(measured.p_WQ, geometry))
    assert "[mm]" in zoom_ax.get_ylabel() and "[deg]" in zoom_ax.get_xlabel()


def test_arc_angle_is_zero_at_the_closed_handle_and_sweep_at_the_end(episode):
    """Q's angle about the hinge is 0 deg at the closed handle and the sweep at the arc's end."""
    _, _, geometry, _, _ = episode
    ends = np.array([geometry.p_WQ_ref(0.0), geometry.p_WQ_ref(1.0)])
    np.testing.assert_allclose(
        plots.arc_angle_deg(ends, geometry), [0.0, np.degrees(geometry.sweep)], atol=1e-9
    )


@pytest.mark.parametrize(
    ("function", "channel", "unit"),
    [
        (plots.plot_joint_velocities, "v_measured", "[rad/s]"),
        (plots.plot_external_torques, "tau_external", "[N m]"),
    ],
)
def test_joint_plots_have_seven_joints_and_the_arc_window(episode, function, channel, unit):
    """Joint velocity/torque plots draw the 7 logged channels vs t, with units and arc shaded."""
    result = episode[0]
    fig = function(result)
    (ax,) = fig.axes
    values = getattr(result, channel)
    for j in range(7):
        ln = line(ax, f"joint {j + 1}")
        np.testing.assert_allclose(ln.get_xdata(), result.t)
        np.testing.assert_allclose(ln.get_ydata(), values[:, j])
    assert unit in ax.get_ylabel() and "[s]" in ax.get_xlabel()
    assert arc_span_matches(ax, result.arc_window)


def test_joint_positions_commanded_dashed_measured_solid(episode):
    """One panel per joint: measured q solid, commanded q_ref dashed, both equal to the logs."""
    result = episode[0]
    fig = plots.plot_joint_positions(result)
    joint_axes = [ax for ax in fig.axes if ax.get_lines()][:7]
    assert len(joint_axes) == 7
    for j, ax in enumerate(joint_axes):
        measured = line(ax, f"measured q{j + 1}")
        commanded = line(ax, f"commanded q_ref{j + 1}")
        np.testing.assert_allclose(measured.get_ydata(), result.q_measured[:, j])
        np.testing.assert_allclose(commanded.get_ydata(), result.q_commanded[:, j])
        assert measured.get_linestyle() == "-" and commanded.get_linestyle() == "--"
        assert "[rad]" in ax.get_ylabel()
        assert arc_span_matches(ax, result.arc_window)


def test_door_angle_and_torque_norm_overlay_runs(episode):
    """Overlay plots draw the left hinge angle [deg] and |tau_ext| [N m] of every run given."""
    result, _, geometry, _, _ = episode
    runs = {"first": result, "second": result}
    fig = plots.plot_door_angle(runs, geometry=geometry)
    (ax,) = fig.axes
    for label in runs:
        np.testing.assert_allclose(
            line(ax, label).get_ydata(), np.degrees(result.door_angles[:, 0])
        )
    plan = line(ax, "arc plan (door from closed)")
    np.testing.assert_allclose(plan.get_xdata(), result.arc_window)
    np.testing.assert_allclose(plan.get_ydata(), [0.0, -np.degrees(geometry.sweep)])
    assert "[deg]" in ax.get_ylabel() and "[s]" in ax.get_xlabel()

    fig = plots.plot_external_torque_norm(runs)
    (ax,) = fig.axes
    np.testing.assert_allclose(
        line(ax, "first").get_ydata(), np.linalg.norm(result.tau_external, axis=1)
    )
    assert "[N m]" in ax.get_ylabel()
    assert arc_span_matches(ax, result.arc_window)


def test_styles_override_line_properties(episode):
    """A ``styles`` entry sets the colour and line style of the curve with that label."""
    _, _, _, measured, _ = episode
    fig = plots.plot_radial_error(
        {"x": measured}, styles={"x": {"color": "tab:red", "ls": "--", "lw": 3.0}}
    )
    ln = line(fig.axes[0], "x")
    assert ln.get_linestyle() == "--" and ln.get_linewidth() == 3.0
    assert ln.get_color() == "tab:red"


def test_save_run_plots_writes_small_valid_pngs(episode, tmp_path: Path):
    """save_run_plots writes every listed PNG (valid signature, non-empty, < 150 kB)."""
    result, _, geometry, _, _ = episode
    paths = plots.save_run_plots(result, geometry, tmp_path)
    assert [p.name for p in paths] == [f"{name}.png" for name in plots.RUN_PLOT_NAMES]
    for path in paths:
        data = path.read_bytes()
        assert data.startswith(PNG_SIGNATURE), path
        assert 1_000 < len(data) < MAX_PNG_BYTES, (path, len(data))
