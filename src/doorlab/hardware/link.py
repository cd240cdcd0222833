"""The LCM link to the drivers: every IIWA_STATUS as it arrives, waiting for the next one.

A ``DrakeLcm`` subscription keeps one message, the oldest, until it is handled: a client that
stops handling for a while then reads a stale status first. :meth:`DriverLink.drain` discards
what waited; the episode handles subscriptions continuously, blocking in
``HandleSubscriptions`` until the next status or its watchdog's deadline.

The link is the only reader of its bus: nothing else may call ``HandleSubscriptions`` on its
``DrakeLcm`` from inside ``Simulator.AdvanceTo`` (an ``LcmInterfaceSystem`` in a diagram does
so at every step). pydrake's ``AdvanceTo`` releases the GIL (Drake >= 1.26), and its
``DrakeLcm.Subscribe`` builds each message's ``bytes`` for the Python handler before taking
the GIL back (every Drake to 1.58, pybind11 and nanobind alike): Python >= 3.12 then crashes
(its allocator's state is the running thread's, and there is none), 3.11 only races.
Handled from Python, as here, the GIL is held throughout (issue 45).
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from drake import lcmt_iiwa_status
from pydrake.lcm import DrakeLcm, DrakeLcmInterface

from doorlab.errors import NoDriver
from doorlab.hardware.protocol import IIWA_STATUS_CHANNEL as IIWA_STATUS
from doorlab.hardware.protocol import MULTICAST_ROUTE_HINT, resolve_lcm_url


@dataclass(frozen=True)
class Status:
    """One IIWA_STATUS as the link received it.

    Attributes:
        arrival: When it was handled, on the link's clock [s].
        utime: The driver's timestamp [us] (-1 until the real driver's clock is settled).
        q: joint_position_measured (7,) [rad].
        q_commanded: joint_position_commanded (7,) [rad] (the driver's echo of the last
            command it applies).
        v: joint_velocity_estimated (7,) [rad/s] (kuka_driver's filtered velocity).
        tau_external: joint_torque_external (7,) [N m] (KUKA's estimate).
    """

    arrival: float
    utime: int
    q: np.ndarray
    q_commanded: np.ndarray
    v: np.ndarray | None = None
    tau_external: np.ndarray | None = None

    @property
    def valid(self) -> bool:
        """A status with a real timestamp (utime >= 0)."""
        return self.utime >= 0


def _handle(lcm: DrakeLcmInterface) -> Callable[[float], None]:
    def pump(timeout: float) -> None:
        lcm.HandleSubscriptions(max(0, math.ceil(1e3 * timeout)))

    return pump


class DriverLink:
    """The statuses on an LCM URL, each stamped with its arrival time.

    Args:
        lcm: The LCM instance (default: a ``DrakeLcm`` on ``url``).
        url: The LCM URL (None: ``LCM_DEFAULT_URL``, else LCM's default,
            :func:`doorlab.hardware.protocol.resolve_lcm_url`).
        clock: The time [s] statuses are stamped with and deadlines are read on
            (``time.monotonic``; an in-process test passes its driver's clock).
        pump: ``pump(timeout)`` handles LCM messages for at most ``timeout`` [s] (default: the
            ``lcm``'s ``HandleSubscriptions``; an in-process test steps its driver there).
    """

    def __init__(
        self,
        lcm: DrakeLcmInterface | None = None,
        *,
        url: str | None = None,
        clock: Callable[[], float] = time.monotonic,
        pump: Callable[[float], None] | None = None,
    ):
        self.lcm = lcm if lcm is not None else DrakeLcm(resolve_lcm_url(url, allow_memq=True))
        self.url = self.lcm.get_lcm_url()
        self.clock = clock
        self._pump = pump or _handle(self.lcm)
        self._pending: deque[Status] = deque()
        self.first_arrival: float | None = None
        self.received = 0
        self.lcm.Subscribe(IIWA_STATUS, self._on_status)

    def _on_status(self, data: bytes) -> None:
        message = lcmt_iiwa_status.decode(data)
        arrival = self.clock()
        if self.first_arrival is None:
            self.first_arrival = arrival
        self.received += 1
        self._pending.append(
            Status(
                arrival,
                int(message.utime),
                np.array(message.joint_position_measured, float),
                np.array(message.joint_position_commanded, float),
                np.array(message.joint_velocity_estimated, float),
                np.array(message.joint_torque_external, float),
            )
        )

    def next_status(self, deadline: float) -> Status | None:
        """The next status received, waiting until ``deadline`` (on the clock) at most."""
        while not self._pending:
            remaining = deadline - self.clock()
            if remaining <= 0:
                return None
            self._pump(remaining)
        return self._pending.popleft()

    def waiting(self) -> int:
        """How many statuses are waiting to be read (after a non-blocking look)."""
        self._pump(0.0)
        return len(self._pending)

    def drain(self) -> None:
        """Handles what is waiting and forgets it (a stale status after a pause)."""
        self._pump(0.0)
        self._pending.clear()

    def wait_first_status(self, wait: float) -> Status:
        """The first valid status (utime >= 0) within ``wait`` [s].

        Raises:
            NoDriver: None came (the message names the URL, the channel and the route hint).
        """
        deadline = self.clock() + wait
        skipped = 0
        while True:
            status = self.next_status(deadline)
            if status is None:
                break
            if status.valid:
                return status
            skipped += 1
        if skipped:
            raise NoDriver(
                f"the driver on {self.url} sent {skipped} {IIWA_STATUS} messages in {wait:g} s, "
                "all with utime -1 (its clock is not settled yet); try a longer --wait"
            )
        raise NoDriver(
            f"no {IIWA_STATUS} on {self.url} within {wait:g} s: is the driver running "
            f"(doorlab sim-driver, or drake-iiwa-driver on the arm)? {MULTICAST_ROUTE_HINT}"
        )
