"""A minimal in-process stand-in for an iiwa + WSG driver on ``memq://``, for the client's
unit tests: deterministic, on a virtual clock the test advances.

Each :meth:`FakeDriver.pump` call first delivers what the client published (the driver takes
the last IIWA_COMMAND), then, if the next 5 ms status time falls within the timeout, moves its
clock there and publishes IIWA_STATUS (and SCHUNK_WSG_STATUS every 50 ms): the arm's measured
q is the last command received (an ideal arm, one status late), the fingers close on a 10 mm
handle. It does no physics: the
closed-loop tests use ``doorlab sim-driver``.

With ``late_copy``, each status delivered is sent once more and left on the bus for the
client's next read: a status that arrives while the client computes, as one does over UDP
when the client is slow (the client skips it: its utime is not newer). A client that read the
bus inside ``Simulator.AdvanceTo`` would run its Python handler there (issue 45).
"""

from __future__ import annotations

import numpy as np
from drake import (
    lcmt_iiwa_command,
    lcmt_iiwa_status,
    lcmt_schunk_wsg_command,
    lcmt_schunk_wsg_status,
)
from pydrake.lcm import DrakeLcm

STATUS_PERIOD = 0.005


class FakeDriver:
    def __init__(
        self, q0, *, utime0: int = 1_000_000, negative_first: int = 0, late_copy: bool = False
    ):
        self.lcm = DrakeLcm("memq://")
        self.t = 0.0  # virtual clock [s]
        self.next_status = 0.0
        self.q = np.array(q0, float)
        self.q_commanded = self.q.copy()
        self.tau_commanded = np.zeros(7)
        self.utime0 = utime0
        self.negative_first = negative_first
        self.late_copy = late_copy
        self.sent = 0
        self.alive = True
        self.commands: list[lcmt_iiwa_command] = []
        self.command_times: list[float] = []
        self.wsg_commands: list[lcmt_schunk_wsg_command] = []
        self.statuses: list[lcmt_iiwa_status] = []
        self.lcm.Subscribe("IIWA_COMMAND", self._on_command)
        self.lcm.Subscribe("SCHUNK_WSG_COMMAND", self._on_wsg)
        self.width = 0.03

    def clock(self) -> float:
        return self.t

    def _on_command(self, data: bytes) -> None:
        message = lcmt_iiwa_command.decode(data)
        self.commands.append(message)
        self.command_times.append(self.t)
        self.q_commanded = np.array(message.joint_position)
        self.tau_commanded = np.array(message.joint_torque)

    def _on_wsg(self, data: bytes) -> None:
        message = lcmt_schunk_wsg_command.decode(data)
        self.wsg_commands.append(message)
        # The fingers stop on a 10 mm handle when told to close further.
        self.width = max(message.target_position_mm / 1e3, 0.0099)

    def pump(self, timeout: float) -> None:
        self.lcm.HandleSubscriptions(0)  # the client's commands reach the driver
        sent = self.alive and self.next_status <= self.t + timeout + 1e-12
        if sent:
            self.t = self.next_status
            self.next_status += STATUS_PERIOD
            self._publish()
        else:
            self.t += timeout
        self.lcm.HandleSubscriptions(0)  # the status reaches the client
        if sent and self.late_copy:  # left for the client's next read
            self.lcm.Publish("IIWA_STATUS", self.statuses[-1].encode())

    def _publish(self) -> None:
        self.q = self.q_commanded.copy()  # an ideal arm, one status late
        s = lcmt_iiwa_status()
        negative = self.sent < self.negative_first
        s.utime = -1 if negative else self.utime0 + round(self.t * 1e6)
        s.num_joints = 7
        s.joint_position_measured = self.q.tolist()
        s.joint_position_commanded = self.q_commanded.tolist()
        s.joint_position_ipo = self.q_commanded.tolist()
        s.joint_velocity_estimated = [0.0] * 7
        s.joint_torque_measured = self.tau_commanded.tolist()
        s.joint_torque_commanded = self.tau_commanded.tolist()
        s.joint_torque_external = [0.0] * 7
        self.lcm.Publish("IIWA_STATUS", s.encode())
        self.statuses.append(s)
        self.sent += 1
        if round(self.t / STATUS_PERIOD) % 10 == 0:
            w = lcmt_schunk_wsg_status()
            w.utime = s.utime
            w.actual_position_mm = 1e3 * self.width
            w.actual_force = 0.0
            w.actual_speed_mm_per_s = 0.0
            self.lcm.Publish("SCHUNK_WSG_STATUS", w.encode())
