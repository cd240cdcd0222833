"""Model files of the doorlab station and helpers to load them with Drake.

The folder holds four SDF files made of primitive shapes only, plus a ROS-style
``package.xml`` that names the folder ``doorlab_models`` so that Drake can
resolve ``package://doorlab_models/<name>.sdf``:

* ``iiwa7.sdf``: model ``iiwa7``, links ``iiwa_link_0`` ... ``iiwa_link_7``,
  revolute joints ``iiwa_joint_1`` ... ``iiwa_joint_7``; no collision geometry
  (see :func:`add_arm_collision`).
* ``wsg_50.sdf``: model ``wsg``, link ``body`` at the model origin (so the
  gripper frame G is the body frame), links ``left_finger`` / ``right_finger``,
  prismatic joints ``left_finger_sliding_joint`` / ``right_finger_sliding_joint``.
* ``cupboard.sdf``: model ``cupboard``, link ``cupboard_body`` (the cupboard
  frame C), links ``left_door`` / ``right_door``, revolute joints
  ``left_door_hinge`` / ``right_door_hinge`` and frames ``left_handle``,
  ``right_handle``, ``left_hinge``, ``right_hinge``.
* ``table.sdf``: model ``table``, link ``table_top`` whose top face is at z = 0.

The station welds ``iiwa_link_0`` at the world origin, the gripper ``body`` to
``iiwa_link_7`` at :data:`X_L7G`, ``cupboard_body`` at :data:`X_WC` and
``table_top`` at :data:`X_W_TABLE`. SI units throughout.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
from pydrake.geometry import Capsule, Cylinder, Shape
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant
from pydrake.multibody.tree import ModelInstanceIndex

__all__ = [
    "ARM_COLLISION_SHAPES",
    "MODELS_DIR",
    "MODEL_NAMES",
    "PACKAGE_NAME",
    "X_L7G",
    "X_WC",
    "X_W_TABLE",
    "add_arm_collision",
    "add_package",
    "model_url",
]

MODELS_DIR: Path = Path(__file__).resolve().parent
"""Folder holding the SDF files and ``package.xml``."""

PACKAGE_NAME: str = "doorlab_models"
"""Package name declared in ``package.xml`` (used in ``package://`` URLs)."""

MODEL_NAMES: tuple[str, ...] = ("iiwa7", "wsg_50", "cupboard", "table")
"""Valid arguments of :func:`model_url` (SDF file stems)."""

X_L7G: RigidTransform = RigidTransform(RollPitchYaw(np.pi / 2, 0.0, np.pi / 2), [0.0, 0.0, 0.114])
"""Pose of the gripper frame G (= the WSG ``body`` link) in ``iiwa_link_7``.

Translation 0.114 m along L7 z, rpy (pi/2, 0, pi/2): G's y axis is L7's z axis
(the approach direction) and G's x axis (the finger axis) is L7's y axis.
"""

X_WC: RigidTransform = RigidTransform(RotationMatrix.MakeZRotation(np.pi), [0.9057, 0.0, 0.4148])
"""Pose of the cupboard frame C (link ``cupboard_body``) in the world, m."""

X_W_TABLE: RigidTransform = RigidTransform([0.9057, 0.0, 0.4148 - 0.815 / 2])
"""Pose of the table model frame in the world: top face at z = 0.0073 m,
centred under the cupboard (the table spans x in about [0.51, 1.31] m)."""

# Arm collision shapes for the optional "arm collision" mode. One entry per
# link: (link name, pose of the shape in the link frame, shape). Each shape
# wraps the matching visual of iiwa7.sdf (a capsule around the cylinder that
# runs from the link origin to the next joint axis; a cylinder for the L7
# flange and adapter). A Drake Capsule's length excludes its two hemispherical
# caps; a Cylinder/Capsule axis is the shape frame's z axis.
_ALONG_Y = RotationMatrix.MakeXRotation(np.pi / 2)  # shape z -> link -y (symmetric)
ARM_COLLISION_SHAPES: tuple[tuple[str, RigidTransform, Shape], ...] = (
    ("iiwa_link_1", RigidTransform([0.0, 0.0, 0.0915]), Capsule(0.07, 0.183)),
    ("iiwa_link_2", RigidTransform(_ALONG_Y, [0.0, 0.092, 0.0]), Capsule(0.065, 0.184)),
    ("iiwa_link_3", RigidTransform([0.0, 0.0, 0.10775]), Capsule(0.065, 0.2155)),
    ("iiwa_link_4", RigidTransform(_ALONG_Y, [0.0, 0.092, 0.0]), Capsule(0.06, 0.184)),
    ("iiwa_link_5", RigidTransform([0.0, 0.0, 0.10775]), Capsule(0.06, 0.2155)),
    (
        "iiwa_link_6",
        RigidTransform(_ALONG_Y, [0.0, 0.04025, 0.0]),
        Capsule(0.055, 0.0805),
    ),
    ("iiwa_link_7", RigidTransform([0.0, 0.0, 0.0389]), Cylinder(0.045, 0.0778)),
)
"""Collision shapes added by :func:`add_arm_collision`: (link, X_LS, shape)."""


def model_url(name: str) -> str:
    """Return the ``package://`` URL of one of the station's model files.

    Args:
        name: File stem, one of ``"iiwa7"``, ``"wsg_50"``, ``"cupboard"``,
            ``"table"``.

    Returns:
        The URL, e.g. ``"package://doorlab_models/iiwa7.sdf"``. It resolves once
        the package is registered with the parser (:func:`add_package`).

    Raises:
        ValueError: If ``name`` is not one of the valid names.
    """
    if name not in MODEL_NAMES:
        raise ValueError(f"unknown model name {name!r}; valid names are {', '.join(MODEL_NAMES)}")
    return f"package://{PACKAGE_NAME}/{name}.sdf"


def add_package(parser: Parser) -> None:
    """Register the ``doorlab_models`` package with the parser's package map.

    Idempotent: nothing happens if the package is already registered at this
    folder.

    Args:
        parser: The Drake parser whose package map gets the package.

    Raises:
        RuntimeError: If a different folder is already registered under the
            name ``doorlab_models``.
    """
    package_map = parser.package_map()
    if package_map.Contains(PACKAGE_NAME):
        registered = Path(package_map.GetPath(PACKAGE_NAME)).resolve()
        if registered != MODELS_DIR:
            raise RuntimeError(
                f"package {PACKAGE_NAME!r} is already registered at {registered}, "
                f"not at {MODELS_DIR}"
            )
        return
    package_map.AddPackageXml(str(MODELS_DIR / "package.xml"))


def add_arm_collision(plant: MultibodyPlant, iiwa: ModelInstanceIndex) -> None:
    """Register collision geometry on ``iiwa_link_1`` ... ``iiwa_link_7``.

    The arm model has no collision geometry (like the original station's arm);
    this adds, for an optional "arm collision" mode, the shapes of
    :data:`ARM_COLLISION_SHAPES`: capsules of radius 0.055-0.07 m around the
    link visuals and a cylinder (radius 0.045 m, 0.0778 m long) for the L7
    flange and adapter, with Coulomb friction 1 (static and dynamic). Collisions
    between bodies joined by a joint or weld are filtered by the plant as usual.
    Call it once per arm.

    Args:
        plant: The plant holding the arm; it must not be finalized yet and must
            be registered as a geometry source with a SceneGraph.
        iiwa: The model instance of the ``iiwa7`` model.

    Raises:
        RuntimeError: If the plant is finalized or has no SceneGraph.
    """
    if plant.is_finalized():
        raise RuntimeError("add_arm_collision() must be called before plant.Finalize()")
    if not plant.geometry_source_is_registered():
        raise RuntimeError(
            "add_arm_collision() needs a plant registered with a SceneGraph "
            "(e.g. from AddMultibodyPlantSceneGraph)"
        )
    friction = CoulombFriction(static_friction=1.0, dynamic_friction=1.0)
    for link_name, X_LS, shape in ARM_COLLISION_SHAPES:
        body = plant.GetBodyByName(link_name, iiwa)
        plant.RegisterCollisionGeometry(body, X_LS, shape, f"{link_name}_arm_collision", friction)


@cache
def model_text(name: str) -> str:
    """The SDF text of one of the station's model files, read once per process.

    Raises:
        ValueError: If ``name`` is not one of the valid names.
    """
    model_url(name)  # validates the name
    return (Path(__file__).resolve().parent / f"{name}.sdf").read_text(encoding="utf-8")


def add_model(parser: Parser, name: str) -> ModelInstanceIndex:
    """Adds one of the station's models to ``parser``'s plant; returns its model instance.

    Parses the cached text (:func:`model_text`): Drake's parser spends ~0.1 s per SDF *file*
    (path resolution) but ~1 ms on the same text, and a run builds the cell several times
    (the station, the controllers' arm model, the replay). The models use no URIs.
    """
    (instance,) = parser.AddModels(file_contents=model_text(name), file_type="sdf")
    return instance
