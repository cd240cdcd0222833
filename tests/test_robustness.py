"""The robustness analysis from rows (no simulation): success rule, table, figure, findings."""

from __future__ import annotations

import math

import numpy as np
import pytest

from doorlab.config import Scenario
from doorlab.errors import ConfigError
from doorlab.studies.robustness import (
    RobustnessRow,
    case_scenario,
    plot_robustness,
    robustness_findings,
    robustness_table,
    row_from_metrics,
)


def row(controller, yaw_deg, *, status="ok", door_deg=41.0, held=True, torque=1.0, hinge=None):
    return RobustnessRow(
        controller=controller,
        yaw_error_rad=math.radians(yaw_deg),
        status=status,
        door_opening_rad=math.radians(door_deg),
        door_opening_final_rad=math.radians(door_deg + 0.5),
        handle_held=held,
        peak_contact_torque_arc_Nm=torque,
        peak_contact_force_arc_N=2.0 * torque,
        max_radial_error_m=0.001,
        hinge_estimate_error_m=hinge,
    )


ROWS = [
    row("velocity", -10, status="slipped", held=False, torque=3.5),
    row("velocity", 0, torque=0.5),
    row("velocity", 10, door_deg=38.0, torque=5.0),
    row("adaptive", -10, torque=0.4, hinge=0.004),
    row("adaptive", 0, torque=0.3, hinge=0.002),
    row("adaptive", 10, torque=0.35, hinge=0.0005),
]


def test_opened_needs_status_ok_the_handle_and_39_degrees():
    assert row("x", 0).opened
    assert not row("x", 0, status="slipped").opened
    assert not row("x", 0, held=False).opened
    assert not row("x", 0, door_deg=38.9).opened
    assert not row("x", 0, door_deg=float("nan")).opened


def test_table_has_one_line_per_row_with_the_measured_values():
    lines = robustness_table(ROWS).splitlines()
    assert len(lines) == 2 + len(ROWS)
    assert "| velocity | -10.0 | slipped | 41.0 / 41.5 | no | 3.50 | 7.00 | 1.0 | - |" in lines
    assert "| adaptive | +10.0 | ok | 41.0 / 41.5 | yes | 0.35 | 0.70 | 1.0 | 0.5 |" in lines


def test_figure_plots_the_rows_sorted_by_yaw():
    fig = plot_robustness(list(reversed(ROWS)))
    door_axes, torque_axes = fig.axes
    lines = {line.get_label(): line for line in torque_axes.get_lines()}
    assert np.allclose(lines["adaptive"].get_xdata(), [-10, 0, 10])
    assert np.allclose(lines["adaptive"].get_ydata(), [0.4, 0.3, 0.35])
    assert np.allclose(lines["velocity"].get_ydata(), [3.5, 0.5, 5.0])


def test_findings_name_where_each_controller_opens():
    velocity, adaptive = robustness_findings(ROWS)
    assert velocity.startswith("velocity: opens the door at yaw errors +0 deg, not at -10")
    assert "+10 (38.0 deg by the arc's end)" in velocity
    (stuck,) = robustness_findings([row("impedance", 0, door_deg=31.0)])
    assert stuck == (
        "impedance: opens the door at none of them (+0 (31.0 deg by the arc's end)); "
        "peak contact torque in the arc 1.00-1.00 N m."
    )
    assert "0.50-5.00 N m" in velocity
    assert adaptive.startswith("adaptive: opens the door at yaw errors -10, +0, +10 deg;")
    assert "within 4.0 mm" in adaptive


def test_case_scenario_sets_the_case_and_validates():
    scenario = case_scenario(Scenario(doors="open"), "adaptive", math.radians(5))
    assert (scenario.controller, scenario.doors) == ("adaptive", "closed")
    assert scenario.station.cupboard_yaw_error == pytest.approx(math.radians(5))
    with pytest.raises(ConfigError, match="cupboard_yaw_error"):
        case_scenario(Scenario(), "adaptive", math.radians(60))


def test_rows_from_metrics_json_match_the_metrics():
    """A run folder's metrics.json gives the same row (the report re-runs nothing); a failed
    run's short metrics give NaNs and its status."""
    metrics = {
        "controller": "adaptive",
        "status": "ok",
        "door_opening_arc_end_rad": 0.71,
        "door_opening_rad": 0.712,
        "handle_held": True,
        "peak_external_torque_arc_Nm": 0.3,
        "peak_contact_force_arc_N": 0.7,
        "max_radial_error_m": 2e-4,
        "hinge_estimate_error_m": 1e-3,
    }
    r = row_from_metrics(metrics, 0.1)
    assert (r.door_opening_rad, r.door_opening_final_rad) == (0.71, 0.712)
    assert r.opened and r.hinge_estimate_error_m == 1e-3 and r.yaw_error_rad == 0.1
    failed = row_from_metrics({"controller": "ik", "status": "ik_failed", "error": "x"}, 0.5)
    assert failed.status == "ik_failed" and not failed.opened
    assert math.isnan(failed.door_opening_rad) and failed.hinge_estimate_error_m is None


def test_largest_yaw_scans_to_the_first_failure_then_bisects(monkeypatch):
    """With a stand-in for the simulation that opens for |yaw| < 13.7 deg and again from
    40 deg, the scan (from 10 deg in 2.5 deg steps) stops at the first failure, 15 deg, and
    bisection brackets 13.7 deg to the tolerance; the island of success further out is not
    reported."""
    import doorlab.studies.robustness as robustness

    calls = []

    def fake_run_case(base, controller, yaw):
        calls.append(yaw)
        opens = abs(math.degrees(yaw)) < 13.7 or abs(math.degrees(yaw)) >= 40
        return row(controller, math.degrees(yaw), door_deg=41.0 if opens else 20.0), None

    monkeypatch.setattr(robustness, "run_case", fake_run_case)
    found = robustness.largest_opening_yaw(
        Scenario(), "velocity", -1, opened_rad=math.radians(10), tolerance_rad=math.radians(0.5)
    )
    assert math.degrees(found.opened_rad) < 13.7 <= math.degrees(found.failed_rad)
    assert found.failed_rad - found.opened_rad <= math.radians(0.5)
    assert all(y < 0 for y in calls) and found.runs == len(calls)
    assert max(abs(math.degrees(y)) for y in calls) == pytest.approx(15.0)


def test_largest_yaw_reports_the_cap_when_nothing_fails(monkeypatch):
    import doorlab.studies.robustness as robustness

    monkeypatch.setattr(
        robustness, "run_case", lambda base, c, yaw: (row(c, math.degrees(yaw)), None)
    )
    found = robustness.largest_opening_yaw(Scenario(), "adaptive", 1)
    assert found.opened_rad == pytest.approx(math.radians(45.0))
    assert math.isnan(found.failed_rad) and found.runs == 18


def test_rows_from_a_sweep_table():
    """A sweep's results table (pandas) gives one row per run; NaN cells (no hinge estimate,
    a failed run's handle) become None."""
    import pandas as pd

    from doorlab.studies.robustness import rows_from_sweep

    frame = pd.DataFrame(
        {
            "controller": ["velocity", "adaptive"],
            "station.cupboard_yaw_error": [0.1, 0.1],
            "status": ["slipped", "ok"],
            "door_opening_arc_end_rad": [0.70, 0.71],
            "door_opening_rad": [0.70, 0.71],
            "handle_held": [False, True],
            "peak_external_torque_arc_Nm": [4.8, 0.3],
            "peak_contact_force_arc_N": [16.0, 0.7],
            "max_radial_error_m": [0.02, 1e-4],
            "hinge_estimate_error_m": [float("nan"), 7e-4],
        }
    )
    adaptive, velocity = rows_from_sweep(frame)
    assert (adaptive.controller, velocity.controller) == ("adaptive", "velocity")
    assert adaptive.opened and adaptive.hinge_estimate_error_m == 7e-4
    assert not velocity.opened and velocity.hinge_estimate_error_m is None
    assert velocity.handle_held is False and velocity.yaw_error_rad == 0.1
