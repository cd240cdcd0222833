"""The door metrics (arc's end, episode's end, lag) on synthetic logs with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from doorlab.cell.geometry import default_door_geometry
from doorlab.episode.metrics import door_lag, door_opening
from doorlab.episode.result import EpisodeResult

T0, T1, T_END = 11.0, 21.0, 24.0
DELAY = 1.5  # [s] the synthetic door runs the plan's ramp this late


def _result(door_left: np.ndarray, t: np.ndarray) -> EpisodeResult:
    n = len(t)
    zeros7 = np.zeros((n, 7))
    return EpisodeResult(
        t=t,
        q_commanded=zeros7,
        q_measured=zeros7,
        v_measured=zeros7,
        tau_external=zeros7,
        tau_feedforward=zeros7,
        tau_commanded=zeros7,
        door_angles=np.column_stack([door_left, np.zeros(n)]),
        wsg_width=np.zeros(n),
        plant_positions=np.zeros((n, 1)),
        plan_names=("grasp", "arc"),
        plan_starts=np.array([9.0, T0]),
        arc_window=np.array([T0, T1]),
    )


def test_door_metrics_of_a_delayed_ramp():
    """A door that follows the plan's ramp DELAY late: at the arc's end it is short by
    sweep x DELAY / T, it completes in the hold, and its largest lag is that same shortfall
    (a ramp delayed by a constant lags by the same angle all along, once it has started)."""
    geometry = default_door_geometry()
    t = np.arange(0.0, T_END + 1e-9, 0.01)
    tau_late = np.clip((t - T0 - DELAY) / (T1 - T0), 0.0, 1.0)
    # Opening is a negative left hinge angle; the door starts slightly open (-0.01 rad), and
    # the metrics count from the arc's start.
    result = _result(-0.01 - geometry.sweep * tau_late, t)
    opening = door_opening(result)
    i_end = int(np.argmin(np.abs(t - T1)))
    shortfall = geometry.sweep * DELAY / (T1 - T0)
    assert opening[i_end] == pytest.approx(geometry.sweep - shortfall, abs=1e-9)
    assert opening[-1] == pytest.approx(geometry.sweep, abs=1e-9)
    times, lag = door_lag(result, geometry)
    assert times[0] == pytest.approx(T0) and times[-1] == pytest.approx(T1)
    assert np.max(lag) == pytest.approx(shortfall, abs=1e-9)
    assert math.degrees(shortfall) == pytest.approx(6.18, abs=0.01)  # 41.2 deg x 0.15


def test_default_inner_loop_is_damped_at_zeta_0_1_at_the_grasp():
    """The default gains were derived as Kq = wn^2 M_ii, Dq = 2 zeta sqrt(Kq M_ii) with zeta =
    0.1 at the grasp pose (docs/explanation/model.md, "Inner loop gains"): the model gives that
    back within the gains' rounding (3 significant digits, so 1 %); dq_scale scales it; ID-PID
    has none."""
    from doorlab.cell.geometry import scenario_door_geometry
    from doorlab.cell.station import make_controller_plant
    from doorlab.config import Scenario
    from doorlab.episode.controllers import get_controller
    from doorlab.episode.metrics import joint_damping_ratios

    scenario = Scenario(controller="velocity", doors="closed")
    arc = get_controller("velocity").build(
        scenario, scenario_door_geometry(scenario), make_controller_plant()
    )
    zeta = joint_damping_ratios(scenario, arc.q_start)
    assert zeta == pytest.approx(np.full(7, 0.1), rel=0.01)
    scenario.station.inner_loop.dq_scale = 2.0
    assert joint_damping_ratios(scenario, arc.q_start) == pytest.approx(2 * zeta, rel=1e-12)
    scenario.station.inner_loop.kind = "inverse_dynamics"
    assert joint_damping_ratios(scenario, arc.q_start) is None
