"""The grader's channel to a student's process waits as long as the test's clock allows
(doorlab.pset.isolation.channel, doorlab.pset.rules.clock)."""

from __future__ import annotations

import os
import time

import pytest

from doorlab.pset.isolation.channel import Channel, ChannelTimeout


class _Clock:
    """A test's clock whose count moves slower than the wall clock, as a Clock's does while
    its process waits for a CPU: ``remaining()`` gives each of ``left`` [s] in turn."""

    def __init__(self, *left: float) -> None:
        self.left, self.asked = list(left), 0

    def remaining(self) -> float:
        self.asked += 1
        return self.left.pop(0) if self.left else 0.0


def test_a_wait_lasts_until_the_test_s_own_time_is_spent():
    """A poll times out in wall time; when the clock still has time left (its process waited
    for a CPU meanwhile), the channel waits on. Once ended a wait here on a loaded host
    before the test's time was spent, and the grading said "the machine is too loaded to
    time this test" to an endless loop, which is the student's: no verdict."""
    rfd, wfd = os.pipe()
    try:
        channel = Channel(rfd, wfd)
        clock = _Clock(0.02, 0.01, 0.01)
        start = time.monotonic()
        with pytest.raises(ChannelTimeout, match="no answer in time"):
            channel.receive(clock)
        assert clock.asked == 4  # three waits, then the clock said its time was spent
        assert time.monotonic() - start >= 0.04 - 0.005  # each wait its full length (poll: ms)
        os.write(wfd, b"x")  # something to read: a wait with time left returns at once
        start = time.monotonic()
        channel._wait(rfd, _Clock(5.0), "for an answer")
        assert time.monotonic() - start < 1.0
    finally:
        os.close(rfd)
        os.close(wfd)
