"""What a controller is, for doorlab's own and for yours: the contract every command runs.

A **controller** turns a scenario into the plan that opens the door, and says where that plan
starts. doorlab runs every controller, built-in or plug-in, through the same episode (the
problem set's task cell): hold the arm, move it to :attr:`ArcPlan.q_start`, close the gripper
on the handle there, run :attr:`ArcPlan.plan` along the handle's arc, hold. Each part:

- :class:`Controller`: a name, a one-line title and summary, and ``build(scenario, geometry,
  plant) -> ArcPlan``, called once per episode before it starts. A plug-in may also be the
  build function alone.
- :class:`ArcPlan`: the plan and its start configuration.
- :class:`~doorlab.control.plan_base.Plan` (a protocol): ``name``, ``duration`` [s] and
  ``command(t, state) -> Command``, called at every control tick
  (``timeline.control_period``, 5 ms) with the time since the plan started, t [s] (it goes on
  past ``duration`` for the 1 s every plan settles: hold there), and the measured
  :class:`~doorlab.control.plan_base.ArmState`.
- :class:`~doorlab.control.plan_base.ArmState`: q (7,) [rad], v (7,) [rad/s] and
  tau_external (7,) [N m], the arm's joints in order ``iiwa_joint_1`` .. ``_7``.
- :class:`~doorlab.control.plan_base.Command`: q_ref (7,) [rad] and tau_ff (7,) [N m], which
  the inner loop turns into torques, tau = Kq (q_ref - q) - Dq v + g(q) + tau_ff (the arm's
  own joint impedance loop on the lab's iiwa).

What ``build`` is given:

- ``scenario``: the validated :class:`doorlab.config.Scenario` of the run (its
  ``timeline.arc_duration`` [s] is the arc's, its ``timeline.control_period`` [s] the tick's).
  Read it; do not change it.
- ``geometry``: the door as the controller BELIEVES it
  (:class:`~doorlab.cell.geometry.DoorGeometry`, in W): ``p_WQ_ref(tau)`` (3,) [m] and
  ``R_WL7_ref(tau)`` (a RotationMatrix) along the arc,
  tau = t / ``timeline.arc_duration`` in [0, 1]; ``p_W_hinge``, ``p_W_handle`` (3,) [m],
  ``r_handle`` [m], ``theta0`` and ``sweep`` [rad]. With ``station.cupboard_yaw_error`` or
  ``station.cupboard_position_error`` the real cupboard is elsewhere: the metrics measure
  against the true one.
- ``plant``: the controllers' model of the arm, a finalized
  :class:`~pydrake.multibody.plant.MultibodyPlant` (7 positions: the iiwa with the gripper
  lumped into its last link, the motors' reflected inertia on the joints), fresh for this
  episode and the controller's own: make your contexts from it (never touch the
  simulation's).

Frames (Drake's monogram notation, :mod:`doorlab.cell.frames`): W the world (x forward from
the robot's base, z up), L7 the arm's last link (``iiwa_link_7``), Q the grasp point between
the finger pads, fixed in L7 at ``p_L7Q`` = (0, 0, 0.214) m. The problem set's errors and
Jacobian, as the built-ins compute them, are in :mod:`doorlab.control.laws` and
:class:`doorlab.control.plans.TaskSpaceVelocityPlan`.

The same checks hold for every controller: ``station.safety`` (always on ``run --hardware``)
checks each command before it goes out. A plug-in is also watched: an exception in a tick, or a
command that is not 7 + 7 finite numbers, ends the run with status ``controller_error`` (its logs
kept, one line naming the plug-in).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from pydrake.multibody.plant import MultibodyPlant

from doorlab.config import Scenario
from doorlab.control.plan_base import ArmState, Command, Plan
from doorlab.errors import ConfigError

if TYPE_CHECKING:  # not imported: the students' doorlab has neither (reference solutions)
    from doorlab.cell.geometry import DoorGeometry
    from doorlab.control.ik_pointwise import IkResult

__all__ = ["ArcPlan", "ArmState", "BuildFunction", "Command", "Controller", "Plan"]

BuildFunction = Callable[[Scenario, "DoorGeometry", MultibodyPlant], "ArcPlan"]
"""``build(scenario, geometry, plant) -> ArcPlan``: a controller's plan for one episode."""

NAME_PATTERN = re.compile(r"[A-Za-z][A-Za-z0-9_-]{0,63}")
"""A controller's name: a letter, then letters, digits, ``_`` or ``-`` (64 at most): it names
folders (``doorlab_out/<name>_<doors>``) and the columns of tables."""


@dataclass(frozen=True)
class ArcPlan:
    """What a controller runs along the arc.

    Attributes:
        plan: The door-opening plan (:class:`~doorlab.control.plan_base.Plan`: ``name``,
            ``duration`` [s], ``command(t, state)``).
        q_start: The arm's configuration where the plan starts (7,) [rad]: the episode moves
            the arm there and closes the gripper on the handle before the plan's first tick.
        ik: The pointwise IK behind the plan (the built-in ``ik`` only; None otherwise).
    """

    plan: Plan
    q_start: np.ndarray
    ik: IkResult | None = None


@dataclass(frozen=True)
class Controller:
    """A controller: its name, what it is, and how it builds its plan.

    Attributes:
        name: What commands and tables call it (``--controller NAME``, ``metrics.json``'s
            ``controller``): a letter, then letters, digits, ``_`` or ``-``.
        task: The problem set's task number of a built-in (1-3; 4 the adaptive plan); None
            for a controller that is no task of it (a plug-in).
        title: A few words, e.g. "Pointwise IK".
        summary: One line: what it commands and from what.
        build: ``build(scenario, geometry, plant) -> ArcPlan`` (see the module docstring).
    """

    name: str
    task: int | None = None
    title: str = ""
    summary: str = ""
    build: BuildFunction | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not NAME_PATTERN.fullmatch(self.name):
            raise ConfigError(
                f"a Controller's name must be a letter, then letters, digits, _ or - (at most "
                f"64), got {self.name!r}"
            )
        if not callable(self.build):
            raise ConfigError(
                f"Controller {self.name!r} needs build=a function (scenario, geometry, plant) "
                f"-> ArcPlan, got {self.build!r}"
            )
