"""The registry of the door-opening controllers and the episode each one runs.

Each controller turns a scenario into the arc plan and the configuration it starts from
(the contract: :mod:`doorlab.episode.contract`); :func:`run_controller` wraps it in the
problem set's episode: close the gripper on the handle at the start configuration, then
follow the arc (:func:`episode_plans`, for either cell; the simulated episode is
:func:`doorlab.episode.simulation.run_episode`). :func:`get_controller` finds a built-in of
:data:`REGISTRY` or loads a plug-in (:mod:`doorlab.episode.plugins`).
"""

from __future__ import annotations

import numpy as np
from pydrake.geometry import Meshcat
from pydrake.multibody.plant import MultibodyPlant

from doorlab.cell.geometry import DoorGeometry, scenario_door_geometry
from doorlab.cell.station import STIFFNESS_LOOPS, joint_damping, make_controller_plant
from doorlab.config import Scenario, validate
from doorlab.config_checks import controller_spec
from doorlab.constants import Q_HOME
from doorlab.control.adaptive import AdaptivePlan, velocity_lead
from doorlab.control.diffik import DiffIkPlan
from doorlab.control.ik import solve_ik
from doorlab.control.ik_pointwise import pointwise_ik
from doorlab.control.osc import OperationalSpacePlan
from doorlab.control.plans import (
    JointSpacePlan,
    Plan,
    TaskSpaceImpedancePlan,
    TaskSpaceVelocityPlan,
)
from doorlab.episode.contract import ArcPlan, Controller
from doorlab.episode.plugins import build_arc, display_name, load_plugin
from doorlab.episode.result import EpisodeResult
from doorlab.episode.simulation import run_episode
from doorlab.errors import ConfigError

__all__ = [
    "REGISTRY",
    "ArcPlan",
    "Controller",
    "controller_name",
    "episode_plans",
    "get_controller",
    "grasp_configuration",
    "run_controller",
    "simulate_controller",
]


def grasp_configuration(
    scenario: Scenario, geometry: DoorGeometry, plant: MultibodyPlant
) -> np.ndarray:
    """Where the task-space plans start: the arm's configuration (7,) [rad] with Q at the
    (believed) handle plus ``ik.grasp_offset`` and L7 at the arc's initial orientation
    ``geometry.R_WL7_ref(0)``, by one-shot IK from the home configuration (within
    ``ik.grasp_position_tolerance`` [m] and ``ik.theta_bound`` [rad]). A plug-in's
    ``ArcPlan.q_start`` may be this.

    Raises:
        IkError: No solution within the tolerances.
    """
    return solve_ik(
        plant,
        geometry.p_WQ_ref(0.0) + np.asarray(scenario.ik.grasp_offset, dtype=float),
        geometry.R_WL7_ref(0.0),
        Q_HOME,
        position_tolerance=scenario.ik.grasp_position_tolerance,
        theta_bound=scenario.ik.theta_bound,
    )


_grasp_configuration = grasp_configuration  # the built-ins' name for it


def build_ik_plan(scenario: Scenario, geometry: DoorGeometry, plant: MultibodyPlant) -> ArcPlan:
    """Task 1: IK at knots along the arc, joined by a cubic joint spline."""
    duration = scenario.timeline.arc_duration
    ik = pointwise_ik(
        plant,
        geometry.p_WQ_ref,
        geometry.R_WL7_ref,
        duration=duration,
        num_knots=scenario.ik.knots,
        q_guess=Q_HOME,
        position_tolerance=scenario.ik.position_tolerance,
        theta_bound=scenario.ik.theta_bound,
        centered=scenario.ik.objective == "centered",
    )
    plan = JointSpacePlan.cubic(ik.times, ik.q_knots, name="ik")
    return ArcPlan(plan, ik.q_knots[0], ik)


def build_velocity_plan(
    scenario: Scenario, geometry: DoorGeometry, plant: MultibodyPlant
) -> ArcPlan:
    """Task 2: differential IK, q_ref = q + J^+ V_des dt (``velocity.lead: inner_loop``: the
    inner loop's lead instead of dt)."""
    period = scenario.timeline.control_period
    lead = None
    if scenario.velocity.lead == "inner_loop":
        lead = velocity_lead(scenario.station.inner_loop, period)
    plan = TaskSpaceVelocityPlan(
        geometry, scenario.timeline.arc_duration, plant, scenario.velocity, period, lead
    )
    return ArcPlan(plan, _grasp_configuration(scenario, geometry, plant))


def build_impedance_plan(
    scenario: Scenario, geometry: DoorGeometry, plant: MultibodyPlant
) -> ArcPlan:
    """Task 3: tau_ff = J^T F, q_ref = q."""
    plan = TaskSpaceImpedancePlan(
        geometry, scenario.timeline.arc_duration, plant, scenario.impedance
    )
    return ArcPlan(plan, _grasp_configuration(scenario, geometry, plant))


def build_adaptive_plan(
    scenario: Scenario, geometry: DoorGeometry, plant: MultibodyPlant
) -> ArcPlan:
    """The adaptive plan: grasp at the believed handle, then nothing from the model."""
    plan = AdaptivePlan(
        scenario.timeline.arc_duration,
        plant,
        scenario.adaptive,
        scenario.timeline.control_period,
        velocity_lead(scenario.station.inner_loop, scenario.timeline.control_period),
    )
    return ArcPlan(plan, _grasp_configuration(scenario, geometry, plant))


def build_diffik_plan(scenario: Scenario, geometry: DoorGeometry, plant: MultibodyPlant) -> ArcPlan:
    """Differential IK: the velocity plan's V_des through Drake's QP with joint position and
    velocity limits, integrated into q_ref."""
    plan = DiffIkPlan(
        geometry,
        scenario.timeline.arc_duration,
        plant,
        scenario.diffik,
        scenario.timeline.control_period,
    )
    return ArcPlan(plan, _grasp_configuration(scenario, geometry, plant))


def build_osc_plan(scenario: Scenario, geometry: DoorGeometry, plant: MultibodyPlant) -> ArcPlan:
    """Operational-space impedance: tau_ff = J^T Lambda (a_ref + Kp e + Kd e_dot) + the inner
    loop's damping in the task's directions, q_ref = q."""
    station = scenario.station
    damping = np.zeros(len(Q_HOME))
    if station.inner_loop.kind in STIFFNESS_LOOPS:
        damping = joint_damping(station)
    plan = OperationalSpacePlan(
        geometry, scenario.timeline.arc_duration, plant, scenario.osc, damping
    )
    return ArcPlan(plan, _grasp_configuration(scenario, geometry, plant))


REGISTRY: dict[str, Controller] = {
    c.name: c
    for c in (
        Controller(
            "ik",
            1,
            "Pointwise IK",
            "IK at knots along the handle arc, cubic joint spline, position commands",
            build_ik_plan,
        ),
        Controller(
            "velocity",
            2,
            "Jacobian velocity mapping",
            "q_dot = J^+ V_des from the pose error, q_ref = q + q_dot dt",
            build_velocity_plan,
        ),
        Controller(
            "impedance",
            3,
            "Jacobian-transpose impedance",
            "tau_ff = J^T F from the pose error, q_ref = q",
            build_impedance_plan,
        ),
        Controller(
            "adaptive",
            4,
            "Adaptive, unknown hinge",
            "velocity along the estimated tangent, radial force compliance, hinge fitted "
            "online from Q's path; nothing from the model after the grasp",
            build_adaptive_plan,
        ),
        Controller(
            "diffik",
            5,
            "Differential IK with joint limits",
            "the velocity plan's V_des through Drake's differential-IK QP with joint position "
            "and velocity limits, integrated into q_ref",
            build_diffik_plan,
        ),
        Controller(
            "osc",
            6,
            "Operational-space impedance",
            "tau_ff = J^T Lambda (a_ref + Kp e + Kd e_dot) with Lambda = (J M^-1 J^T)^-1 from "
            "the controller plant, q_ref = q",
            build_osc_plan,
        ),
    )
}
"""Controllers by CLI name, in the problem set's task order, the adaptive plan, then the two a
manipulation course teaches next."""


def get_controller(name: str) -> Controller:
    """The controller ``name`` names: a built-in of :data:`REGISTRY`, or a plug-in
    (``FILE.py:NAME``, ``MODULE:NAME`` or an installed one's name), loaded once per process
    and checked (:func:`doorlab.episode.plugins.load_plugin`).

    Raises:
        ConfigError: Unknown name (the message lists the valid ones).
        PluginError: A plug-in that cannot be loaded or used (one line naming it).
    """
    if name in REGISTRY:
        return REGISTRY[name]
    try:
        controller_spec(name, tuple(REGISTRY))
    except ConfigError as e:
        raise ConfigError(
            f"unknown controller {name!r}; choose one of {', '.join(REGISTRY)}; {e}"
        ) from None
    return load_plugin(name, tuple(REGISTRY))


def controller_name(name: str) -> str:
    """What tables, metrics and folders call the controller ``name`` names: a built-in's
    name, a plug-in's own (a Controller's ``name``, a function's NAME, an installed one's
    entry point name). A plug-in is loaded to read it (once per process).

    Raises:
        ConfigError, PluginError: As :func:`get_controller`.
    """
    get_controller(name)  # one line if it does not load
    return display_name(name, tuple(REGISTRY))


def run_controller(
    scenario: Scenario, *, meshcat: Meshcat | None = None, realtime_rate: float = 0.0
) -> tuple[EpisodeResult, ArcPlan]:
    """Runs the scenario's controller through one episode (the problem set's task cell),
    after checking the scenario (:func:`doorlab.config.validate`).

    Returns:
        The episode logs and the arc plan that ran.

    Raises:
        ConfigError: Invalid scenario. IkError: No IK solution. SimulationError: Physics failed.
    """
    return simulate_controller(validate(scenario), meshcat=meshcat, realtime_rate=realtime_rate)


def simulate_controller(
    scenario: Scenario, *, meshcat: Meshcat | None = None, realtime_rate: float = 0.0
) -> tuple[EpisodeResult, ArcPlan]:
    """:func:`run_controller` for a scenario already validated (a run folder's, whose
    scenario was checked before the folder was touched): its plans, then the episode.

    Raises:
        IkError: No IK solution. SimulationError: Physics failed.
    """
    plans, widths, arc = episode_plans(scenario)
    result = run_episode(
        scenario, plans, widths, q_start=arc.q_start, meshcat=meshcat, realtime_rate=realtime_rate
    )
    return result, arc


def episode_plans(scenario: Scenario) -> tuple[list[Plan], list[float], ArcPlan]:
    """The problem set's task cell as plans, for either cell: close the gripper on the handle at the
    arc plan's start configuration, then the arc plan.

    Returns:
        The plans, their gripper setpoints [m] and the arc plan.

    Raises:
        ConfigError: Unknown controller. PluginError: A plug-in that cannot be loaded or
            whose build failed. IkError: No IK solution.
    """
    controller = get_controller(scenario.controller)
    geometry = scenario_door_geometry(scenario)
    if scenario.controller in REGISTRY:
        arc = controller.build(scenario, geometry, make_controller_plant())
    else:  # a plug-in: its build and every tick watched (doorlab.episode.plugins)
        arc = build_arc(
            controller, scenario.controller, scenario, geometry, make_controller_plant()
        )
    grasp = JointSpacePlan.hold(arc.q_start, scenario.timeline.grasp_duration, name="grasp")
    width = scenario.station.gripper.grasp_width
    return [grasp, arc.plan], [width, width], arc
