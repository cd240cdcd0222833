"""One typed scenario: nested dataclasses with defaults (units in comments), loadable from YAML.

A scenario fully determines an episode: the same scenario gives bit-identical logs.

Example YAML (every key optional; unknown keys are an error)::

    controller: impedance
    doors: closed
    station:
      time_step: 0.002
      inner_loop: {kind: stiffness}
    impedance: {kv: 100.0, kw: 50.0}
"""

import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path

from pydrake.common.yaml import yaml_load_typed

from doorlab.config_checks import (  # noqa: F401 (the bounds, named here too)
    COMMAND_TIMINGS,
    KUKA_DAMPING_MODELS,
    MAX_CUPBOARD_POSITION_ERROR,
    MAX_EPISODE_DURATION,
    MAX_LOG_SAMPLES,
    MIN_ARC_SAMPLES,
    absolute_controller,
    check,
    choice,
    controller_spec,
    gains,
    non_negative,
    positive,
    validate_arm_model,
    validate_kuka,
    validate_position_error,
    validate_safety,
    validate_timeline,
)
from doorlab.constants import DOOR_ANGLES
from doorlab.errors import ConfigError
from doorlab.kuka import (
    EXTERNAL_TORQUE_LIMIT,
    KUKA_DAMPING,
    KUKA_STIFFNESS,
    VELOCITY_FILTER_CUTOFF,
)
from doorlab.runtime.drake_compat import missing_contact_approximation
from doorlab.runtime.inputs import load_yaml, quote, quote_text, read_text_file, yaml_float_spelling

CONTROLLERS = ("ik", "velocity", "impedance", "adaptive", "diffik", "osc")
"""Names of the built-in door-opening controllers: the problem set's tasks 1-3, the adaptive
plan, then the two a manipulation course teaches next (differential IK with limits,
operational-space control). ``Scenario.controller`` may also name a plug-in
(:mod:`doorlab.episode.plugins`)."""
DOOR_STATES = tuple(DOOR_ANGLES)
INNER_LOOPS = ("stiffness", "implicit_pd", "inverse_dynamics", "kuka_joint_impedance")
IK_OBJECTIVES = ("feasible", "centered")
VELOCITY_LEADS = ("control_period", "inner_loop")
"""``velocity.lead``: what q_dot is multiplied by in q_ref = q + q_dot x lead."""
CONTACT_APPROXIMATIONS = ("sap", "lagged", "similar", "tamsi")
"""Every discrete contact approximation doorlab knows; tamsi only on Drake <= 1.56
(:func:`doorlab.runtime.drake_compat.contact_approximations`: the running Drake's)."""
LEFT_HINGE_RANGE = (-math.pi / 2, 0.0)
"""Hinge range of the left door [rad] (opening is negative)."""
RIGHT_HINGE_RANGE = (0.0, math.pi / 2)
MAX_CUPBOARD_YAW_ERROR = math.pi / 4
"""Largest |station.cupboard_yaw_error| [rad]: beyond 45 deg the handle faces away from the arm."""

MIN_TIME_STEP = 1e-5
"""Finest ``station.time_step`` [s]: 200x finer than the original's 2 ms (the default episode
is then 2.4 million plant steps)."""
MAX_GRASP_OFFSET = 0.01
"""Largest |ik.grasp_offset| per axis [m]: the handle is 10 mm thick, so a centimetre off
the fingers no longer close on it."""


@dataclass
class InnerLoopConfig:
    """The robot's joint-level controller (the problem set's "robot controller").

    ``stiffness`` is the problem set's law tau = Kq (q_ref - q) - Dq qdot + g(q) + tau_ff: the
    spring, g(q) and tau_ff are one explicit torque per step (C++ systems), the damping is the
    joints' own viscous damping, integrated implicitly by the plant. ``implicit_pd`` is the same law
    through the plant's PD actuators (the design before issue 9, kept for comparison: slower,
    same physics). ``inverse_dynamics`` is the original station's PID through M(q).
    ``kuka_joint_impedance`` is the lab arm's loop (``DrakeFRITorqueDriver``: KUKA's
    ``JointImpedanceControlMode``, :mod:`doorlab.kuka`): the ``stiffness`` law with Kq =
    ``kuka_stiffness`` and Dq = 2 d sqrt(Kq M_ii), d = ``kuka_damping`` (KUKA's dimensionless
    value), M_ii the model's joint inertia at the problem set's grasp pose
    (:data:`doorlab.constants.Q_GRASP`); ``kq``, ``dq`` and ``dq_scale`` do not apply to it.

    What ``dq`` means: the problem set's (and the PD actuators') Dq. The damping that acts is
    Dq dq_scale + h Kq, h = ``station.time_step``: SAP evaluates a PD actuator's spring at the
    step's end, q_{n+1} = q_n + h v_{n+1}, which adds h Kq of damping (0.02 to the damping
    ratio at the defaults' 20 rad/s and 2 ms); the ``stiffness`` loop keeps that term, now
    explicit, in the joints' damping, so both loops give the same results, and so do the gains
    and the measured trade-offs below, which were derived under it.
    """

    kind: str = "stiffness"  # one of INNER_LOOPS
    # Joint stiffness Kq [N m/rad] and damping Dq [N m s/rad], per joint (docs: the model of
    # the cell, "Inner loop gains"), for the arm's joint inertia M_ii at the grasp pose (links
    # plus the motors' reflected inertia, 1.4-6.9 kg m^2): Kq = wn^2 M_ii with wn = 20 rad/s,
    # Dq = 2 zeta sqrt(Kq M_ii) with zeta = 0.1, so Dq/Kq = 10 ms. Low damping is a measured
    # trade-off (benchmarks/inner_loop_sweep.py): with q_ref = q, Dq (and Kq over the 5 ms control
    # period) is all that resists the impedance plan's J^T F, and the velocity plan's
    # q_ref = q + qdot dt stalls once Dq/Kq exceeds a few control periods.
    kq: list[float] = field(
        default_factory=lambda: [1330.0, 2770.0, 1670.0, 1090.0, 570.0, 580.0, 560.0]
    )
    dq: list[float] = field(  # [N m s/rad] per joint (see kq)
        default_factory=lambda: [13.3, 27.7, 16.7, 10.9, 5.7, 5.8, 5.6]
    )
    # Multiplier on every Dq [-] (>= 0): one knob for the position-tracking vs impedance-lag
    # trade-off (benchmarks/inner_loop_sweep.py).
    dq_scale: float = 1.0
    # [N m/rad] KUKA's joint stiffness per joint (kind kuka_joint_impedance;
    # DrakeFRITorqueDriver's values).
    kuka_stiffness: list[float] = field(default_factory=lambda: list(KUKA_STIFFNESS))
    # [-] KUKA's dimensionless joint damping per joint, 0.1-1.0 (kind kuka_joint_impedance;
    # Dq = 2 d sqrt(Kq M_ii), see the class docstring).
    kuka_damping: list[float] = field(default_factory=lambda: list(KUKA_DAMPING))
    # How KUKA turns d into N m s/rad (one of KUKA_DAMPING_MODELS; KUKA does not publish it):
    # "rotor_link" 2 d sqrt(Kq M_ii) with M_ii of links, gripper and the motors' reflected
    # inertia at the grasp pose; "link" the same with the link-side M_ii (no rotor: DLR's
    # design, whose torque feedback hides the motor inertia); "driver_kd" kuka_driver's own
    # torque-only hold, 50, 50, 50, 50, 35, 35, 35 (d does not apply); "values"
    # kuka_damping_values (a measured damping: doorlab identify writes it).
    kuka_damping_model: str = "rotor_link"
    # [N m s/rad] per joint, for kuka_damping_model "values" (None otherwise).
    kuka_damping_values: list[float] | None = None
    # Inverse-dynamics PID gains of the original station (act through M(q)).
    id_kp: float = 100.0  # [1/s^2] proportional gain
    id_ki: float = 1.0  # [1/s^3] integral gain
    id_kd: float = 20.0  # [1/s] derivative gain


@dataclass
class GripperConfig:
    """WSG-50 finger controller: PD on finger separation, force-limited."""

    kp: float = 200.0  # [N/m] stiffness on the finger separation
    kd: float = 5.0  # [N s/m] damping on the finger separation's rate
    force_limit: float = 15.0  # [N], the course code's value
    initial_width: float = 0.03  # [m] finger separation at t = 0
    approach_width: float = 0.025  # [m] setpoint while moving to the handle
    grasp_width: float = 0.005  # [m] setpoint while holding the handle


@dataclass
class SafetyConfig:
    """Limits every arm command is checked against before it goes out (:mod:`doorlab.cell.safety`).

    Always on for ``doorlab run --hardware``; in simulation only when ``enabled``, to rehearse a
    plan under the real run's limits.
    """

    enabled: bool = False  # check the commands in simulation too
    joint_limit_margin: float = 0.0873  # [rad] (5 deg) q_ref stays this far inside the limits
    gap_time: float = 0.02  # [s] |q_ref - q| <= data-sheet speed x this
    speed_fraction: float = 0.5  # [-] implied joint speed <= this x the data-sheet speed
    torque_fraction: float = 0.25  # [-] |tau_ff| <= this x the data-sheet torque


@dataclass
class DriverConfig:
    """How commands reach the arm and what the plans read back (:mod:`doorlab.kuka`).

    ``timing`` is for one-process runs; ``doorlab sim-driver`` always keeps kuka_driver's
    cycle and reads the other fields. ``next_step`` (doorlab's cell): the command a plan
    computes at its tick acts from the next plant step, and the plan reads the plant's exact
    state. ``kuka_driver`` (the lab arm): the plan reads a status sampled at each 5 ms cycle,
    with kuka_driver's filtered velocity; its command acts from the next cycle (one period
    after the state it was computed from), clamped to the joint limits less 1 deg; the arm
    stands still until the first command; an external torque over kuka_driver's limits stops
    the run (``safety_stop``, limit ``external_torque``), as the driver exits.
    """

    timing: str = "next_step"  # one of COMMAND_TIMINGS
    velocity_filter_cutoff: float = VELOCITY_FILTER_CUTOFF  # [Hz] low-pass of the status velocity
    # [N m] kuka_driver's --ext_trq_limit: |tau_external| over it x (1, 1, 1, 0.5, 0.2, 0.2,
    # 0.1) per joint stops the driver.
    external_torque_limit: float = EXTERNAL_TORQUE_LIMIT


@dataclass
class ArmModelConfig:
    """What doorlab cannot read from a source about the lab's iiwa (kind
    ``kuka_joint_impedance``; the damping's mapping is ``inner_loop.kuka_damping_model``).

    Each field is a model of the arm that no source pins down (docs/guides/real-arm.md, "The
    arm's uncertain parameters"): ``doorlab report``'s "On the arm" runs each plan over their
    plausible range, and ``doorlab identify`` measures them on the lab's arm. Defaults: the
    model before it was measured (exact load data, no friction, no latency beyond the cycle).

    - **Load data** (``load_mass``): the mass KUKA's model carries at the flange, at the
      gripper's centre of mass. KUKA's gravity compensation and its external-torque estimate
      use it; the gripper's real 1.09 kg is what the plant has. None: exact (the gripper's
      mass); 0: none entered (``DrakeFRITorqueDriver`` attaches no tool).
    - **Friction** (``coulomb_friction``, ``stiction``): the joints' residual friction,
      a Stribeck curve (stiction at rest decaying to Coulomb friction above
      :data:`doorlab.kuka.STRIBECK_VELOCITY`); KUKA's friction observer cancels it only
      away from the commanded position, fully once |q_ref - q| >=
      ``friction_compensation_band`` and in proportion below (kuka_driver.cc's IIR filter
      exists to make that difference).
    - **Latency** (``latency``, ``latency_jitter``): how long after its cycle a command
      acts, beyond the cycle itself; each cycle's latency is latency + jitter x U(-1, 1),
      within [0, 5 ms). It needs a plant step that divides the 5 ms cycle.
    - **External torque** (``external_torque_noise``): the status's external torque is
      KUKA's estimate, measured minus its model: the contact torques, plus the gravity of
      the load its load data leaves out, plus Gaussian noise of this standard deviation
      per status; kuka_driver's freeze is judged on it.
    """

    # [kg] the mass in KUKA's load data, at the gripper's centre of mass; None: exact (the
    # gripper's 1.09 kg), 0: none entered
    load_mass: float | None = None
    # [N m] per joint, the joints' Coulomb (sliding) friction where KUKA's observer is off
    coulomb_friction: list[float] = field(default_factory=lambda: [0.0] * 7)
    # [N m] per joint, the friction at rest (breakaway), >= coulomb_friction
    stiction: list[float] = field(default_factory=lambda: [0.0] * 7)
    # [rad] |q_ref - q| from which KUKA's friction observer cancels the friction fully
    # (linearly below; an assumption, no source gives it)
    friction_compensation_band: float = 5e-4
    # [s] how long after its cycle a command acts, beyond the cycle, in [0, 4 ms]
    latency: float = 0.0
    # [s] half-width of the latency's uniform jitter, drawn per cycle (<= latency)
    latency_jitter: float = 0.0
    # [N m] per joint, the standard deviation of the external-torque estimate's noise
    external_torque_noise: list[float] = field(default_factory=lambda: [0.0] * 7)
    # the random seed of the noise and the jitter (the same seed, the same draws in any
    # process)
    seed: int = 0

    def friction(self) -> bool:
        """Whether any joint has friction."""
        return any(v > 0 for v in (*self.coulomb_friction, *self.stiction))


@dataclass
class StationConfig:
    """Physics of the cell."""

    time_step: float = 0.002  # [s] plant discrete step (the original's)
    contact_approximation: str = (
        "sap"  # sap, lagged, similar, or tamsi (Drake <= 1.56 only; not with kind=implicit_pd)
    )
    arm_collision: bool = False  # give the arm collision capsules (the original arm had none)
    # Keep the collision geometry of the cupboard's carcass, right door and the table also
    # without arm collision (only the gripper could touch them; it touches the left door only).
    scene_collision: bool = False
    # Cupboard frame C in W [m] (rotation fixed at RotZ(pi)); move it to test reachability.
    cupboard_position: list[float] = field(default_factory=lambda: [0.9057, 0.0, 0.4148])
    # [rad] The TRUE cupboard is the believed one (at cupboard_position) turned by this angle
    # about the left handle's vertical axis (positive: counter-clockwise seen from above). The
    # handle stays where the plans believe it is, the hinge does not (10 deg moves it 4.7 cm);
    # the problem set's plans follow the believed arc, metrics use the true one.
    cupboard_yaw_error: float = 0.0
    # [m] (3,) The TRUE cupboard also stands this far from the believed one, in W (x, y, z):
    # handle and hinge move with it, the plans aim where they believe (doorlab bench draws
    # it); the metrics use the true cupboard.
    cupboard_position_error: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    hinge_damping: float = 1.0  # [N m s/rad] viscous damping of the door hinges
    friction: float = 1.0  # Coulomb friction of fingers and handle [-]
    inner_loop: InnerLoopConfig = field(default_factory=InnerLoopConfig)
    gripper: GripperConfig = field(default_factory=GripperConfig)
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    driver: DriverConfig = field(default_factory=DriverConfig)
    arm: ArmModelConfig = field(default_factory=ArmModelConfig)


@dataclass
class TimelineConfig:
    """The original episode timeline (station facts §4)."""

    control_period: float = 0.005  # [s] plan runner period (200 Hz)
    log_period: float = 0.01  # [s] sample period of the episode's logs
    hold_duration: float = 1.0  # [s] hold q_home (plus the 1 s every plan gets)
    approach_duration: float = 6.0  # [s] cubic move to the first plan's start (+1 s)
    grasp_duration: float = 1.0  # [s] close the gripper on the handle (+1 s)
    arc_duration: float = 10.0  # [s] the door-opening arc (+1 s)
    extra_time: float = 2.0  # [s] after the last plan


@dataclass
class ArcConfig:
    """The handle's arc and the L7 reference orientation along it."""

    angle_end_deg: float = 50.0  # [deg] handle angle about the hinge at the arc's end


@dataclass
class IkConfig:
    """Pointwise IK (task 1) and the one-shot IK to the handle."""

    knots: int = 10  # knot points along the arc, >= 2
    # "feasible": the problem set's IK, any pose within the tolerances; "centered": the exact pose
    # within them (knots then carry no error of their own).
    objective: str = "feasible"
    position_tolerance: float = 0.001  # [m] box half-width around each arc point
    theta_bound: float = 0.005 * math.pi  # [rad] L7 orientation bound
    grasp_position_tolerance: float = 0.0005  # [m] one-shot IK to the handle
    # [m] (3,) where the one-shot IK aims Q: the handle's centre plus this, in W. The
    # original's feasibility-only IK grasped 0.5 mm off the handle in each axis;
    # examples/sweep_grasp_offset.yaml measures what such an offset does.
    grasp_offset: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])


@dataclass
class VelocityPlanConfig:
    """Jacobian pseudo-inverse velocity plan (task 2)."""

    kv: float = 100.0  # [1/s] gain from Q's position error to its desired velocity
    kw: float = 50.0  # [1/s] gain from L7's orientation error to its angular velocity
    joint_speed_limit: float = 1.0  # [rad/s] clip on q_dot (the original's)
    # q_ref = q + q_dot x the lead: "control_period" (the problem set's dt) or "inner_loop"
    # (Dq / Kq + dt / 2 per joint: what a stiffness loop needs to reach the speed; a change
    # of the problem set's law for a damped loop such as KUKA's).
    lead: str = "control_period"


@dataclass
class ImpedancePlanConfig:
    """Jacobian-transpose impedance plan (task 3)."""

    kv: float = 100.0  # [N/m] translational stiffness: force at Q per metre of error
    kw: float = 50.0  # [N m/rad] rotational stiffness: torque on L7 per radian of error
    torque_limit: float = 20.0  # [N m] clip on tau_ff (the original's)


@dataclass
class DiffIkPlanConfig:
    """Differential IK with joint limits (``diffik``): the velocity plan's V_des, solved by
    Drake's QP under joint position and velocity limits, integrated into q_ref."""

    kv: float = 100.0  # [1/s] gain from Q's position error to its desired velocity
    kw: float = 50.0  # [1/s] gain from L7's orientation error to its angular velocity
    # [rad/s] symmetric joint velocity limit of the QP (the velocity plan's clip, as a limit
    # that scales the whole motion down instead of clipping joints one by one)
    joint_speed_limit: float = 1.0
    # [rad] the QP keeps q_ref this far inside the data sheet's position limits (the safety
    # checks' margin, station.safety.joint_limit_margin's default)
    joint_limit_margin: float = 0.0873
    # [1/s] null-space pull of the joints towards the grasp configuration (Drake's
    # joint_centering_gain); 0: the minimum-norm solution in the null space, as J^+
    centering_gain: float = 0.0


@dataclass
class OscPlanConfig:
    """Operational-space impedance (``osc``, Khatib): tau_ff = J^T Lambda (a_ref + Kp e + Kd
    e_dot) + the task-space part of the inner loop's damping, Lambda = (J M^-1 J^T)^-1 from
    the controller plant's M(q), q_ref = q."""

    # [rad/s] natural frequency of Q's translational error dynamics (Kp = wn^2, per unit
    # task-space mass: the same in every direction and configuration)
    wn_translation: float = 10.0
    wn_rotation: float = 10.0  # [rad/s] natural frequency of L7's orientation error dynamics
    zeta: float = 1.0  # [-] damping ratio of both (Kd = 2 zeta wn)
    # [-] fraction of the inner loop's joint damping (its task-space part J_bar^T D q_dot)
    # the plan adds back; 0: none (the joints' damping then drags Q behind its reference, as
    # it drags the impedance plan's, against a stiffer spring)
    damping_compensation: float = 1.0
    torque_limit: float = 20.0  # [N m] clip on tau_ff (the impedance plan's)


PLAN_SWEEP_DEG = math.degrees(math.radians(50.0) - math.atan2(0.041, 0.264))
"""The problem set's door rotation over the arc, angle_end - theta0 = 41.17 deg (station facts
§4)."""


@dataclass
class AdaptivePlanConfig:
    """The adaptive plan: opens the door knowing only the grasp (no hinge, radius or arc).

    It moves Q along the estimated tangent, yields to radial contact force, and stops when
    its own estimate of the door angle reaches ``target_angle``.
    """

    target_angle: float = PLAN_SWEEP_DEG  # [deg] door rotation to open, estimated online
    speed: float = 0.022  # [m/s] Q's planned speed along the estimated tangent
    ramp_time: float = 1.5  # [s] the speed ramps up from 0 over this time (smoothstep)
    approach_gain: float = 3.0  # [1/s] speed <= this x the estimated arc length left
    progress_gain: float = 10.0  # [1/s] speed += this x (planned - measured arc length)
    force_gain: float = 0.01  # [m/(N s)] radial admittance: velocity per newton
    force_target: float = 0.0  # [N] outward pull on the handle (may be negative)
    kz: float = 10.0  # [1/s] gain holding Q at its grasp height
    kw: float = 5.0  # [1/s] orientation gain (L7 turns with the estimated door yaw)
    # [rad/s] L7's yaw reference follows the estimated door yaw at most this fast: the
    # estimate jumps from 0 to the swept angle when the hinge fit becomes trusted.
    yaw_rate_limit: float = 0.2
    joint_speed_limit: float = 1.0  # [rad/s] clip on q_dot
    min_sagitta: float = 0.001  # [m] the hinge fit is trusted once Q's path bulges this much
    velocity_time_constant: float = 0.1  # [s] low-pass of Q's velocity direction
    min_speed: float = 0.005  # [m/s] slower motion does not update the direction


@dataclass
class Scenario:
    """Everything one episode needs."""

    # one of CONTROLLERS, or a plug-in: FILE.py:NAME, MODULE:NAME or an installed plug-in's
    # name (docs/guides/controllers.md; a relative FILE is relative to this YAML file)
    controller: str = "velocity"
    doors: str = "closed"  # one of DOOR_STATES; sets the initial hinge angles
    door_angles: list[float] | None = None  # [rad] (left, right); None: from `doors`
    station: StationConfig = field(default_factory=StationConfig)
    timeline: TimelineConfig = field(default_factory=TimelineConfig)
    arc: ArcConfig = field(default_factory=ArcConfig)
    ik: IkConfig = field(default_factory=IkConfig)
    velocity: VelocityPlanConfig = field(default_factory=VelocityPlanConfig)
    impedance: ImpedancePlanConfig = field(default_factory=ImpedancePlanConfig)
    adaptive: AdaptivePlanConfig = field(default_factory=AdaptivePlanConfig)
    diffik: DiffIkPlanConfig = field(default_factory=DiffIkPlanConfig)
    osc: OscPlanConfig = field(default_factory=OscPlanConfig)

    def initial_door_angles(self) -> tuple[float, float]:
        """Initial (left, right) hinge angles [rad]."""
        if self.door_angles is not None:
            return (float(self.door_angles[0]), float(self.door_angles[1]))
        return DOOR_ANGLES[self.doors]


ARM_PRESET = """\
station:
  time_step: 0.0025
  inner_loop: {kind: kuka_joint_impedance}
  driver: {timing: kuka_driver}
  safety: {enabled: true}
"""
"""The lab arm preset's fields (``examples/kuka_arm.yaml`` sets the same on the defaults, with
KUKA's gains written out): kuka_driver's cycle, KUKA's joint impedance, a 2.5 ms plant step
(two per cycle) and the real run's safety limits at every tick."""


def arm_preset(base: Scenario | None = None) -> Scenario:
    """``base`` (default: the defaults) as the lab's arm: :data:`ARM_PRESET` on a copy."""
    import copy

    return update_scenario(copy.deepcopy(base) if base is not None else Scenario(), ARM_PRESET)


def load_scenario(path: str | Path, *, defaults: Scenario | None = None) -> Scenario:
    """Loads and validates a scenario from a YAML file.

    Args:
        path: YAML file; keys it leaves out keep the defaults.
        defaults: Values for the keys the file leaves out (default: ``Scenario()``).

    Raises:
        ConfigError: The file is missing, is not valid YAML, has unknown keys, wrong types or
            out-of-range values (the message names the file and the dotted field).
    """
    path = Path(path)
    text = read_text_file(path, what="config file")
    try:
        scenario = update_scenario(defaults or Scenario(), text)
    except ConfigError as e:
        raise ConfigError(f"config file {str(path)!r}: {e}") from None
    data = load_yaml(text)
    if isinstance(data, dict) and isinstance(data.get("controller"), str):
        # A plug-in's relative FILE is the YAML's neighbour, from any working directory.
        scenario.controller = absolute_controller(data["controller"], path.parent)
    return scenario


def update_scenario(scenario: Scenario, document: str) -> Scenario:
    """Returns ``scenario`` updated by the keys of a YAML ``document``, validated.

    Raises:
        ConfigError: Invalid YAML, unknown keys, wrong types or out-of-range values.
    """
    # within doorlab.runtime.inputs' budget, so Drake's parse below is too
    data = load_yaml(document)
    if data is None:
        return validate(scenario)
    _check_shape(data, Scenario, "")
    try:
        updated = yaml_load_typed(schema=Scenario, data=document, defaults=scenario)
    except (RuntimeError, ValueError, TypeError) as e:  # not expected after _check_shape
        raise ConfigError(str(e).splitlines()[0] if str(e) else type(e).__name__) from None
    return validate(updated)


def _type_name(schema: object) -> str:
    if dataclasses.is_dataclass(schema):
        return "a mapping"
    return {float: "a number", int: "an integer", str: "a string", bool: "true or false"}.get(
        schema, str(schema)
    )


def _check_shape(data: object, schema: object, path: str) -> None:
    """Checks YAML data against the scenario's dataclass schema, naming the dotted field."""
    name = path or "the scenario"
    if dataclasses.is_dataclass(schema):
        if not isinstance(data, dict):
            raise ConfigError(f"{name} must be a mapping of fields, got {quote(data)}")
        fields = {f.name: f.type for f in dataclasses.fields(schema)}
        hints = typing.get_type_hints(schema)
        for key, value in data.items():
            dotted = f"{path}.{key}" if path else str(key)
            if key not in fields:
                raise ConfigError(
                    f"unknown field {quote(dotted)}; valid fields here: {', '.join(fields)}"
                )
            _check_shape(value, hints[key], dotted)
        return
    origin, args = typing.get_origin(schema), typing.get_args(schema)
    if origin in (typing.Union, types.UnionType):
        if data is None and type(None) in args:
            return
        (inner,) = [a for a in args if a is not type(None)]
        _check_shape(data, inner, path)
        return
    if origin is list:
        if not isinstance(data, list):
            raise ConfigError(f"{name} must be a list, got {quote(data)}")
        for i, item in enumerate(data):
            _check_shape(item, args[0], f"{path}[{i}]")
        return
    ok = {
        float: isinstance(data, (int, float)) and not isinstance(data, bool),
        int: isinstance(data, int) and not isinstance(data, bool),
        bool: isinstance(data, bool),
        str: isinstance(data, str),
    }.get(schema, True)
    if not ok:
        hint = ""
        if schema is float and isinstance(data, str):
            spelled = yaml_float_spelling(data)
            if spelled is not None:
                hint = f" (YAML reads {quote_text(data)} as text: write {spelled})"
            elif data.strip().lower().lstrip("+-.") in ("nan", "inf", "infinity"):
                hint = " (it must be a finite number)"
        raise ConfigError(f"{name} must be {_type_name(schema)}, got {quote(data)}{hint}")


def validate(scenario: Scenario) -> Scenario:
    """Checks every field's type and range.

    Returns:
        The same scenario, for chaining.

    Raises:
        ConfigError: Naming the first offending field and its valid range.
    """
    check(isinstance(scenario, Scenario), f"expected a Scenario, got {type(scenario).__name__}")
    controller_spec(scenario.controller, CONTROLLERS)  # its syntax; a plug-in loads when it runs
    choice("doors", scenario.doors, DOOR_STATES)
    if scenario.door_angles is not None:
        angles = scenario.door_angles
        check(
            isinstance(angles, (list, tuple))
            and len(angles) == 2
            and all(isinstance(a, (int, float)) and math.isfinite(a) for a in angles),
            f"door_angles must be two finite numbers [rad] (left, right), got {quote(angles)}",
        )
        for name, value, (lo, hi) in (
            ("door_angles[0] (left)", angles[0], LEFT_HINGE_RANGE),
            ("door_angles[1] (right)", angles[1], RIGHT_HINGE_RANGE),
        ):
            check(
                lo <= value <= hi, f"{name} must be in [{lo:.4f}, {hi:.4f}] rad, got {quote(value)}"
            )

    station = scenario.station
    positive("station.time_step", station.time_step)
    choice("station.contact_approximation", station.contact_approximation, CONTACT_APPROXIMATIONS)
    missing = missing_contact_approximation(station.contact_approximation)
    check(missing is None, str(missing))  # tamsi on Drake >= 1.57
    position = station.cupboard_position
    check(
        isinstance(position, (list, tuple))
        and len(position) == 3
        and all(isinstance(v, (int, float)) and abs(v) <= 10.0 for v in position),
        f"station.cupboard_position must be three numbers [m] within +-10 m, got {quote(position)}",
    )
    yaw = station.cupboard_yaw_error
    check(
        isinstance(yaw, (int, float)) and math.isfinite(yaw) and abs(yaw) <= MAX_CUPBOARD_YAW_ERROR,
        f"station.cupboard_yaw_error must be a number in [-{MAX_CUPBOARD_YAW_ERROR:.4f}, "
        f"{MAX_CUPBOARD_YAW_ERROR:.4f}] rad (+-45 deg), got {quote(yaw)}",
    )
    validate_position_error(station.cupboard_position_error)
    non_negative("station.hinge_damping", station.hinge_damping)
    non_negative("station.friction", station.friction)
    loop = station.inner_loop
    choice("station.inner_loop.kind", loop.kind, INNER_LOOPS)
    gains("station.inner_loop.kq", loop.kq, allow_zero=False)
    gains("station.inner_loop.dq", loop.dq, allow_zero=True)
    non_negative("station.inner_loop.dq_scale", loop.dq_scale)
    for name in ("id_kp", "id_kd"):
        positive(f"station.inner_loop.{name}", getattr(loop, name))
    non_negative("station.inner_loop.id_ki", loop.id_ki)
    check(
        not (station.contact_approximation == "tamsi" and loop.kind == "implicit_pd"),
        "station.contact_approximation 'tamsi' cannot integrate PD actuators (implicit_pd); "
        "use sap, lagged or similar, or station.inner_loop.kind: stiffness or inverse_dynamics",
    )
    gripper = station.gripper
    for name in ("kp", "force_limit"):
        positive(f"station.gripper.{name}", getattr(gripper, name))
    non_negative("station.gripper.kd", gripper.kd)
    for name in ("initial_width", "approach_width", "grasp_width"):
        value = getattr(gripper, name)
        check(
            isinstance(value, (int, float)) and 0.0 <= value <= 0.11,
            f"station.gripper.{name} must be in [0, 0.11] m (finger travel), got {quote(value)}",
        )

    validate_safety(station.safety)
    validate_kuka(loop, station.driver, scenario.timeline)
    validate_arm_model(station.arm, station.time_step)

    check(
        station.time_step >= MIN_TIME_STEP,
        f"station.time_step must be >= {MIN_TIME_STEP} s, got {quote(station.time_step)} "
        "(200x finer than the original's 2 ms; the default episode would be 2.4 million steps)",
    )
    validate_timeline(scenario)

    angle_end = scenario.arc.angle_end_deg
    check(
        isinstance(angle_end, (int, float)) and 15.0 <= angle_end <= 90.0,
        f"arc.angle_end_deg must be in [15, 90] deg, got {quote(angle_end)}",
    )
    ik = scenario.ik
    check(
        isinstance(ik.knots, int) and not isinstance(ik.knots, bool) and 2 <= ik.knots <= 100,
        f"ik.knots must be an integer in [2, 100], got {quote(ik.knots)}",
    )
    choice("ik.objective", ik.objective, IK_OBJECTIVES)
    for name in ("position_tolerance", "theta_bound", "grasp_position_tolerance"):
        positive(f"ik.{name}", getattr(ik, name))
    offset = ik.grasp_offset
    check(
        isinstance(offset, (list, tuple))
        and len(offset) == 3
        and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) <= MAX_GRASP_OFFSET
            for v in offset
        ),
        f"ik.grasp_offset must be three numbers [m] within +-{MAX_GRASP_OFFSET} m, "
        f"got {quote(offset)}",
    )
    choice("velocity.lead", scenario.velocity.lead, VELOCITY_LEADS)
    for section in ("velocity", "impedance", "diffik", "osc"):
        for f in dataclasses.fields(getattr(scenario, section)):
            value = getattr(getattr(scenario, section), f.name)
            if f.name in ("centering_gain", "damping_compensation"):
                non_negative(f"{section}.{f.name}", value)
            elif f.name != "lead":
                positive(f"{section}.{f.name}", value)
    check(
        scenario.osc.damping_compensation <= 1.0,
        "osc.damping_compensation must be in [0, 1] (a fraction of the inner loop's damping), "
        f"got {quote(scenario.osc.damping_compensation)}",
    )
    check(
        scenario.diffik.joint_limit_margin < 0.5,
        "diffik.joint_limit_margin must be in (0, 0.5) rad, got "
        f"{quote(scenario.diffik.joint_limit_margin)}",
    )
    adaptive = scenario.adaptive
    for f in dataclasses.fields(adaptive):
        value = getattr(adaptive, f.name)
        if f.name == "force_target":
            check(
                isinstance(value, (int, float)) and math.isfinite(value),
                f"adaptive.force_target must be a finite number [N], got {quote(value)}",
            )
        else:
            positive(f"adaptive.{f.name}", value)
    for name in ("ramp_time", "velocity_time_constant"):  # durations within the arc plan
        value = getattr(adaptive, name)
        check(
            value <= MAX_EPISODE_DURATION,
            f"adaptive.{name} must be at most {MAX_EPISODE_DURATION:g} s (the longest "
            f"timeline), got {quote(value)}",
        )
    check(
        adaptive.target_angle < 90.0,
        f"adaptive.target_angle must be in (0, 90) deg, got {quote(adaptive.target_angle)}",
    )
    return scenario
