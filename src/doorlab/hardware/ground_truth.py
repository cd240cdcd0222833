"""The simulated driver's ground truth: what the simulated cell did, as named arrays.

``doorlab sim-driver --out DIR`` writes ``DIR/ground_truth.npz`` (:class:`GroundTruth`),
``DIR/driver.json`` (how the run went: status, URL, statuses sent, commands read, real-time
rate) and ``DIR/scenario.yaml``. A client's logs join the ground truth by time: a status at
simulation time t carries utime round(t * 1e6) (:func:`status_utime`).
"""

from __future__ import annotations

import io
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from doorlab.cell.frames import LEFT_HINGE, RIGHT_HINGE
from doorlab.cell.station import Station
from doorlab.hardware.protocol import IIWA_STATUS_PERIOD, UTIME_WARMUP_STATUSES

GROUND_TRUTH_FILE = "ground_truth.npz"
DRIVER_FILE = "driver.json"
SCENARIO_FILE = "scenario.yaml"


@dataclass(frozen=True)
class GroundTruth:
    """What the simulated cell did, sampled every log period (named channels).

    Attributes:
        t: Sample times (n,) [s], simulation time: the cell just after the plant step at t,
            as the status at t (utime t * 1e6) reports it.
        utime: The utime a status at t carries (n,) [us] (-1 in the warm-up).
        plant_state: The whole plant's [q; v] (n, nx). plant_positions: Its q (n, nq).
        q_measured: Arm joint positions (n, 7) [rad]. v_measured: Their rates (n, 7) [rad/s]
            (the plant's, exact).
        v_estimated: The status's velocity, kuka_driver's filter (n, 7) [rad/s].
        q_commanded: The command the arm tracked up to the status (after the driver's
            clamp; the status's joint_position_commanded) (n, 7) [rad].
        tau_feedforward: The feed-forward torque it tracked with it (n, 7) [N m].
        tau_commanded: The torque the joints receive (n, 7) [N m] (status torque commanded
            and measured). tau_external: Contact torques on the arm's joints (n, 7) [N m].
            These come from the last status at or before t (at t itself when the log period
            is a multiple of 5 ms).
        door_angles: Hinge angles (n, 2) [rad], columns (left, right).
        wsg_width: Finger separation (n,) [m]. wsg_speed: Its rate (n,) [m/s].
        wsg_force: Grip force (n,) [N].
        wsg_position_commanded: The separation commanded (n,) [m].
        wsg_force_limit: The force limit commanded (n,) [N].
    """

    t: np.ndarray
    utime: np.ndarray
    plant_state: np.ndarray
    plant_positions: np.ndarray
    q_measured: np.ndarray
    v_measured: np.ndarray
    v_estimated: np.ndarray
    q_commanded: np.ndarray
    tau_feedforward: np.ndarray
    tau_commanded: np.ndarray
    tau_external: np.ndarray
    door_angles: np.ndarray
    wsg_width: np.ndarray
    wsg_speed: np.ndarray
    wsg_force: np.ndarray
    wsg_position_commanded: np.ndarray
    wsg_force_limit: np.ndarray

    @classmethod
    def from_channels(
        cls,
        station: Station,
        t: np.ndarray,
        channels: dict[str, np.ndarray],
        *,
        utime_warmup: bool,
    ) -> GroundTruth:
        """The ground truth from the driver logger's channels.

        Args:
            station: The station whose plant the state belongs to.
            t: Sample times (n,) [s].
            channels: (n, size) arrays: ``plant_state``, ``v_estimated``, ``q_commanded``,
                ``tau_feedforward``, ``tau_commanded``, ``tau_external``, ``wsg_state``,
                ``wsg_force``, ``wsg_position_commanded``, ``wsg_force_limit``.
            utime_warmup: Whether the driver sent utime -1 in its first 200 statuses.
        """
        plant = station.plant
        x = channels["plant_state"]
        nq = plant.num_positions()
        q_all, v_all = x[:, :nq], x[:, nq:]
        arm_q = plant.GetPositionsFromArray(station.iiwa, np.arange(nq)).astype(int)
        arm_v = plant.GetVelocitiesFromArray(
            station.iiwa, np.arange(plant.num_velocities())
        ).astype(int)
        hinges = [
            plant.GetJointByName(h, station.cupboard).position_start()
            for h in (LEFT_HINGE, RIGHT_HINGE)
        ]
        return cls(
            t=t,
            utime=status_utime(t, utime_warmup=utime_warmup),
            plant_state=x,
            plant_positions=q_all,
            q_measured=q_all[:, arm_q],
            v_measured=v_all[:, arm_v],
            v_estimated=channels["v_estimated"],
            q_commanded=channels["q_commanded"],
            tau_feedforward=channels["tau_feedforward"],
            tau_commanded=channels["tau_commanded"],
            tau_external=channels["tau_external"],
            door_angles=q_all[:, hinges],
            wsg_width=channels["wsg_state"][:, 0],
            wsg_speed=channels["wsg_state"][:, 1],
            wsg_force=channels["wsg_force"][:, 0],
            wsg_position_commanded=channels["wsg_position_commanded"][:, 0],
            wsg_force_limit=channels["wsg_force_limit"][:, 0],
        )

    def save(self, path: str | Path) -> None:
        """Writes every channel to an ``.npz`` file (see :meth:`load`)."""
        buffer = io.BytesIO()
        np.savez_compressed(buffer, **{f.name: getattr(self, f.name) for f in fields(self)})
        Path(path).write_bytes(buffer.getvalue())

    @classmethod
    def load(cls, path: str | Path) -> GroundTruth:
        """Reads a file written by :meth:`save`."""
        with np.load(path, allow_pickle=False) as data:
            return cls(**{f.name: data[f.name] for f in fields(cls)})


def status_utime(t: np.ndarray | float, *, utime_warmup: bool) -> np.ndarray:
    """The utime [us] the simulated driver's status at simulation time ``t`` [s] carries."""
    t = np.asarray(t, dtype=float)
    utime = np.rint(t * 1e6).astype(np.int64)
    if utime_warmup:
        utime = np.where(t < (UTIME_WARMUP_STATUSES - 0.5) * IIWA_STATUS_PERIOD, -1, utime)
    return utime
