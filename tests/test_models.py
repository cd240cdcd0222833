"""Tests of the station model files in ``doorlab.cell.models``.

The reference numbers below are copied from shared/reference/station_facts.md
(sections 1-3); the tests compare the SDF files against them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from pydrake.geometry import QueryObject, SceneGraph
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import (
    AddMultibodyPlantSceneGraph,
    MultibodyPlant,
)
from pydrake.multibody.tree import (
    FixedOffsetFrame,
    ModelInstanceIndex,
    RevoluteJoint,
    RotationalInertia,
    SpatialInertia,
)
from pydrake.systems.framework import Context, Diagram, DiagramBuilder

from doorlab.cell.models import (
    ARM_COLLISION_SHAPES,
    MODEL_NAMES,
    MODELS_DIR,
    PACKAGE_NAME,
    X_L7G,
    X_W_TABLE,
    X_WC,
    add_arm_collision,
    add_package,
    model_url,
)

# --- Reference data (station_facts.md section 1) ---------------------------
PI = np.pi
# (pose xyz at q=0, pose rpy at q=0, COM in link frame, mass, (Ixx, Iyy, Izz))
IIWA_LINKS = [
    ((0, 0, 0), (0, 0, 0), (-0.013, 0, 0.07), 3.863, (0.0141, 0.0171, 0.0178)),
    ((0, 0, 0.1575), (0, 0, 0), (0, -0.0347, 0.113), 2.7025, (0.0171, 0.0163, 0.006)),
    (
        (0, 0, 0.3405),
        (PI / 2, 0, -PI),
        (0, 0.0668, 0.0344),
        2.7258,
        (0.0170, 0.0061, 0.0162),
    ),
    ((0, 0, 0.5245), (0, 0, 0), (0, 0.0296, 0.1265), 3.175, (0.025, 0.0238, 0.0076)),
    ((0, 0, 0.74), (PI / 2, 0, 0), (0, 0.067, 0.034), 2.73, (0.017, 0.0061, 0.0162)),
    ((0, 0, 0.924), (0, 0, -PI), (0.0001, 0.021, 0.076), 1.69, (0.01, 0.0087, 0.00449)),
    (
        (0, 0, 1.1395),
        (PI / 2, 0, -PI),
        (0, 0.0026, 0.0005),
        1.8,
        (0.0051, 0.0049, 0.0035),
    ),
    ((0, 0, 1.22), (0, 0, 0), (0, 0, 0.0294), 0.4, (0.0004, 0.0004, 0.0005)),
]
# (axis in the model frame at q=0, position limit rad, max speed deg/s, torque N m)
IIWA_JOINTS = [
    ((0, 0, 1), 2.96706, 98, 176),
    ((0, 1, 0), 2.0944, 98, 176),
    ((0, 0, 1), 2.96706, 100, 110),
    ((0, -1, 0), 2.0944, 130, 110),
    ((0, 0, 1), 2.96706, 140, 110),
    ((0, 1, 0), 2.0944, 180, 40),
    ((0, 0, 1), 3.05433, 180, 40),
]
# Motor side of Drake's official iiwa7 description (station_facts.md section 1, issue 12): gear
# ratio and rotor inertia [kg m^2] of joints 1-7; Drake adds GEAR_RATIO^2 x rotor inertia.
GEAR_RATIO = 160.0
ROTOR_INERTIAS = (
    7.171875e-5,
    1.737109e-4,
    1.266406e-4,
    7.09765e-5,
    5.4375e-5,
    5.4765e-5,
    5.4375e-5,
)
REFLECTED_INERTIAS = (1.84, 4.45, 3.24, 1.82, 1.39, 1.40, 1.39)  # [kg m^2], rounded (issue 12)
Q_ZERO = np.zeros(7)
Q_HOME = np.array([0, -0.2136, 0, -2.094, 0, 0.463, 0])
Q0 = np.array([0, 0.6, 0, -1.75, 0, 1.0, 0])
Q_RANDOM = np.random.default_rng(20240601).uniform(-2.0, 2.0, 7)
TEST_POSES = [Q_ZERO, Q_HOME, Q0, Q_RANDOM]

# --- Reference data (station_facts.md sections 2 and 4) --------------------
WSG_BODY_MASS = 0.988882
WSG_BODY_BOX = (0.146, 0.0725, 0.049521)
FINGER_MASS = 0.05
FINGER_BOX = (0.016, 0.075, 0.02)
P_L7Q = np.array([0.0, 0.0, 0.214])

# --- Reference data (station_facts.md section 3) ---------------------------
P_W_LEFT_HINGE = np.array([0.7557, 0.2840, 0.4148])
P_W_RIGHT_HINGE = np.array([0.7557, -0.2840, 0.4148])
P_W_LEFT_HANDLE = np.array([0.7147, 0.0200, 0.4148])


@dataclass
class Station:
    """A plant with the four station models welded as the station does."""

    diagram: Diagram
    plant: MultibodyPlant
    scene_graph: SceneGraph
    context: Context
    iiwa: ModelInstanceIndex
    wsg: ModelInstanceIndex
    cupboard: ModelInstanceIndex
    table: ModelInstanceIndex

    @property
    def plant_context(self) -> Context:
        return self.plant.GetMyMutableContextFromRoot(self.context)

    def query(self) -> QueryObject:
        return self.plant.get_geometry_query_input_port().Eval(self.plant_context)


def build_station(arm_collision: bool = False) -> Station:
    """Parse the four models (strictly) and weld them like the station."""
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=0.0)
    parser = Parser(plant)
    parser.SetStrictParsing()
    add_package(parser)
    (iiwa,) = parser.AddModels(url=model_url("iiwa7"))
    (wsg,) = parser.AddModels(url=model_url("wsg_50"))
    (cupboard,) = parser.AddModels(url=model_url("cupboard"))
    (table,) = parser.AddModels(url=model_url("table"))
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("iiwa_link_0", iiwa))
    plant.WeldFrames(
        plant.GetFrameByName("iiwa_link_7", iiwa),
        plant.GetFrameByName("body", wsg),
        X_L7G,
    )
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("cupboard_body", cupboard), X_WC)
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("table_top", table), X_W_TABLE)
    if arm_collision:
        add_arm_collision(plant, iiwa)
    plant.Finalize()
    diagram = builder.Build()
    return Station(
        diagram,
        plant,
        scene_graph,
        diagram.CreateDefaultContext(),
        iiwa,
        wsg,
        cupboard,
        table,
    )


@pytest.fixture(scope="module")
def station() -> Station:
    return build_station()


@pytest.fixture(scope="module")
def station_arm_collision() -> Station:
    return build_station(arm_collision=True)


def load_iiwa_alone() -> tuple[MultibodyPlant, ModelInstanceIndex]:
    """The iiwa7.sdf model alone, link 0 welded at the world origin."""
    plant = MultibodyPlant(0.0)
    parser = Parser(plant)
    parser.SetStrictParsing()
    add_package(parser)
    (iiwa,) = parser.AddModels(url=model_url("iiwa7"))
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("iiwa_link_0", iiwa))
    plant.Finalize()
    return plant, iiwa


def build_reference_iiwa() -> MultibodyPlant:
    """An iiwa built in code from the section-1 table (not from the SDF)."""
    plant = MultibodyPlant(0.0)
    instance = plant.AddModelInstance("reference_iiwa")
    bodies = []
    X_MB = []  # link poses in the model frame at q = 0
    for i, (xyz, rpy, com, mass, moments) in enumerate(IIWA_LINKS):
        M_BBo_B = SpatialInertia.MakeFromCentralInertia(
            mass, np.array(com, dtype=float), RotationalInertia(*moments)
        )
        bodies.append(plant.AddRigidBody(f"link_{i}", instance, M_BBo_B))
        X_MB.append(RigidTransform(RollPitchYaw(*rpy), np.array(xyz, dtype=float)))
    plant.WeldFrames(plant.world_frame(), bodies[0].body_frame())
    for i, (axis_M, _, _, _) in enumerate(IIWA_JOINTS, start=1):
        X_PC = X_MB[i - 1].inverse().multiply(X_MB[i])
        frame_on_parent = plant.AddFrame(
            FixedOffsetFrame(f"joint_{i}_parent", bodies[i - 1].body_frame(), X_PC)
        )
        axis_C = X_MB[i].rotation().inverse().multiply(np.array(axis_M, dtype=float))
        plant.AddJoint(
            RevoluteJoint(f"joint_{i}", frame_on_parent, bodies[i].body_frame(), axis_C, 0.0)
        )
    plant.Finalize()
    return plant


def _rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' formula: rotation matrix about a unit axis."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def gravity_by_product_of_exponentials(q: np.ndarray, g: float = 9.81) -> np.ndarray:
    """Gravity generalized forces from the section-1 table, in plain numpy."""
    # Joint axes and points (link origins) in the world at q = 0.
    axes0 = [np.array(j[0], dtype=float) for j in IIWA_JOINTS]
    points0 = [np.array(IIWA_LINKS[i][0], dtype=float) for i in range(1, 8)]
    coms0 = [
        RigidTransform(RollPitchYaw(*rpy), np.array(xyz, dtype=float)).multiply(
            np.array(com, dtype=float)
        )
        for xyz, rpy, com, _, _ in IIWA_LINKS
    ]
    # Accumulated rigid motion T_j = exp(xi_1 q_1) ... exp(xi_j q_j).
    R, p = np.eye(3), np.zeros(3)
    axes, points, coms = [], [], [coms0[0]]
    for i in range(7):
        axes.append(R @ axes0[i])
        points.append(R @ points0[i] + p)
        R_i = _rotation_about(axes0[i], q[i])
        t_i = points0[i] - R_i @ points0[i]
        R, p = R @ R_i, R @ t_i + p
        coms.append(R @ coms0[i + 1] + p)
    weight = [np.array([0.0, 0.0, -g]) * link[3] for link in IIWA_LINKS]
    return np.array(
        [
            sum(np.cross(axes[i], coms[j] - points[i]) @ weight[j] for j in range(i + 1, 8))
            for i in range(7)
        ]
    )


# --- Package helpers ----------------------------------------------------------


def test_model_url_names() -> None:
    """model_url gives package:// URLs for the four models and rejects others."""
    assert MODEL_NAMES == ("iiwa7", "wsg_50", "cupboard", "table")
    for name in MODEL_NAMES:
        assert model_url(name) == f"package://{PACKAGE_NAME}/{name}.sdf"
        assert (MODELS_DIR / f"{name}.sdf").is_file()
    with pytest.raises(ValueError, match="iiwa7, wsg_50, cupboard, table"):
        model_url("iiwa14")


def test_add_package_is_idempotent() -> None:
    """add_package registers the folder once and may be called again."""
    plant = MultibodyPlant(0.0)
    parser = Parser(plant)
    add_package(parser)
    add_package(parser)
    assert parser.package_map().Contains(PACKAGE_NAME)
    resolved = parser.package_map().ResolveUrl(model_url("cupboard"))
    assert resolved == str(MODELS_DIR / "cupboard.sdf")


def test_add_package_rejects_other_folder(tmp_path) -> None:
    """add_package raises if another folder already claims the package name."""
    plant = MultibodyPlant(0.0)
    parser = Parser(plant)
    parser.package_map().Add(PACKAGE_NAME, str(tmp_path))
    with pytest.raises(RuntimeError, match="already registered"):
        add_package(parser)


@pytest.mark.parametrize(
    ("name", "model", "bodies", "joints", "actuators"),
    [
        ("iiwa7", "iiwa7", 8, 7, 7),
        ("wsg_50", "wsg", 3, 2, 2),
        ("cupboard", "cupboard", 3, 2, 0),
        ("table", "table", 1, 0, 0),
    ],
)
def test_each_file_parses_strictly(name, model, bodies, joints, actuators) -> None:
    """Each SDF parses without warnings into the expected model and sizes."""
    plant = MultibodyPlant(0.0)
    parser = Parser(plant)
    parser.SetStrictParsing()
    add_package(parser)
    (instance,) = parser.AddModels(url=model_url(name))
    assert plant.GetModelInstanceName(instance) == model
    assert len(plant.GetBodyIndices(instance)) == bodies
    assert len(plant.GetJointIndices(instance)) == joints
    plant.Finalize()
    assert plant.num_actuators(instance) == actuators


def test_station_welds_all_four_models(station: Station) -> None:
    """The four models weld into one plant with 7 arm, 2 finger, 2 hinge dofs."""
    plant = station.plant
    assert plant.num_positions() == 11
    assert plant.num_positions(station.iiwa) == 7
    assert plant.num_positions(station.wsg) == 2
    assert plant.num_positions(station.cupboard) == 2
    assert plant.num_positions(station.table) == 0
    assert plant.num_actuators() == 9


# --- iiwa -----------------------------------------------------------------------


def test_iiwa_fk_at_zero(station: Station) -> None:
    """At q = 0, joints 2/4/6 axes sit at 0.34/0.74/1.14 m and L7 at 1.22 m."""
    plant, ctx = station.plant, station.plant_context
    plant.SetPositions(ctx, station.iiwa, Q_ZERO)
    for i, height in ((2, 0.34), (4, 0.74), (6, 1.14)):
        joint = plant.GetJointByName(f"iiwa_joint_{i}", station.iiwa)
        p_WJ = joint.frame_on_child().CalcPoseInWorld(ctx).translation()
        assert p_WJ[2] == pytest.approx(height, abs=1e-3)
        assert p_WJ[:2] == pytest.approx([0.0, 0.0], abs=1e-12)
    X_WL7 = plant.GetFrameByName("iiwa_link_7", station.iiwa).CalcPoseInWorld(ctx)
    assert X_WL7.translation() == pytest.approx([0.0, 0.0, 1.22], abs=1e-3)
    assert X_WL7.rotation().matrix() == pytest.approx(np.eye(3), abs=1e-12)


def test_iiwa_axes_and_link_poses_match_table(station: Station) -> None:
    """Joint axes (world, q = 0) and link poses equal the section-1 table."""
    plant, ctx = station.plant, station.plant_context
    plant.SetPositions(ctx, station.iiwa, Q_ZERO)
    for i, (xyz, rpy, _, _, _) in enumerate(IIWA_LINKS):
        X_WL = plant.GetFrameByName(f"iiwa_link_{i}", station.iiwa).CalcPoseInWorld(ctx)
        X_ref = RigidTransform(RollPitchYaw(*rpy), np.array(xyz, dtype=float))
        assert X_WL.GetAsMatrix4() == pytest.approx(X_ref.GetAsMatrix4(), abs=1e-12)
    for i, (axis_M, _, _, _) in enumerate(IIWA_JOINTS, start=1):
        joint = plant.GetJointByName(f"iiwa_joint_{i}", station.iiwa)
        R_WJ = joint.frame_on_child().CalcPoseInWorld(ctx).rotation()
        assert R_WJ.multiply(joint.revolute_axis()) == pytest.approx(axis_M, abs=1e-12)


def test_iiwa_masses_and_inertias_match_table() -> None:
    """Link masses, COMs and central inertias equal the section-1 table."""
    plant, iiwa = load_iiwa_alone()
    for i, (_, _, com, mass, moments) in enumerate(IIWA_LINKS):
        body = plant.GetBodyByName(f"iiwa_link_{i}", iiwa)
        M = body.default_spatial_inertia()
        assert body.default_mass() == mass
        assert M.get_com() == pytest.approx(com, abs=1e-15)
        I_Bcm = M.CalcRotationalInertia().ShiftToCenterOfMass(mass, M.get_com())
        assert I_Bcm.CopyToFullMatrix3() == pytest.approx(np.diag(moments), abs=1e-12)


@pytest.mark.parametrize("q", TEST_POSES, ids=["zero", "home", "q0", "random"])
def test_iiwa_gravity_matches_independent_model(q: np.ndarray) -> None:
    """Gravity forces of the SDF arm equal a code-built model and numpy PoE."""
    plant, _ = load_iiwa_alone()
    ctx = plant.CreateDefaultContext()
    plant.SetPositions(ctx, q)
    tau_sdf = plant.CalcGravityGeneralizedForces(ctx)

    reference = build_reference_iiwa()
    ref_ctx = reference.CreateDefaultContext()
    reference.SetPositions(ref_ctx, q)
    tau_ref = reference.CalcGravityGeneralizedForces(ref_ctx)

    scale = np.linalg.norm(tau_ref)
    assert scale > 1e-3  # small at q = 0 (arm upright), tens of N m elsewhere
    assert np.linalg.norm(tau_sdf - tau_ref) <= 1e-9 * scale
    g = -plant.gravity_field().gravity_vector()[2]
    tau_poe = gravity_by_product_of_exponentials(q, g)
    assert np.linalg.norm(tau_sdf - tau_poe) <= 1e-9 * scale


def test_iiwa_limits_match_data_sheet() -> None:
    """Position, velocity (deg/s -> rad/s) and effort limits equal the data sheet."""
    plant, iiwa = load_iiwa_alone()
    for i, (_, q_max, speed_deg, torque) in enumerate(IIWA_JOINTS, start=1):
        joint = plant.GetJointByName(f"iiwa_joint_{i}", iiwa)
        assert joint.position_lower_limits() == pytest.approx([-q_max], abs=1e-15)
        assert joint.position_upper_limits() == pytest.approx([q_max], abs=1e-15)
        speed = np.deg2rad(speed_deg)
        assert joint.velocity_lower_limits() == pytest.approx([-speed], rel=1e-14)
        assert joint.velocity_upper_limits() == pytest.approx([speed], rel=1e-14)
        assert joint.default_damping() == 0.0
        actuator = plant.GetJointActuatorByName(f"iiwa_joint_{i}", iiwa)
        assert actuator.joint().index() == joint.index()
        assert actuator.effort_limit() == torque


def _arm_plants() -> list[tuple[MultibodyPlant, ModelInstanceIndex]]:
    """The arm alone, the controllers' plant and the simulation plant of the station."""
    from doorlab.cell.station import build_station, make_controller_plant
    from doorlab.config import StationConfig

    sim = build_station(StationConfig())
    controller = make_controller_plant()
    return [
        load_iiwa_alone(),
        (controller, controller.GetModelInstanceByName("iiwa7")),
        (sim.plant, sim.iiwa),
    ]


def test_iiwa_reflected_rotor_inertia() -> None:
    """Every arm joint carries gear ratio 160 and the official rotor inertia, so its reflected
    inertia is 160^2 x rotor inertia (1.4-4.4 kg m^2), in every plant built from the SDF; and
    that is exactly what it adds to the diagonal of M(q) (nothing off the diagonal)."""
    expected = GEAR_RATIO**2 * np.array(ROTOR_INERTIAS)
    assert expected == pytest.approx(REFLECTED_INERTIAS, abs=0.005)
    for plant, iiwa in _arm_plants():
        context = plant.CreateDefaultContext()
        actuators = [plant.GetJointActuatorByName(f"iiwa_joint_{i}", iiwa) for i in range(1, 8)]
        for actuator, rotor, reflected in zip(actuators, ROTOR_INERTIAS, expected, strict=True):
            assert actuator.default_gear_ratio() == GEAR_RATIO
            assert actuator.default_rotor_inertia() == rotor
            assert actuator.calc_reflected_inertia(context) == pytest.approx(reflected, rel=1e-12)
        v = [a.joint().velocity_start() for a in actuators]
        plant.SetPositions(context, iiwa, Q0)
        with_rotors = plant.CalcMassMatrix(context)[np.ix_(v, v)]
        for actuator in actuators:
            actuator.SetRotorInertia(context, 0.0)
        without = plant.CalcMassMatrix(context)[np.ix_(v, v)]
        assert with_rotors - without == pytest.approx(np.diag(expected), abs=1e-12)


# --- Cupboard -------------------------------------------------------------------


def test_cupboard_world_points(station: Station) -> None:
    """Hinge axes and the left handle centre land on the section-3 world points."""
    plant, ctx = station.plant, station.plant_context
    plant.SetPositions(ctx, station.cupboard, [0.0, 0.0])
    c = station.cupboard

    def p_W(frame_name: str) -> np.ndarray:
        return plant.GetFrameByName(frame_name, c).CalcPoseInWorld(ctx).translation()

    for side, expected in (("left", P_W_LEFT_HINGE), ("right", P_W_RIGHT_HINGE)):
        hinge = plant.GetJointByName(f"{side}_door_hinge", c)
        for frame in (hinge.frame_on_parent(), hinge.frame_on_child()):
            assert frame.CalcPoseInWorld(ctx).translation() == pytest.approx(expected, abs=1e-4)
        assert p_W(f"{side}_hinge") == pytest.approx(expected, abs=1e-4)
    assert p_W("left_handle") == pytest.approx(P_W_LEFT_HANDLE, abs=1e-4)
    mirrored = P_W_LEFT_HANDLE * np.array([1.0, -1.0, 1.0])
    assert p_W("right_handle") == pytest.approx(mirrored, abs=1e-4)
    # The handle geometry (vertical cylinder r 0.005, length 0.14) sits at the frame.
    query = station.query()
    inspector = query.inspector()
    for side in ("left", "right"):
        door = plant.GetBodyByName(f"{side}_door", c)
        (handle,) = [
            g
            for g in plant.GetCollisionGeometriesForBody(door)
            if inspector.GetName(g).endswith("handle_collision")
        ]
        cylinder = inspector.GetShape(handle)
        assert (cylinder.radius(), cylinder.length()) == (0.005, 0.14)
        X_WH = query.GetPoseInWorld(handle)
        assert X_WH.translation() == pytest.approx(p_W(f"{side}_handle"), abs=1e-12)
        assert X_WH.rotation().col(2) == pytest.approx([0.0, 0.0, 1.0], abs=1e-12)
    handle_radius = np.linalg.norm((P_W_LEFT_HANDLE - P_W_LEFT_HINGE)[:2])
    assert handle_radius == pytest.approx(0.2671647, abs=1e-7)


def test_cupboard_hinges(station: Station) -> None:
    """Hinges: revolute about z, damping 1, passive, signed limits per door."""
    plant, c = station.plant, station.cupboard
    left = plant.GetJointByName("left_door_hinge", c)
    right = plant.GetJointByName("right_door_hinge", c)
    assert isinstance(left, RevoluteJoint) and isinstance(right, RevoluteJoint)
    for joint in (left, right):
        assert joint.revolute_axis() == pytest.approx([0.0, 0.0, 1.0])
        assert joint.default_damping() == 1.0
    assert left.position_lower_limits() == pytest.approx([-1.5708])
    assert left.position_upper_limits() == pytest.approx([0.0])
    assert right.position_lower_limits() == pytest.approx([0.0])
    assert right.position_upper_limits() == pytest.approx([1.5708])
    assert plant.num_actuators(c) == 0
    for door in ("left_door", "right_door"):
        body = plant.GetBodyByName(door, c)
        M = body.default_spatial_inertia()
        assert body.default_mass() == 1.0
        assert M.get_com() == pytest.approx([0.0, 0.0, 0.0])
        assert M.CalcRotationalInertia().CopyToFullMatrix3() == pytest.approx(
            np.diag([0.01042, 0.00542, 0.00542])
        )
        assert M.IsPhysicallyValid()


@pytest.mark.parametrize(("side", "angle"), [("left", -0.5), ("right", 0.5)])
def test_door_opening_convention(station: Station, side: str, angle: float) -> None:
    """Opening (left negative, right positive) moves the handle towards the robot."""
    plant, ctx, c = station.plant, station.plant_context, station.cupboard
    hinge = plant.GetJointByName(f"{side}_door_hinge", c)
    handle = plant.GetFrameByName(f"{side}_handle", c)
    hinge.set_angle(ctx, 0.0)
    p_closed = handle.CalcPoseInWorld(ctx).translation()
    hinge.set_angle(ctx, angle)
    p_open = handle.CalcPoseInWorld(ctx).translation()
    hinge.set_angle(ctx, 0.0)
    assert p_open[0] < p_closed[0] - 0.05
    # The handle stays on its circle about the hinge axis.
    p_hinge = hinge.frame_on_parent().CalcPoseInWorld(ctx).translation()
    r_closed = np.linalg.norm((p_closed - p_hinge)[:2])
    r_open = np.linalg.norm((p_open - p_hinge)[:2])
    assert r_open == pytest.approx(r_closed, abs=1e-12)


def test_closed_doors_do_not_penetrate(station: Station) -> None:
    """With doors at (-0.001, 0.001) no contact pair involving a door penetrates."""
    plant, ctx = station.plant, station.plant_context
    plant.SetPositions(ctx, station.cupboard, [-0.001, 0.001])
    door_bodies = {
        plant.GetBodyByName(n, station.cupboard).index() for n in ("left_door", "right_door")
    }
    query = station.query()
    for pair in query.ComputePointPairPenetration():
        bodies = {
            plant.GetBodyFromFrameId(query.inspector().GetFrameId(g)).index()
            for g in (pair.id_A, pair.id_B)
        }
        if bodies & door_bodies:
            assert pair.depth < 1e-9
    plant.SetPositions(ctx, station.cupboard, [0.0, 0.0])


# --- Gripper --------------------------------------------------------------------


def _pad_ids(station: Station) -> tuple:
    plant = station.plant
    (left,) = plant.GetCollisionGeometriesForBody(plant.GetBodyByName("left_finger", station.wsg))
    (right,) = plant.GetCollisionGeometriesForBody(plant.GetBodyByName("right_finger", station.wsg))
    return left, right


def _set_fingers(station: Station, q_left: float, q_right: float) -> None:
    plant, ctx = station.plant, station.plant_context
    plant.GetJointByName("left_finger_sliding_joint", station.wsg).set_translation(ctx, q_left)
    plant.GetJointByName("right_finger_sliding_joint", station.wsg).set_translation(ctx, q_right)


def test_gripper_pad_gap(station: Station) -> None:
    """At fingers (-0.005, 0.005) the pads are 0.01 m apart; at (0, 0) they touch."""
    left, right = _pad_ids(station)
    station.plant.SetPositions(station.plant_context, station.iiwa, Q_HOME)
    for (q_left, q_right), gap in (
        ((-0.005, 0.005), 0.01),
        ((0.0, 0.0), 0.0),
        ((-0.02, 0.015), 0.035),
    ):
        _set_fingers(station, q_left, q_right)
        query = station.query()
        distance = query.ComputeSignedDistancePairClosestPoints(left, right).distance
        assert distance == pytest.approx(gap, abs=1e-6)
        # Same by geometry: inner faces of the pads along the finger axis.
        X_GL = X_L7G.inverse()
        X_WL7 = station.plant.EvalBodyPoseInWorld(
            station.plant_context,
            station.plant.GetBodyByName("iiwa_link_7", station.iiwa),
        )
        X_GW = X_GL.multiply(X_WL7.inverse())
        x_left_inner = X_GW.multiply(query.GetPoseInWorld(left).translation())[0] + 0.008
        x_right_inner = X_GW.multiply(query.GetPoseInWorld(right).translation())[0] - 0.008
        assert x_right_inner - x_left_inner == pytest.approx(gap, abs=1e-12)
    _set_fingers(station, 0.0, 0.0)


def test_gripper_fingertips_and_grasp_point(station: Station) -> None:
    """Fingertips reach 0.2256 m along L7 z and Q (0.214 m) lies between the pads."""
    plant, ctx = station.plant, station.plant_context
    plant.SetPositions(ctx, station.iiwa, Q0)
    _set_fingers(station, -0.005, 0.005)
    query = station.query()
    X_WL7 = plant.EvalBodyPoseInWorld(ctx, plant.GetBodyByName("iiwa_link_7", station.iiwa))
    p_WQ = X_WL7.multiply(P_L7Q)
    for pad, inward in zip(_pad_ids(station), (+1.0, -1.0), strict=True):
        box = query.inspector().GetShape(pad)
        assert (box.width(), box.depth(), box.height()) == pytest.approx(FINGER_BOX)
        X_WP = query.GetPoseInWorld(pad)
        # The pad's long (y) axis is the approach direction L7 z.
        R_L7P = X_WL7.rotation().inverse().multiply(X_WP.rotation())
        assert R_L7P.col(1) == pytest.approx([0.0, 0.0, 1.0], abs=1e-12)
        tip_L7 = X_WL7.inverse().multiply(X_WP.multiply([0.0, box.depth() / 2, 0.0]))
        assert tip_L7[2] == pytest.approx(0.2256, abs=1e-3)
        assert tip_L7[2] == pytest.approx(0.114 + 0.074133 + 0.0375, abs=1e-12)
        # Q in the pad frame: within the pad's y and z extent, on its inner side.
        p_PQ = X_WP.inverse().multiply(p_WQ)
        assert abs(p_PQ[1]) < box.depth() / 2
        assert abs(p_PQ[2]) < box.height() / 2
        assert inward * p_PQ[0] == pytest.approx(box.width() / 2 + 0.005, abs=1e-12)
    _set_fingers(station, 0.0, 0.0)


def test_gripper_joints(station: Station) -> None:
    """Finger joints: prismatic along G x, limits [-0.055, 0] / [0, 0.055], 80 N."""
    plant, wsg = station.plant, station.wsg
    for side, lower, upper in (("left", -0.055, 0.0), ("right", 0.0, 0.055)):
        joint = plant.GetJointByName(f"{side}_finger_sliding_joint", wsg)
        assert joint.translation_axis() == pytest.approx([1.0, 0.0, 0.0])
        assert joint.position_lower_limits() == pytest.approx([lower])
        assert joint.position_upper_limits() == pytest.approx([upper])
        actuator = plant.GetJointActuatorByName(f"{side}_finger_sliding_joint", wsg)
        assert actuator.effort_limit() == 80.0
    ctx = station.plant_context
    _set_fingers(station, 0.0, 0.0)
    X_GF = {
        side: plant.GetFrameByName("body", wsg)
        .CalcPose(ctx, plant.GetFrameByName(f"{side}_finger", wsg))
        .inverse()
        for side in ("left", "right")
    }
    assert X_GF["left"].translation() == pytest.approx([-0.008, 0.074133, 0.0])
    assert X_GF["right"].translation() == pytest.approx([0.008, 0.074133, 0.0])


def _solid_box_moments(mass: float, size: tuple[float, float, float]) -> np.ndarray:
    a, b, c = size
    return mass / 12.0 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])


@pytest.mark.parametrize(
    ("link", "mass", "size", "bound"),
    [
        ("left_finger", FINGER_MASS, FINGER_BOX, 1e-3),
        ("right_finger", FINGER_MASS, FINGER_BOX, 1e-3),
        # The body's solid-box inertia is ~2.2e-3 kg m^2 (Izz), so its bound is
        # 1e-2: still ~75x below the original's unphysical 0.16 kg m^2.
        ("body", WSG_BODY_MASS, WSG_BODY_BOX, 1e-2),
    ],
)
def test_gripper_inertias_are_physical(station: Station, link, mass, size, bound) -> None:
    """Gripper link inertias are valid solid-box inertias, small (< bound)."""
    body = station.plant.GetBodyByName(link, station.wsg)
    M = body.default_spatial_inertia()
    assert M.IsPhysicallyValid()
    assert body.default_mass() == mass
    assert M.get_com() == pytest.approx([0.0, 0.0, 0.0])
    moments = np.diag(M.CalcRotationalInertia().CopyToFullMatrix3())
    assert moments == pytest.approx(_solid_box_moments(mass, size), rel=1e-12)
    assert moments.max() < bound
    (geometry,) = station.plant.GetCollisionGeometriesForBody(body)
    box = station.query().inspector().GetShape(geometry)
    assert (box.width(), box.depth(), box.height()) == pytest.approx(size)


def test_collision_friction_is_one(station: Station) -> None:
    """Every collision geometry of the station has static and dynamic friction 1."""
    inspector = station.query().inspector()
    geometry_ids = inspector.GetAllGeometryIds()
    assert len(geometry_ids) > 0
    n_collision = 0
    for g in geometry_ids:
        props = inspector.GetProximityProperties(g)
        if props is None:
            continue
        n_collision += 1
        friction = props.GetProperty("material", "coulomb_friction")
        assert friction.static_friction() == 1.0
        assert friction.dynamic_friction() == 1.0
    assert n_collision == station.plant.num_collision_geometries() == 3 + 10 + 1


# --- Arm collision mode -----------------------------------------------------------


def test_arm_has_no_collision_by_default(station: Station) -> None:
    """The arm has no collision geometry unless add_arm_collision is called."""
    plant = station.plant
    for i in range(8):
        body = plant.GetBodyByName(f"iiwa_link_{i}", station.iiwa)
        assert plant.GetCollisionGeometriesForBody(body) == []
        assert len(plant.GetVisualGeometriesForBody(body)) >= 1


def test_add_arm_collision(station_arm_collision: Station) -> None:
    """add_arm_collision puts one friction-1 shape on each of links 1-7."""
    station = station_arm_collision
    plant = station.plant
    inspector = station.query().inspector()
    assert len(ARM_COLLISION_SHAPES) == 7
    assert (
        plant.GetCollisionGeometriesForBody(plant.GetBodyByName("iiwa_link_0", station.iiwa)) == []
    )
    for i in range(1, 8):
        body = plant.GetBodyByName(f"iiwa_link_{i}", station.iiwa)
        (geometry,) = plant.GetCollisionGeometriesForBody(body)
        friction = inspector.GetProximityProperties(geometry).GetProperty(
            "material", "coulomb_friction"
        )
        assert friction.static_friction() == friction.dynamic_friction() == 1.0


@pytest.mark.parametrize("q", [Q_ZERO, Q_HOME, Q0], ids=["zero", "home", "q0"])
def test_arm_collision_free_at_standard_poses(
    station_arm_collision: Station, q: np.ndarray
) -> None:
    """In arm-collision mode the arm touches nothing at q = 0, q_home and q0."""
    station = station_arm_collision
    plant, ctx = station.plant, station.plant_context
    plant.SetPositions(ctx, station.iiwa, q)
    _set_fingers(station, -0.015, 0.015)
    query = station.query()
    arm_bodies = {plant.GetBodyByName(f"iiwa_link_{i}", station.iiwa).index() for i in range(8)}
    for pair in query.ComputePointPairPenetration():
        bodies = {
            plant.GetBodyFromFrameId(query.inspector().GetFrameId(g)).index()
            for g in (pair.id_A, pair.id_B)
        }
        assert not bodies & arm_bodies, f"arm contact at q = {q}"


def test_add_arm_collision_requires_unfinalized_plant(station: Station) -> None:
    """add_arm_collision refuses a finalized plant or one without a SceneGraph."""
    with pytest.raises(RuntimeError, match="before plant.Finalize"):
        add_arm_collision(station.plant, station.iiwa)
    plant = MultibodyPlant(0.0)
    parser = Parser(plant)
    add_package(parser)
    (iiwa,) = parser.AddModels(url=model_url("iiwa7"))
    with pytest.raises(RuntimeError, match="SceneGraph"):
        add_arm_collision(plant, iiwa)


def test_module_transforms() -> None:
    """X_L7G, X_WC and X_W_TABLE hold the station's weld poses."""
    assert X_L7G.translation() == pytest.approx([0.0, 0.0, 0.114])
    R = X_L7G.rotation().matrix()
    assert R[:, 1] == pytest.approx([0.0, 0.0, 1.0], abs=1e-15)  # G y = L7 z
    assert R[:, 0] == pytest.approx([0.0, 1.0, 0.0], abs=1e-15)  # G x = L7 y
    assert X_WC.translation() == pytest.approx([0.9057, 0.0, 0.4148])
    assert X_WC.rotation().matrix() == pytest.approx(np.diag([-1.0, -1.0, 1.0]), abs=1e-15)
    assert X_W_TABLE.translation() == pytest.approx([0.9057, 0.0, 0.0073], abs=1e-12)
    assert X_W_TABLE.rotation().matrix() == pytest.approx(np.eye(3))
