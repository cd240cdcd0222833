"""The simulated cell: iiwa7 + WSG-50 + cupboard, with the robot's inner loop, as one Diagram.

The station exports stable, named ports in the spirit of the original ManipulationStation:

inputs
    ``iiwa_position`` (7) q_ref [rad], ``iiwa_feedforward_torque`` (7) tau_ff [N m],
    ``wsg_position`` (1) finger separation setpoint [m], ``wsg_force_limit`` (1) [N].
outputs
    ``iiwa_position_commanded`` (7), ``iiwa_position_measured`` (7) [rad],
    ``iiwa_velocity_estimated`` (7) [rad/s], ``iiwa_state`` (14) both as [q; v],
    ``iiwa_torque_commanded`` (7) [N m] (the torque the joints receive: the actuators'
    after saturation plus, for ``stiffness``, the joints' damping -(Dq + h Kq) qdot),
    ``iiwa_torque_external`` (7) [N m] (generalized contact forces on the arm joints),
    ``wsg_state_measured`` (2) separation [m] and its rate [m/s],
    ``wsg_force_measured`` (1) the fingers' grip force [N] (the gripper controller's),
    ``plant_state`` (the whole plant's [q; v]), ``door_angles`` (2) left/right hinge [rad].

The inner loop is built from Drake's C++ systems only (no Python per simulation step):

- ``stiffness`` (the problem set's law) tau = Kq (q_ref - q) - Dq qdot + g(q) + tau_ff: the spring
  and g(q) from a ``JointStiffnessController`` (kd = 0) on the controller plant, plus tau_ff,
  clamped at the effort limits (``Saturation``), one explicit torque per step; the damping
  -(Dq + h Kq) qdot is the arm joints' own viscous damping, which SAP integrates implicitly
  (stable at any step, and SAP has no PD constraint to solve). The h Kq term is the one SAP's
  implicit PD added (see ``InnerLoopConfig``), so both loops give the same physics.
- ``implicit_pd`` (the design before issue 9, for comparison): the plant's own PD actuators
  (Kq, Dq) with desired state (q_ref, 0), SAP evaluating the spring at the step's end (so
  they damp with Dq + h Kq), plus g(q) from ``InverseDynamics`` and tau_ff.
- ``kuka_joint_impedance`` (the lab arm, KUKA's joint impedance): the ``stiffness`` law with
  KUKA's stiffness and damping (:func:`loop_gains`).
- ``inverse_dynamics`` (the original station): ``InverseDynamicsController`` PID through M(q),
  the desired velocity from a discrete derivative of q_ref, plus tau_ff, then ``Saturation``.

Gravity compensation and the original's inverse dynamics use a separate *controller plant*
(the arm with the gripper lumped into L7); they never read the simulation plant's context.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache

import numpy as np
from pydrake.geometry import (
    CollisionFilterDeclaration,
    GeometrySet,
    Meshcat,
    MeshcatVisualizer,
    MeshcatVisualizerParams,
    Role,
    RoleAssign,
    SceneGraph,
)
from pydrake.manipulation import MakeMultibodyStateToWsgStateSystem, SchunkWsgPositionController
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import (
    AddMultibodyPlant,
    CoulombFriction,
    MultibodyPlant,
    MultibodyPlantConfig,
)
from pydrake.multibody.tree import ModelInstanceIndex, PdControllerGains, SpatialInertia
from pydrake.systems.controllers import (
    InverseDynamics,
    InverseDynamicsController,
    JointStiffnessController,
)
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import (
    Adder,
    ConstantVectorSource,
    Demultiplexer,
    MatrixGain,
    Multiplexer,
    PassThrough,
    Saturation,
    StateInterpolatorWithDiscreteDerivative,
)

from doorlab.cell import models
from doorlab.cell.frames import (
    ARM_JOINTS,
    CUPBOARD_MODEL,
    FINGER_JOINTS,
    GRIPPER_BODY,
    L7_FRAME,
    LEFT_HANDLE_FRAME,
    LEFT_HINGE,
    RIGHT_HINGE,
)
from doorlab.config import InnerLoopConfig, StationConfig
from doorlab.constants import JOINT_TORQUE_LIMITS, NUM_JOINTS, Q_GRASP
from doorlab.kuka import DRIVER_HOLD_DAMPING, kuka_damping

GRIPPER_LUMPED_BODY = "wsg_lumped"
"""Name of the rigid body that stands for the whole gripper in the controller plant."""


@dataclass(frozen=True)
class Station:
    """A built station.

    Attributes:
        diagram: The Diagram with the exported ports listed in the module docstring.
        plant: The simulation plant (do not hand its context to controllers).
        scene_graph: The SceneGraph of the simulation plant.
        iiwa, wsg, cupboard: Model instances of the simulation plant.
        interpolator: The q_ref differentiator of the ``inverse_dynamics`` loop (None for
            the other loops); its state must be set to the initial q.
    """

    diagram: Diagram
    plant: MultibodyPlant
    scene_graph: SceneGraph
    iiwa: ModelInstanceIndex
    wsg: ModelInstanceIndex
    cupboard: ModelInstanceIndex
    interpolator: StateInterpolatorWithDiscreteDerivative | None
    controller_plant: MultibodyPlant


def _plant_config(config: StationConfig) -> MultibodyPlantConfig:
    return MultibodyPlantConfig(
        time_step=config.time_step,
        contact_model="point",
        discrete_contact_approximation=config.contact_approximation,
    )


def add_cell(
    plant: MultibodyPlant,
    *,
    arm_collision: bool = False,
    p_WC: Sequence[float] | None = None,
    yaw_error: float = 0.0,
) -> tuple[ModelInstanceIndex, ...]:
    """Adds the arm, gripper, cupboard and table to ``plant`` and welds them (before Finalize).

    Args:
        plant: A plant that is not finalized yet.
        arm_collision: Give the arm collision capsules (the original arm had none).
        p_WC: Where the (believed) cupboard frame C sits in W (3,) [m]; its orientation is
            RotZ(pi) and the table follows it. Default: the original station's placement.
        yaw_error: The cupboard actually stands turned by this angle [rad] about the left
            handle's vertical axis (see :func:`cupboard_turned_about_handle`); the table
            does not turn.

    Returns:
        The model instances (iiwa, wsg, cupboard).
    """
    parser = Parser(plant)
    models.add_package(parser)
    iiwa = models.add_model(parser, "iiwa7")
    wsg = models.add_model(parser, "wsg_50")
    cupboard = models.add_model(parser, "cupboard")
    table = models.add_model(parser, "table")
    world = plant.world_frame()
    plant.WeldFrames(world, plant.GetFrameByName("iiwa_link_0", iiwa), RigidTransform())
    plant.WeldFrames(
        plant.GetFrameByName(L7_FRAME, iiwa), plant.GetFrameByName(GRIPPER_BODY, wsg), models.X_L7G
    )
    X_WC, X_W_table = models.X_WC, models.X_W_TABLE
    if p_WC is not None:
        p_WC = np.asarray(p_WC, dtype=float)
        X_WC = RigidTransform(models.X_WC.rotation(), p_WC)
        X_W_table = RigidTransform(
            models.X_W_TABLE.translation() + p_WC - models.X_WC.translation()
        )
    if yaw_error:
        X_WC = cupboard_turned_about_handle(X_WC, yaw_error)
    plant.WeldFrames(world, plant.GetFrameByName("cupboard_body", cupboard), X_WC)
    plant.WeldFrames(world, plant.GetFrameByName("table_top", table), X_W_table)
    if arm_collision:
        models.add_arm_collision(plant, iiwa)
    return iiwa, wsg, cupboard


@cache
def _p_C_left_handle() -> tuple[float, float, float]:
    """The left handle's centre in C with the door closed [m], read from the model."""
    plant = MultibodyPlant(0.0)
    parser = Parser(plant)
    models.add_package(parser)
    cupboard = models.add_model(parser, "cupboard")
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("cupboard_body", cupboard))
    plant.Finalize()
    context = plant.CreateDefaultContext()
    plant.GetJointByName(LEFT_HINGE, cupboard).set_angle(context, 0.0)
    p = plant.GetFrameByName(LEFT_HANDLE_FRAME, cupboard).CalcPoseInWorld(context).translation()
    return (float(p[0]), float(p[1]), float(p[2]))


def true_cupboard_position(config: StationConfig) -> list[float]:
    """Where the cupboard frame C really is in W (3,) [m]: the believed
    ``cupboard_position`` plus ``cupboard_position_error`` (before the yaw error's turn about
    the handle, :func:`cupboard_turned_about_handle`)."""
    error = config.cupboard_position_error
    return [float(p + e) for p, e in zip(config.cupboard_position, error, strict=True)]


def cupboard_turned_about_handle(X_WC: RigidTransform, yaw: float) -> RigidTransform:
    """The cupboard pose X_WC turned by ``yaw`` [rad] about the closed left handle's vertical axis.

    The left handle's centre stays where it is (a camera would find it there); the hinge,
    0.267 m away, moves by 2 r sin(yaw / 2) (4.7 cm at 10 deg). Positive yaw is
    counter-clockwise seen from above (about +z of W).
    """
    p_W_handle = X_WC @ np.array(_p_C_left_handle())
    X_W_pivot = RigidTransform(p_W_handle)
    X_pivot_turned = RigidTransform(RotationMatrix.MakeZRotation(yaw))
    return X_W_pivot @ X_pivot_turned @ X_W_pivot.inverse() @ X_WC


def _filter_scene_collisions(plant: MultibodyPlant, scene_graph: SceneGraph) -> None:
    """Lets the scene's bodies (doors, cupboard, table) collide only with the robot.

    The doors rest on the table and the cupboard (their slabs touch it at every angle) and
    never need contact among themselves: dropping those pairs removes contact queries the
    result does not depend on.
    """
    scene = [plant.GetModelInstanceByName(name) for name in (CUPBOARD_MODEL, "table")]
    bodies = [b for instance in scene for b in plant.GetBodyIndices(instance)]
    scene_geometry = GeometrySet([plant.GetBodyFrameIdOrThrow(b) for b in bodies])
    scene_graph.collision_filter_manager().Apply(
        CollisionFilterDeclaration().ExcludeWithin(scene_geometry)
    )


WORKING_GEOMETRIES = (
    ("left_door", f"{CUPBOARD_MODEL}::slab_collision"),
    ("left_door", f"{CUPBOARD_MODEL}::handle_collision"),
)
"""(body, geometry name) of the cupboard collision geometries the experiments touch: the left
door that the gripper opens. Without arm collision only these keep their proximity role."""


def _drop_untouched_collisions(plant: MultibodyPlant, scene_graph: SceneGraph) -> None:
    """Removes the proximity role of the cupboard and table geometries nothing touches.

    With a collision-free arm only the gripper can touch the scene, and it only ever touches
    the left door (its pads on the handle): the carcass, the right door and the table cost
    contact queries on every step (3-10 %) and change no result.
    """
    inspector = scene_graph.model_inspector()
    source_id = plant.get_source_id()
    keep = set()
    for body_name, geometry_name in WORKING_GEOMETRIES:
        frame_id = plant.GetBodyFrameIdOrThrow(plant.GetBodyByName(body_name).index())
        keep.add(inspector.GetGeometryIdByName(frame_id, Role.kProximity, geometry_name))
    for name in (CUPBOARD_MODEL, "table"):
        for body in plant.GetBodyIndices(plant.GetModelInstanceByName(name)):
            for geometry_id in plant.GetCollisionGeometriesForBody(plant.get_body(body)):
                if geometry_id not in keep:
                    scene_graph.RemoveRole(source_id, geometry_id, Role.kProximity)


def gripper_spatial_inertia(finger_separation: float = 0.01) -> SpatialInertia:
    """Spatial inertia of the whole WSG-50 (body and fingers) about G's origin, in G.

    Args:
        finger_separation: Separation of the pads [m] at which the fingers are lumped.
    """
    plant = MultibodyPlant(0.0)
    parser = Parser(plant)
    models.add_package(parser)
    wsg = models.add_model(parser, "wsg_50")
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName(GRIPPER_BODY, wsg))
    plant.Finalize()
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, wsg, [-finger_separation / 2, finger_separation / 2])
    bodies = plant.GetBodyIndices(wsg)
    return plant.CalcSpatialInertia(context, plant.GetFrameByName(GRIPPER_BODY, wsg), bodies)


@cache
def make_controller_plant(load_mass: float | None = None) -> MultibodyPlant:
    """The controllers' model: the arm with the gripper lumped into one body welded at X_L7G.

    Built once per process and shared (it is finalized, so no user can change it): the
    inner loop, the plans and the metrics each keep their own Context of it.

    Args:
        load_mass: The lumped body's mass [kg] (its centre of mass and its inertia per kg
            stay the gripper's): the load data KUKA's model carries
            (``station.arm.load_mass``); None: the gripper's own.

    Returns:
        A finalized continuous MultibodyPlant with 7 positions (the arm joints).
    """
    plant = MultibodyPlant(0.0)
    parser = Parser(plant)
    models.add_package(parser)
    iiwa = models.add_model(parser, "iiwa7")
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("iiwa_link_0", iiwa))
    inertia = gripper_spatial_inertia()
    if load_mass is not None:
        inertia = SpatialInertia(
            load_mass, inertia.get_com(), inertia.get_unit_inertia(), skip_validity_check=True
        )
    lumped = plant.AddRigidBody(GRIPPER_LUMPED_BODY, iiwa, inertia)
    plant.WeldFrames(plant.GetFrameByName(L7_FRAME, iiwa), lumped.body_frame(), models.X_L7G)
    plant.Finalize()
    return plant


def _set_friction(plant: MultibodyPlant, scene_graph: SceneGraph, friction: float) -> None:
    """Replaces the Coulomb friction of every collision geometry of the plant."""
    inspector = scene_graph.model_inspector()
    source_id = plant.get_source_id()
    for geometry_id in inspector.GetAllGeometryIds(Role.kProximity):
        props = inspector.GetProximityProperties(geometry_id)
        new_props = type(props)(props)
        new_props.UpdateProperty(
            "material", "coulomb_friction", CoulombFriction(friction, friction)
        )
        scene_graph.AssignRole(source_id, geometry_id, new_props, RoleAssign.kReplace)


STIFFNESS_LOOPS = ("stiffness", "kuka_joint_impedance")
"""Inner loops of the law tau = Kq (q_ref - q) - Dq qdot + g(q) + tau_ff (:func:`loop_gains`)."""


@cache
def grasp_pose_inertia(rotor: bool = True) -> np.ndarray:
    """The controllers' model's joint inertia M_ii at the grasp pose Q_GRASP (7,) [kg m^2]
    (links, lumped gripper, and with ``rotor`` the motors' reflected inertia 160^2 x the
    rotor's; without, the link-side inertia DLR's design tunes for)."""
    plant = make_controller_plant()
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, Q_GRASP)
    if not rotor:
        for index in plant.GetJointActuatorIndices():
            plant.get_joint_actuator(index).SetRotorInertia(context, 0.0)
    inertia = np.diag(plant.CalcMassMatrix(context)).copy()
    inertia.flags.writeable = False
    return inertia


def kuka_joint_damping(loop: InnerLoopConfig) -> np.ndarray:
    """KUKA's joint damping in N m s/rad (7,), as ``loop.kuka_damping_model`` says:
    ``rotor_link`` 2 d sqrt(K M_ii) with M_ii at the grasp pose, rotors included; ``link``
    the same with the link-side M_ii; ``driver_kd`` kuka_driver's torque-only hold
    (:data:`doorlab.kuka.DRIVER_HOLD_DAMPING`); ``values`` ``kuka_damping_values``."""
    model = loop.kuka_damping_model
    kq = np.asarray(loop.kuka_stiffness, float)
    if model == "values":
        return np.asarray(loop.kuka_damping_values, float)
    if model == "driver_kd":
        return np.asarray(DRIVER_HOLD_DAMPING, float)
    return kuka_damping(kq, loop.kuka_damping, grasp_pose_inertia(rotor=model == "rotor_link"))


def loop_gains(loop: InnerLoopConfig) -> tuple[np.ndarray, np.ndarray]:
    """Kq [N m/rad] and Dq [N m s/rad] (7,) of a :data:`STIFFNESS_LOOPS` inner loop.

    ``stiffness``: ``kq`` and ``dq`` x ``dq_scale``. ``kuka_joint_impedance``:
    ``kuka_stiffness`` and KUKA's damping in N m s/rad (:func:`kuka_joint_damping`).
    """
    if loop.kind == "kuka_joint_impedance":
        return np.asarray(loop.kuka_stiffness, float), kuka_joint_damping(loop)
    return np.asarray(loop.kq, float), np.asarray(loop.dq, float) * loop.dq_scale


def joint_damping(config: StationConfig) -> np.ndarray:
    """The damping that acts on each arm joint with a stiffness loop, (7,) [N m s/rad].

    doorlab's ``stiffness`` loop: Dq + h Kq (:func:`loop_gains`; see
    :class:`doorlab.config.InnerLoopConfig`): the h Kq term is what SAP's implicit PD actuators
    added by evaluating the spring at the step's end, kept so that both loops (and the gains
    derived under them) give the same physics. KUKA's loop: Dq alone, so that
    ``station.time_step`` does not change KUKA's physics (the explicit spring stays stable:
    docs/guides/real-arm.md, "The simulator's step").
    """
    kq, dq = loop_gains(config.inner_loop)
    if config.inner_loop.kind == "kuka_joint_impedance":
        return dq
    return dq + config.time_step * kq


WSG_FIRMWARE_PERIOD = 0.05
"""The WSG controller's setpoint derivative period [s] (Drake's default: the WSG firmware's
update rate)."""


def build_station(
    config: StationConfig,
    *,
    meshcat: Meshcat | None = None,
    gripper_period: float = WSG_FIRMWARE_PERIOD,
) -> Station:
    """Builds the station Diagram.

    Args:
        config: Physics, inner loop and gripper settings (validated by the caller).
        meshcat: When given, a MeshcatVisualizer draws the illustration geometry live.
        gripper_period: The gripper controller differentiates its setpoint at this period
            [s] (:mod:`doorlab.cell.arm_cell` uses its 5 ms cycle).

    Returns:
        The built station.

    """
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(_plant_config(config), builder)
    plant.set_name("plant")
    iiwa, wsg, cupboard = add_cell(
        plant,
        arm_collision=config.arm_collision,
        p_WC=true_cupboard_position(config),
        yaw_error=config.cupboard_yaw_error,
    )
    for hinge in (LEFT_HINGE, RIGHT_HINGE):
        plant.GetJointByName(hinge, cupboard).set_default_damping(config.hinge_damping)
    kind = config.inner_loop.kind
    kq, dq = loop_gains(config.inner_loop)
    damping = joint_damping(config)
    arm_actuators = [plant.GetJointActuatorByName(name, iiwa) for name in ARM_JOINTS]
    for actuator, limit in zip(arm_actuators, JOINT_TORQUE_LIMITS, strict=True):
        actuator.set_effort_limit(float(limit))
    if kind in STIFFNESS_LOOPS:
        # The damping half of the law is the joints' own viscous damping: SAP integrates it
        # implicitly (stable at any step), and no PD constraint is left for the solver.
        for name, d in zip(ARM_JOINTS, damping, strict=True):
            plant.GetJointByName(name, iiwa).set_default_damping(float(d))
    elif kind == "implicit_pd":
        for actuator, p, d in zip(arm_actuators, kq, dq, strict=True):
            actuator.set_controller_gains(PdControllerGains(p=float(p), d=float(d)))
    plant.Finalize()
    _set_friction(plant, scene_graph, config.friction)
    _filter_scene_collisions(plant, scene_graph)
    if not (config.arm_collision or config.scene_collision):
        _drop_untouched_collisions(plant, scene_graph)

    controller_plant = make_controller_plant()

    def add(system, name: str):
        system.set_name(name)
        return builder.AddSystem(system)

    # Measured arm state.
    arm_state = plant.get_state_output_port(iiwa)
    demux = add(Demultiplexer(2 * NUM_JOINTS, NUM_JOINTS), "iiwa_state_demux")
    builder.Connect(arm_state, demux.get_input_port(0))

    # Commands.
    q_ref = add(PassThrough(NUM_JOINTS), "iiwa_position")
    tau_ff = add(PassThrough(NUM_JOINTS), "iiwa_feedforward_torque")
    builder.ExportInput(q_ref.get_input_port(), "iiwa_position")
    builder.ExportInput(tau_ff.get_input_port(), "iiwa_feedforward_torque")
    builder.ExportOutput(q_ref.get_output_port(), "iiwa_position_commanded")

    interpolator = None
    if kind in STIFFNESS_LOOPS:
        # tau = sat(Kq (q_ref - q) + g(q) + tau_ff) [actuation input, explicit: evaluated at
        # the step's start] - Dq qdot [joint damping, implicit in SAP].
        desired = add(Multiplexer([NUM_JOINTS, NUM_JOINTS]), "desired_state")
        zero_velocity = add(ConstantVectorSource(np.zeros(NUM_JOINTS)), "zero_velocity")
        builder.Connect(q_ref.get_output_port(), desired.get_input_port(0))
        builder.Connect(zero_velocity.get_output_port(), desired.get_input_port(1))
        # KUKA's gravity compensation carries its load data (station.arm.load_mass).
        loop_model = controller_plant
        if kind == "kuka_joint_impedance" and config.arm.load_mass is not None:
            loop_model = make_controller_plant(config.arm.load_mass)
        spring = add(
            JointStiffnessController(loop_model, kq, np.zeros(NUM_JOINTS)),
            "stiffness_plus_gravity",
        )
        builder.Connect(arm_state, spring.get_input_port_estimated_state())
        builder.Connect(desired.get_output_port(), spring.get_input_port_desired_state())
        adder = add(Adder(2, NUM_JOINTS), "stiffness_plus_feedforward")
        builder.Connect(spring.get_output_port_actuation(), adder.get_input_port(0))
        builder.Connect(tau_ff.get_output_port(), adder.get_input_port(1))
        saturation = add(Saturation(-JOINT_TORQUE_LIMITS, JOINT_TORQUE_LIMITS), "torque_saturation")
        builder.Connect(adder.get_output_port(), saturation.get_input_port())
        if kind == "kuka_joint_impedance" and config.arm.friction():
            # The joints' friction, less what KUKA's friction observer cancels (imported here:
            # the student's view of the problem set holds the station, not the arm's model).
            from doorlab.cell.arm_model import add_joint_friction

            friction = add_joint_friction(
                builder,
                demux.get_output_port(0),
                demux.get_output_port(1),
                q_ref.get_output_port(),
                config.arm,
                inertia=grasp_pose_inertia(),
                h=config.time_step,
            )
            actuation = add(Adder(2, NUM_JOINTS), "motor_plus_friction")
            builder.Connect(saturation.get_output_port(), actuation.get_input_port(0))
            builder.Connect(friction, actuation.get_input_port(1))
            builder.Connect(actuation.get_output_port(), plant.get_actuation_input_port(iiwa))
        else:
            builder.Connect(saturation.get_output_port(), plant.get_actuation_input_port(iiwa))
        # The torque the joints receive includes the damping the joints apply themselves.
        damping_torque = add(MatrixGain(-np.diag(damping)), "joint_damping_torque")
        builder.Connect(demux.get_output_port(1), damping_torque.get_input_port())
        commanded = add(Adder(2, NUM_JOINTS), "torque_commanded")
        builder.Connect(saturation.get_output_port(), commanded.get_input_port(0))
        builder.Connect(damping_torque.get_output_port(), commanded.get_input_port(1))
        builder.ExportOutput(commanded.get_output_port(), "iiwa_torque_commanded")
    elif kind == "implicit_pd":
        # The 353b732 design: the plant's PD actuators with desired state (q_ref, 0) + g(q) +
        # tau_ff; SAP adds one PD constraint per joint.
        gravity = add(
            InverseDynamics(
                controller_plant, InverseDynamics.InverseDynamicsMode.kGravityCompensation
            ),
            "gravity_compensation",
        )
        builder.Connect(arm_state, gravity.get_input_port_estimated_state())
        desired = add(Multiplexer([NUM_JOINTS, NUM_JOINTS]), "desired_state")
        zero_velocity = add(ConstantVectorSource(np.zeros(NUM_JOINTS)), "zero_velocity")
        builder.Connect(q_ref.get_output_port(), desired.get_input_port(0))
        builder.Connect(zero_velocity.get_output_port(), desired.get_input_port(1))
        builder.Connect(desired.get_output_port(), plant.get_desired_state_input_port(iiwa))
        adder = add(Adder(2, NUM_JOINTS), "gravity_plus_feedforward")
        builder.Connect(gravity.get_output_port(), adder.get_input_port(0))
        builder.Connect(tau_ff.get_output_port(), adder.get_input_port(1))
        builder.Connect(adder.get_output_port(), plant.get_actuation_input_port(iiwa))
        builder.ExportOutput(plant.get_net_actuation_output_port(iiwa), "iiwa_torque_commanded")
    else:
        loop = config.inner_loop
        pid = add(
            InverseDynamicsController(
                controller_plant,
                kp=np.full(NUM_JOINTS, loop.id_kp),
                ki=np.full(NUM_JOINTS, loop.id_ki),
                kd=np.full(NUM_JOINTS, loop.id_kd),
                has_reference_acceleration=False,
            ),
            "inverse_dynamics_pid",
        )
        interpolator = add(
            StateInterpolatorWithDiscreteDerivative(
                NUM_JOINTS, config.time_step, suppress_initial_transient=True
            ),
            "desired_state_from_position",
        )
        builder.Connect(q_ref.get_output_port(), interpolator.get_input_port())
        builder.Connect(interpolator.get_output_port(), pid.get_input_port_desired_state())
        builder.Connect(arm_state, pid.get_input_port_estimated_state())
        adder = add(Adder(2, NUM_JOINTS), "pid_plus_feedforward")
        builder.Connect(pid.get_output_port_control(), adder.get_input_port(0))
        builder.Connect(tau_ff.get_output_port(), adder.get_input_port(1))
        saturation = add(Saturation(-JOINT_TORQUE_LIMITS, JOINT_TORQUE_LIMITS), "torque_saturation")
        builder.Connect(adder.get_output_port(), saturation.get_input_port())
        builder.Connect(saturation.get_output_port(), plant.get_actuation_input_port(iiwa))
        builder.ExportOutput(saturation.get_output_port(), "iiwa_torque_commanded")

    builder.ExportOutput(arm_state, "iiwa_state")
    builder.ExportOutput(demux.get_output_port(0), "iiwa_position_measured")
    builder.ExportOutput(demux.get_output_port(1), "iiwa_velocity_estimated")
    builder.ExportOutput(
        plant.get_generalized_contact_forces_output_port(iiwa), "iiwa_torque_external"
    )

    # Gripper: PD on the finger separation, force-limited (C++).
    gripper = config.gripper
    wsg_controller = add(
        SchunkWsgPositionController(
            time_step=gripper_period, kp_command=gripper.kp, kd_command=gripper.kd
        ),
        "wsg_controller",
    )
    builder.Connect(plant.get_state_output_port(wsg), wsg_controller.get_state_input_port())
    builder.Connect(
        wsg_controller.get_generalized_force_output_port(), plant.get_actuation_input_port(wsg)
    )
    builder.ExportInput(wsg_controller.get_desired_position_input_port(), "wsg_position")
    builder.ExportInput(wsg_controller.get_force_limit_input_port(), "wsg_force_limit")
    wsg_state = add(MakeMultibodyStateToWsgStateSystem(), "wsg_state")
    builder.Connect(plant.get_state_output_port(wsg), wsg_state.get_input_port())
    builder.ExportOutput(wsg_state.get_output_port(), "wsg_state_measured")
    builder.ExportOutput(wsg_controller.get_grip_force_output_port(), "wsg_force_measured")

    # Whole-plant state and the door hinge angles.
    builder.ExportOutput(plant.get_state_output_port(), "plant_state")
    selector = np.zeros((2, plant.num_multibody_states()))
    for row, hinge in enumerate((LEFT_HINGE, RIGHT_HINGE)):
        selector[row, plant.GetJointByName(hinge, cupboard).position_start()] = 1.0
    doors = add(MatrixGain(selector), "door_angles")
    builder.Connect(plant.get_state_output_port(), doors.get_input_port())
    builder.ExportOutput(doors.get_output_port(), "door_angles")

    if meshcat is not None:
        MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, MeshcatVisualizerParams())

    diagram = builder.Build()
    diagram.set_name("doorlab_station")
    return Station(diagram, plant, scene_graph, iiwa, wsg, cupboard, interpolator, controller_plant)


def initialize_cell(
    station: Station,
    root_context,
    *,
    q_initial: np.ndarray,
    gripper_width: float,
    door_angles: tuple[float, float],
) -> None:
    """Sets the station's initial state in ``root_context``, as an episode starts.

    Args:
        station: The built station (its diagram may be a subsystem of the context's root).
        root_context: The root Context that holds the station's.
        q_initial: Arm configuration (7,) [rad]; also the ``inverse_dynamics`` loop's
            differentiator state.
        gripper_width: Finger separation [m], the fingers symmetric about G.
        door_angles: (left, right) hinge angles [rad].
    """
    plant = station.plant
    plant_context = plant.GetMyMutableContextFromRoot(root_context)
    plant.SetPositions(plant_context, station.iiwa, q_initial)
    for joint_name, q in zip(FINGER_JOINTS, (-gripper_width / 2, gripper_width / 2), strict=True):
        plant.GetJointByName(joint_name, station.wsg).set_translation(plant_context, q)
    left, right = door_angles
    plant.GetJointByName(LEFT_HINGE, station.cupboard).set_angle(plant_context, left)
    plant.GetJointByName(RIGHT_HINGE, station.cupboard).set_angle(plant_context, right)
    if station.interpolator is not None:
        station.interpolator.set_initial_position(
            station.interpolator.GetMyMutableContextFromRoot(root_context), q_initial
        )
