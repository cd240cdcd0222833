"""``doorlab sim-driver``'s library on memq://, stepped by a client's waits: deterministic
in-process runs of a hardware client (tests/test_hardware_wiring.py, tests/test_identify.py)."""

from __future__ import annotations

import math

from doorlab.config import Scenario
from doorlab.hardware.protocol import IIWA_STATUS_PERIOD
from doorlab.hardware.sim_driver import SimDriver


class SteppedDriver:
    """``doorlab sim-driver``'s library on memq://, advanced one status at a time by the
    client's waits (:class:`~doorlab.hardware.link.DriverLink`'s pump) on its own clock."""

    def __init__(self, scenario: Scenario):
        self.driver = SimDriver(scenario, lcm_url="memq://", record=True)
        self.lcm = self.driver.lcm
        self.simulator = self.driver.simulator
        self.simulator.set_target_realtime_rate(0.0)
        self.simulator.Initialize()
        self.offset = self.driver.systems.status_offset

    def clock(self) -> float:
        return self.driver.time

    def pump(self, timeout: float) -> None:
        t = self.driver.time
        k = math.floor((t - self.offset) / IIWA_STATUS_PERIOD + 1e-9) + 1
        t_next = k * IIWA_STATUS_PERIOD + self.offset  # when the driver publishes status k
        self.driver.systems.advance_to(
            self.simulator, t_next if t_next <= t + timeout + 1e-9 else t + timeout
        )
        self.lcm.HandleSubscriptions(0)  # deliver it
