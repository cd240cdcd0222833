"""The plug-in's law, checked without a simulation, and (installed) found by doorlab.

Run: ``python -m pytest examples/doorlab-feedforward/tests`` (the package installed, or its
``src`` on PYTHONPATH).
"""

from __future__ import annotations

from importlib.metadata import entry_points

import numpy as np
import pytest
from doorlab_feedforward import CONTROLLER, FeedforwardPlan, reference_velocity

import doorlab
from doorlab.cell.geometry import default_door_geometry
from doorlab.cell.station import make_controller_plant


def test_the_feed_forward_is_the_arcs_velocity():
    """V_ref is the time derivative of the arc's reference (Q's position, L7's yaw), taken
    numerically: central differences over 1 ms agree to 1e-6 of the speeds."""
    geometry = default_door_geometry()
    duration, h = 10.0, 1e-3
    for tau in (0.1, 0.5, 0.9):
        V = reference_velocity(geometry, tau, duration)
        dp = geometry.p_WQ_ref(tau + h / duration) - geometry.p_WQ_ref(tau - h / duration)
        np.testing.assert_allclose(V[3:], dp / (2 * h), atol=1e-6)
        R1, R0 = geometry.R_WL7_ref(tau + h / duration), geometry.R_WL7_ref(tau - h / duration)
        w = (R1 @ R0.inverse()).ToAngleAxis()
        np.testing.assert_allclose(V[:3], w.angle() * w.axis() / (2 * h), atol=1e-6)
    assert np.all(reference_velocity(geometry, 1.5, duration) == 0)  # the hold after the arc


def test_the_command_realizes_the_feed_forward_on_the_arc():
    """On the reference (no error), J q_dot = V_ref: the plan moves Q at the arc's speed."""
    geometry = default_door_geometry()
    plant = make_controller_plant()
    scenario = doorlab.Scenario()
    arc = CONTROLLER.build(scenario, geometry, plant)
    assert isinstance(arc, doorlab.ArcPlan) and arc.q_start.shape == (7,)
    plan = FeedforwardPlan(geometry, 10.0, plant, 0.005, kv=0.0, kw=0.0)  # feedback off
    q = arc.q_start
    command = plan.command(5.0, doorlab.ArmState(q, np.zeros(7), np.zeros(7)))
    q_dot = (command.q_ref - q) / 0.005
    from pydrake.multibody.tree import JacobianWrtVariable

    context = plant.CreateDefaultContext()
    plant.SetPositions(context, q)
    L7, W = plant.GetFrameByName("iiwa_link_7"), plant.world_frame()
    J = plant.CalcJacobianSpatialVelocity(
        context, JacobianWrtVariable.kV, L7, np.array([0, 0, 0.214]), W, W
    )
    np.testing.assert_allclose(J @ q_dot, reference_velocity(geometry, 0.5, 10.0), atol=1e-9)
    assert np.all(command.tau_ff == 0)


def test_doorlab_finds_the_installed_plug_in():
    """Installed (pip install -e .), the entry point names this package's controller."""
    names = {e.name for e in entry_points(group="doorlab.controllers")}
    if "feedforward" not in names:
        pytest.skip("the package is not installed (its src is only on the path)")
    from doorlab.episode.controllers import get_controller

    assert get_controller("feedforward").build is CONTROLLER.build
