"""The report's experiment set as data: :data:`EXPERIMENTS` (the three controllers with the
doors open and closed, IK with 2, 5 and 10 knots; diffik and osc, open and closed), the
robustness grid (:func:`make_robustness_cases`) and :class:`RunRecord`, what a run left.

The page (:mod:`doorlab.report.page`) reads these; :mod:`doorlab.report.runner` runs them.
This module builds no page and runs nothing, so the page's modules may import it.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from doorlab.config import Scenario

IK_KNOTS = (2, 5, 10)
"""Knot counts of the problem set's task 1 question 1."""
BEYOND = ("diffik", "osc")
"""The controllers the report compares with the problem set's three, doors open and closed:
what a manipulation course teaches next (differential IK with limits, operational-space
control)."""


def make_experiments(base: Scenario | None = None) -> tuple[tuple[str, Scenario], ...]:
    """The problem set's experiment set, each a copy of ``base`` with its controller and doors.

    ``door_angles`` is reset to None in every experiment so that ``doors`` decides the initial
    hinge angles; every other setting of ``base`` (physics, timeline, gains) is kept.

    Args:
        base: The scenario the experiments vary (default: ``Scenario()``).

    Returns:
        (name, scenario) pairs: ik_2_open, ik_5_open, ik_10_open, ik_10_closed, velocity_open,
        velocity_closed, impedance_open, impedance_closed (the problem set's), then
        diffik_open, diffik_closed, osc_open, osc_closed (:data:`BEYOND`).
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
        *((f"{c}_{doors}", variant(c, doors)) for c in BEYOND for doors in ("open", "closed")),
    )


EXPERIMENTS: tuple[tuple[str, Scenario], ...] = make_experiments()
"""The problem set's eight runs and the four of the controllers beyond it on the default
scenario (see :func:`make_experiments`)."""


@dataclass(frozen=True)
class RobustnessCase:
    """One cell of the report's robustness grid: a controller, doors closed, one yaw error.

    Attributes:
        run: Name of the experiment (run folder) holding it: one of the problem set's
            experiments when its scenario is the very same case, else
            ``robust_<controller>_yaw_<m|p><deg>``.
        controller: Registry name.
        yaw_error_rad: ``station.cupboard_yaw_error`` [rad].
    """

    run: str
    controller: str
    yaw_error_rad: float


def make_plugin_experiments(
    controllers: Sequence[str], base: Scenario | None = None
) -> tuple[tuple[str, Scenario], ...]:
    """The runs of the report's controllers that are not built-ins (plug-ins): each with the
    doors open and closed, ``<name>_open`` and ``<name>_closed`` (a copy of ``base`` each), so
    that the tables and the overlays show them beside the problem set's."""
    from doorlab.config import CONTROLLERS
    from doorlab.episode.plugins import display_name

    base = base if base is not None else Scenario()
    out = []
    for controller in controllers:
        if controller in CONTROLLERS:
            continue
        name = display_name(controller)
        for doors in ("open", "closed"):
            scenario = copy.deepcopy(base)
            scenario.controller, scenario.doors, scenario.door_angles = controller, doors, None
            out.append((f"{name}_{doors}", scenario))
    return tuple(out)


def make_robustness_cases(
    base: Scenario | None = None,
    experiments: Sequence[tuple[str, Scenario]] = (),
    yaw_errors_deg: Sequence[float] | None = None,
    controllers: Sequence[str] | None = None,
) -> tuple[tuple[RobustnessCase, ...], tuple[tuple[str, Scenario], ...]]:
    """The robustness grid: every controller on every yaw error, doors closed.

    Args:
        base: The scenario the cases vary (:func:`doorlab.studies.robustness.case_scenario`).
        experiments: Runs already in the report: a case whose scenario equals one of them
            reuses that run instead of running it twice.
        yaw_errors_deg: The yaw errors [deg] (default: the acceptance grid, -10 to +10).
        controllers: The controllers (built-ins' names or plug-ins' specs; default: every
            built-in of the registry).

    Returns:
        (cases in (controller, yaw) order, the (name, scenario) experiments still to run).
    """
    import math

    from doorlab.episode.controllers import REGISTRY
    from doorlab.episode.plugins import display_name
    from doorlab.studies.robustness import ACCEPTANCE_YAW_ERRORS_DEG, case_scenario

    base = base if base is not None else Scenario()
    yaws = ACCEPTANCE_YAW_ERRORS_DEG if yaw_errors_deg is None else tuple(yaw_errors_deg)
    cases, new = [], []
    for spec in controllers if controllers is not None else list(REGISTRY):
        controller = display_name(spec)
        for yaw_deg in yaws:
            scenario = case_scenario(base, spec, math.radians(yaw_deg))
            same = [name for name, existing in experiments if existing == scenario]
            if same:
                name = same[0]
            else:
                sign = "m" if yaw_deg < 0 else "p"
                name = f"robust_{controller}_yaw_{sign}{abs(yaw_deg):g}".replace(".", "_")
                new.append((name, scenario))
            cases.append(RobustnessCase(name, controller, math.radians(yaw_deg)))
    return tuple(cases), tuple(new)


@dataclass(frozen=True)
class RunRecord:
    """One experiment's run folder and how the run went.

    Attributes:
        name: Experiment name (the folder's name), e.g. ``ik_10_open``.
        run_dir: The run folder (``metrics.json``, ``log.npz``, plots, ``replay.html``).
        status: Run status (:data:`doorlab.episode.metrics.STATUSES`, or ``error`` when the worker
            raised); the page re-reads it from ``metrics.json``.
        message: Why the run failed ("" when it did not).
        elapsed_s: Wall-clock time of the whole run, plots and replay included [s].
    """

    name: str
    run_dir: Path
    status: str = "unknown"
    message: str = ""
    elapsed_s: float = float("nan")


ARM_CONDITIONS = ("cell", "timing", "arm")
"""The report's "On the arm" conditions: doorlab's cell (``station.driver.timing: next_step``,
doorlab's inner loop), the arm's timing only (``kuka_driver``), and the arm preset
(:func:`doorlab.config.arm_preset`: the timing, KUKA's joint impedance, a 2.5 ms step, the
real run's safety limits)."""
ARM_TUNING: dict[str, str] = {
    "velocity": "velocity: {lead: inner_loop}",
    "impedance": "impedance: {kv: 10000.0}",
}
"""What makes the problem set's plans that fail on the arm open the door there (scenario YAML
on top of the case's): for the velocity plan a change of its law (q_ref = q + q_dot x the
inner loop's lead instead of x dt), for the impedance plan a stiffer task-space spring. Found with
``examples/sweep_kuka_velocity.yaml`` and ``examples/sweep_kuka_impedance.yaml``; the report
measures them on the arm and what they cost in doorlab's cell."""
ARM_COST_YAW_DEG = 5.0
"""The tuned plans' cost is also measured with the cupboard turned this much [deg] (a stiffer
plan gives up compliance against a hinge that is not where it believes)."""


@dataclass(frozen=True)
class ArmModel:
    """One plausible model of the lab's arm other than the preset's (the nominal one).

    Attributes:
        name: Its name (a run folder's suffix). parameter: The uncertain parameter it moves
            (one of :data:`ARM_PARAMETERS`). label: What it is, for the page.
        yaml: The scenario YAML that makes it, on top of the arm preset.
    """

    name: str
    parameter: str
    label: str
    yaml: str


ARM_PARAMETERS: dict[str, str] = {
    "damping": "KUKA's damping mapping",
    "load": "the load data",
    "friction": "the joints' friction",
    "latency": "the latency beyond the cycle",
    "noise": "the external torque's noise",
}
"""The arm's uncertain parameters (docs/guides/real-arm.md, "The arm's uncertain
parameters"), each with what the nominal model (the arm preset) takes: KUKA's damping on the
rotor-and-link inertia, exact load data, no friction, no latency beyond the cycle, an exact
external torque."""
ARM_STICTION = (2.0, 2.0, 1.5, 1.5, 1.0, 0.5, 0.5)
"""The band's high friction: stiction per joint [N m] (Coulomb friction 0.7 of it), with KUKA's
friction observer off at the commanded position; an assumption (no source gives the iiwa's
residual joint friction), to be replaced by ``doorlab identify``'s measurement."""
ARM_NOISE = 0.1
"""The band's external-torque noise [N m], standard deviation per joint and status; an
assumption (``doorlab identify`` measures it at rest)."""


def _friction_yaml() -> str:
    stiction = ", ".join(f"{v:g}" for v in ARM_STICTION)
    coulomb = ", ".join(f"{0.7 * v:g}" for v in ARM_STICTION)
    return f"station: {{arm: {{stiction: [{stiction}], coulomb_friction: [{coulomb}]}}}}"


ARM_MODELS: tuple[ArmModel, ...] = (
    ArmModel(
        "damping_link",
        "damping",
        "KUKA's damping on the link-side inertia (DLR's design)",
        "station: {inner_loop: {kuka_damping_model: link, kuka_damping_values: null}}",
    ),
    ArmModel(
        "damping_driver_kd",
        "damping",
        "kuka_driver's own hold damping, 50/35 N m s/rad",
        "station: {inner_loop: {kuka_damping_model: driver_kd, kuka_damping_values: null}}",
    ),
    ArmModel("load_none", "load", "no load data entered", "station: {arm: {load_mass: 0.0}}"),
    ArmModel(
        "friction_high",
        "friction",
        "friction up to 2 N m, KUKA's observer off at the commanded position",
        _friction_yaml(),
    ),
    ArmModel(
        "latency_3ms",
        "latency",
        "3 +- 1 ms of latency beyond the cycle",
        "station: {arm: {latency: 0.003, latency_jitter: 0.001}}",
    ),
    ArmModel(
        "noise",
        "noise",
        f"external-torque noise {ARM_NOISE:g} N m",
        "station: {arm: {external_torque_noise: [" + ", ".join([f"{ARM_NOISE:g}"] * 7) + "]}}",
    ),
)
"""The band's models other than the nominal, each one parameter at a plausible extreme."""
ARM_CORNERS: tuple[tuple[str, str], ...] = (
    ("damping_driver_kd", "latency_3ms"),
    ("damping_link", "friction_high"),
    ("damping_link", "latency_3ms"),
)
"""Pairs of :data:`ARM_MODELS` also run together: the pairs whose effects interact, measured
by ``benchmarks/arm_band.py`` over every pair of parameters on every plan
(``benchmarks/results/arm_band.json``): kuka_driver's damping with the latency stops the tuned
velocity plan and leaves the tuned impedance plan's door at 38.5 deg (each alone opens the
door); the link-side damping with friction or latency moves the impedance plan's door 1.5 and
1.3 deg from the one-at-a-time sum. The other 11 pairs change no verdict and move no door by
1 deg or more."""


def arm_model_names() -> tuple[str, ...]:
    """The band's models: "" (the nominal), each of :data:`ARM_MODELS`, each corner
    ("a+b")."""
    return ("", *(m.name for m in ARM_MODELS), *(f"{a}+{b}" for a, b in ARM_CORNERS))


def arm_model_parameters(model: str) -> tuple[str, ...]:
    """The parameters a band model moves (none for the nominal)."""
    by_name = {m.name: m for m in ARM_MODELS}
    return tuple(by_name[name].parameter for name in model.split("+") if name)


def apply_arm_model(scenario: Scenario, model: str) -> Scenario:
    """``scenario`` (on the arm preset) under a band model (a validated copy)."""
    from doorlab.config import update_scenario

    by_name = {m.name: m for m in ARM_MODELS}
    scenario = copy.deepcopy(scenario)
    for name in filter(None, model.split("+")):
        scenario = update_scenario(scenario, by_name[name].yaml)
    return scenario


@dataclass(frozen=True)
class ArmCase:
    """One run of the report's "On the arm" section.

    Attributes:
        run: The run folder's name (shared with an identical run of the report if any).
        controller: Registry name. condition: One of :data:`ARM_CONDITIONS`.
        tuned: With :data:`ARM_TUNING`'s settings. yaw_error_rad: The cupboard's yaw error.
        model: The band's model (condition ``arm``; :func:`arm_model_names`): "" the
            nominal (the preset).
    """

    run: str
    controller: str
    condition: str
    tuned: bool = False
    yaw_error_rad: float = 0.0
    model: str = ""


def arm_condition(base: Scenario, condition: str) -> Scenario:
    """``base`` (doors closed) under a condition of :data:`ARM_CONDITIONS` (a validated copy).

    ``cell`` keeps ``base`` but with doorlab's timing, and doorlab's default loop if ``base``
    runs KUKA's; ``timing`` adds kuka_driver's timing; in both the arm's model
    (``station.arm``) is the nominal one. ``arm`` is the arm preset on ``cell``, with ``base``'s
    own KUKA loop and arm model when it has them (``base`` an identified preset: its measured
    damping, load data, friction, latency and noise).
    """
    from doorlab.config import ArmModelConfig, InnerLoopConfig, arm_preset, validate

    scenario = copy.deepcopy(base)
    kuka_loop = None
    if scenario.station.inner_loop.kind == "kuka_joint_impedance":
        kuka_loop = copy.deepcopy(scenario.station.inner_loop)
        scenario.station.inner_loop = InnerLoopConfig()
    arm_model = copy.deepcopy(scenario.station.arm)
    scenario.doors, scenario.door_angles = "closed", None
    scenario.station.driver.timing = "next_step"
    scenario.station.arm = ArmModelConfig()
    if condition == "timing":
        scenario.station.driver.timing = "kuka_driver"
    elif condition == "arm":
        scenario = arm_preset(scenario)
        if kuka_loop is not None:
            scenario.station.inner_loop = kuka_loop
        scenario.station.arm = arm_model
    return validate(scenario)


def make_arm_cases(
    base: Scenario | None = None,
    existing: Sequence[tuple[str, Scenario]] = (),
    *,
    band: bool = True,
    controllers: Sequence[str] | None = None,
) -> tuple[tuple[ArmCase, ...], tuple[tuple[str, Scenario], ...]]:
    """The "On the arm" runs: every controller under every condition; the plans of
    :data:`ARM_TUNING` tuned on the arm and in doorlab's cell, there also with the cupboard
    turned :data:`ARM_COST_YAW_DEG` (tuned and not); and every plan on the arm (tuned ones
    too) under each other model of the band (:func:`arm_model_names`).

    Args:
        base: The report's base scenario. existing: Runs the report has already: a case
            with the very same scenario reuses it.
        band: Also the band's models (False: the nominal arm only).
        controllers: The controllers (built-ins' names or plug-ins' specs; default: every
            built-in of the registry); :data:`ARM_TUNING` tunes built-ins only.

    Returns:
        (the cases, the (name, scenario) runs still to run).
    """
    from doorlab.config import update_scenario
    from doorlab.episode.controllers import REGISTRY
    from doorlab.episode.plugins import display_name

    base = base if base is not None else Scenario()
    chosen = list(controllers) if controllers is not None else list(REGISTRY)
    yaw = math.radians(ARM_COST_YAW_DEG)
    wanted = [(c, condition, False, 0.0, "") for c in chosen for condition in ARM_CONDITIONS]
    for controller in (c for c in ARM_TUNING if c in chosen):
        wanted += [
            (controller, "arm", True, 0.0, ""),
            (controller, "cell", True, 0.0, ""),
            (controller, "cell", False, yaw, ""),
            (controller, "cell", True, yaw, ""),
        ]
    if band:
        plans = [(c, False) for c in chosen] + [(c, True) for c in ARM_TUNING if c in chosen]
        wanted += [
            (c, "arm", tuned, 0.0, model)
            for c, tuned in plans
            for model in arm_model_names()
            if model
        ]
    known = list(existing)
    cases, new = [], []
    for spec, condition, tuned, yaw_error, model in wanted:
        controller = display_name(spec)
        scenario = arm_condition(base, condition)
        scenario.controller = spec
        scenario.station.cupboard_yaw_error = yaw_error
        if tuned:
            scenario = update_scenario(scenario, ARM_TUNING[controller])
        if model:
            scenario = apply_arm_model(scenario, model)
        same = [name for name, other in known if other == scenario]
        if same:
            name = same[0]
        else:
            prefix = {"cell": "arm_cell", "timing": "arm_timing", "arm": "arm_preset"}
            name = f"{prefix[condition]}_{controller}" + ("_tuned" if tuned else "")
            name += f"_yaw_p{ARM_COST_YAW_DEG:g}" if yaw_error else ""
            name += f"_{model.replace('+', '_and_')}" if model else ""
            new.append((name, scenario))
            known.append((name, scenario))
        cases.append(ArmCase(name, controller, condition, tuned, yaw_error, model))
    return tuple(cases), tuple(new)
