"""An episode's logs: :class:`EpisodeResult` (named, time-stamped channels, saved as
``log.npz``), whatever cell produced them, and the part of it the schedule gives
(:func:`schedule_fields`).
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path

import numpy as np

from doorlab.episode.schedule import ScheduledPlan

_PLAN_LOG_PREFIX = "plan_log."
"""Keys of EpisodeResult.plan_log's columns in a saved ``.npz``."""


@dataclass(frozen=True)
class EpisodeResult:
    """Named, time-stamped logs of one episode (all sampled every log period).

    Attributes:
        t: Sample times (n,) [s].
        q_commanded: Commanded joint positions q_ref (n, 7) [rad].
        q_measured: Measured joint positions (n, 7) [rad].
        v_measured: Measured joint velocities (n, 7) [rad/s].
        tau_external: Contact torques on the arm joints (n, 7) [N m].
        tau_feedforward: tau_ff sent by the plans (n, 7) [N m].
        tau_commanded: Torque the joints receive (n, 7) [N m]: the actuators' after
            saturation plus, for the stiffness loop, the joints' damping -(Dq + h Kq) qdot.
        door_angles: Hinge angles (n, 2) [rad], columns (left, right); None on the real
            cell, which has no hinge sensor.
        wsg_width: Finger separation (n,) [m].
        plant_positions: Positions of the whole plant (n, nq), for replays.
        plan_names: Names of the scheduled plans.
        plan_starts: Start times of the scheduled plans (k,) [s].
        arc_window: [t_start, t_end] of the door-opening arc [s], shape (2,).
        wall_time_s: Wall-clock time of the simulation [s].
        scenario_yaml: The scenario that produced the logs.
        plan_log: The arc plan's own per-tick table {channel: (m,)} (empty for plans that
            record nothing); its ``t`` column is the episode's time [s]. The adaptive plan's
            channels are listed in :data:`doorlab.control.adaptive.LOG_CHANNELS`.
        door_angle_estimated: The real cell's estimate of the left hinge angle (n,) [rad]:
            Q's angle about the believed hinge while the handle is held, nan elsewhere
            (:func:`doorlab.hardware.estimates.door_angle_estimate`); None in simulation.
        status_time: The real cell's ``utime`` of the status each sample shows, as seconds
            (n,) [s]; None in simulation.
        tau_external_estimated: With ``station.driver.timing: kuka_driver``, the external
            torque the arm's status carries (n, 7) [N m]: KUKA's estimate (its load data,
            noise: :mod:`doorlab.cell.arm_model`), what kuka_driver's freeze judges; None
            otherwise (on the real cell ``tau_external`` is that estimate).
        cell: ``simulation`` or ``hardware`` (the real cell over LCM).
        cycle_log: With ``station.driver.timing: kuka_driver``, the status of every 5 ms
            cycle, as the arm's driver would send it: ``t`` (m,) [s] and
            :data:`doorlab.cell.arm_cell.STATUS_LAYOUT`'s channels (m, size); kept in memory,
            not saved.
    """

    t: np.ndarray
    q_commanded: np.ndarray
    q_measured: np.ndarray
    v_measured: np.ndarray
    tau_external: np.ndarray
    tau_feedforward: np.ndarray
    tau_commanded: np.ndarray
    door_angles: np.ndarray | None
    wsg_width: np.ndarray
    plant_positions: np.ndarray
    plan_names: tuple[str, ...]
    plan_starts: np.ndarray
    arc_window: np.ndarray
    wall_time_s: float = 0.0
    scenario_yaml: str = field(default="", compare=False)
    plan_log: dict[str, np.ndarray] = field(default_factory=dict, compare=False)
    door_angle_estimated: np.ndarray | None = None
    status_time: np.ndarray | None = None
    tau_external_estimated: np.ndarray | None = None
    cell: str = "simulation"
    cycle_log: dict[str, np.ndarray] = field(default_factory=dict, compare=False)

    @property
    def sim_time_s(self) -> float:
        """Simulated duration [s]."""
        return float(self.t[-1]) if len(self.t) else 0.0

    def window(self, t_start: float, t_end: float) -> np.ndarray:
        """Boolean mask of the samples with t_start <= t <= t_end (tolerates float noise)."""
        eps = 1e-9
        return (self.t >= t_start - eps) & (self.t <= t_end + eps)

    def save(self, path: str | Path) -> None:
        """Writes every channel to an ``.npz`` file (see :meth:`load`)."""
        arrays = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in ("plan_log", "cycle_log") or value is None:  # None: not measured
                continue
            arrays[f.name] = np.asarray(value)
        for name, column in self.plan_log.items():
            arrays[f"{_PLAN_LOG_PREFIX}{name}"] = np.asarray(column)
        buffer = io.BytesIO()
        np.savez_compressed(buffer, **arrays)
        Path(path).write_bytes(buffer.getvalue())

    @classmethod
    def load(cls, path: str | Path) -> EpisodeResult:
        """Reads a file written by :meth:`save`."""
        with np.load(path, allow_pickle=False) as data:
            values = {}
            for f in fields(cls):
                if f.name == "cycle_log":
                    continue
                if f.name == "plan_log":
                    values[f.name] = {
                        key[len(_PLAN_LOG_PREFIX) :]: data[key]
                        for key in data.files
                        if key.startswith(_PLAN_LOG_PREFIX)
                    }
                    continue
                if f.name not in data.files:  # a channel the cell did not measure
                    values[f.name] = None if f.default is MISSING else f.default
                    continue
                value = data[f.name]
                if f.name == "plan_names":
                    value = tuple(str(s) for s in value)
                elif f.name in ("wall_time_s",):
                    value = float(value)
                elif f.name in ("scenario_yaml", "cell"):
                    value = str(value)
                values[f.name] = value
        return cls(**values)


def schedule_fields(schedule: Sequence[ScheduledPlan], arc_index: int) -> dict[str, object]:
    """The fields of an :class:`EpisodeResult` that come from the schedule: ``plan_names``,
    ``plan_starts``, ``arc_window`` (of ``schedule[arc_index]``) and the arc plan's own
    ``plan_log`` (its ``t`` column moved to episode time)."""
    arc = schedule[arc_index]
    plan_log = {}
    log_table = getattr(arc.plan, "log_table", None)
    if callable(log_table):
        plan_log = dict(log_table())
        if "t" in plan_log:
            plan_log["t"] = plan_log["t"] + arc.t_start
    return {
        "plan_names": tuple(s.plan.name for s in schedule),
        "plan_starts": np.array([s.t_start for s in schedule]),
        "arc_window": np.array([arc.t_start, arc.t_start + arc.plan.duration]),
        "plan_log": plan_log,
    }
