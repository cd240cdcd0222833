"""LCM test infrastructure: a bus of its own per test, a listener, a driver process.

Import the fixtures into a test module (``from lcm_fixtures import lcm_url  # noqa: F401``).

- ``lcm_url``: a loopback multicast URL ``udpm://239.255.76.67:PORT?ttl=0`` with a port of
  its own (random in 20000-59999, never twice in a session and never LCM's 7667), so tests,
  and the test runs of people sharing this machine, do not hear each other; ``ttl=0`` keeps
  it on this host.
- ``multicast_route`` (session; ``lcm_url`` uses it): checks once that LCM delivers on this
  host. In a network namespace without a multicast route it delivers nothing (LCM only
  warns): then the tests that need the bus are skipped with the fix in the message, or fail
  under CI (``CI`` set), where ``.ci/run`` must have added the route.
- :class:`BusListener`: a plain ``pydrake.lcm.DrakeLcm`` subscriber in the test process,
  decoding Drake's lcmtypes and stamping each message with its receipt time.
- :func:`sim_driver_process`: ``doorlab sim-driver`` as a child process at real-time
  priority where it can be had (tests/realtime_priority.py; killed at the end of the test
  whatever happens).
"""

from __future__ import annotations

import contextlib
import os
import random
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import realtime_priority

MULTICAST_GROUP = "239.255.76.67"
_used_ports: set[int] = set()
_random = random.SystemRandom()


def unique_port() -> int:
    """A UDP port for one test's bus: random in [20000, 60000), not reused in this session."""
    while True:
        port = _random.randrange(20000, 60000)
        if port not in _used_ports and port != 7667:
            _used_ports.add(port)
            return port


def bus_url(port: int | None = None) -> str:
    """A loopback multicast LCM URL on ``port`` (default: a fresh :func:`unique_port`)."""
    return f"udpm://{MULTICAST_GROUP}:{port or unique_port()}?ttl=0"


@pytest.fixture(scope="session")
def multicast_route() -> None:
    """Skips (or under CI fails) when LCM's loopback multicast delivers nothing here."""
    from doorlab.hardware.protocol import MULTICAST_ROUTE_HINT, lcm_delivers

    url = bus_url()
    if lcm_delivers(url, timeout=2.0):
        return
    message = f"LCM multicast delivers nothing on this host ({url}): {MULTICAST_ROUTE_HINT}"
    if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
        pytest.fail(f"{message}; .ci/run should have added the route")
    pytest.skip(message)


@pytest.fixture
def lcm_url(multicast_route) -> str:
    """A loopback multicast LCM URL with a port of this test's own."""
    return bus_url()


class BusListener:
    """Subscribes to channels on ``url`` and keeps every decoded message with its receipt time.

    A ``DrakeLcm`` subscription holds one undelivered message: a listener that is not polling
    (the test process descheduled) can miss some, so tests count what was *sent* from utime.

    Args:
        url: The bus.
        channels: {channel: lcmtype class} to decode.
    """

    def __init__(self, url: str, channels: dict[str, type]):
        from pydrake.lcm import DrakeLcm

        self.lcm = DrakeLcm(url)
        self.messages: dict[str, list[tuple[float, object]]] = {ch: [] for ch in channels}
        self.handlers: list[Callable[[str, float, object], None]] = []
        for channel, lcm_type in channels.items():
            self.lcm.Subscribe(channel, self._handler(channel, lcm_type))

    def _handler(self, channel: str, lcm_type: type):
        def handle(data: bytes) -> None:
            received = time.monotonic()
            message = lcm_type.decode(data)
            self.messages[channel].append((received, message))
            for handler in self.handlers:
                handler(channel, received, message)

        return handle

    def poll(self, seconds: float, until: Callable[[], bool] | None = None) -> bool:
        """Handles messages for ``seconds`` [s], or until ``until()`` is true (returns it)."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            if until is not None and until():
                return True
            self.lcm.HandleSubscriptions(2)
        return until() if until is not None else False

    def wait_for(self, channel: str, count: int = 1, timeout: float = 60.0) -> None:
        """Polls until ``count`` messages arrived on ``channel``; fails after ``timeout`` [s]."""
        if not self.poll(timeout, lambda: len(self.messages[channel]) >= count):
            pytest.fail(f"no {channel} within {timeout:g} s")

    def publish(self, channel: str, message) -> None:
        self.lcm.Publish(channel, message.encode())


def paced_cli(args: list[str], env: dict[str, str] | None = None) -> subprocess.Popen:
    """``doorlab ARGS`` as a child process paced to the wall clock (a driver or a client of
    the bus): text pipes, real-time priority where it can be had (tests/realtime_priority.py)."""
    return subprocess.Popen(
        [sys.executable, "-m", "doorlab.cli", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=realtime_priority.preexec(),
    )


@contextlib.contextmanager
def sim_driver_process(url: str, *args: str, out: Path | None = None) -> Iterator[subprocess.Popen]:
    """``doorlab sim-driver --lcm-url URL [--out OUT] ARGS`` as a child process (text pipes).

    The process is killed when the block ends if it is still running.
    """
    command = ["sim-driver", "--lcm-url", url, *args]
    if out is not None:
        command += ["--out", str(out)]
    process = paced_cli(command)
    try:
        yield process
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGKILL)
        process.communicate(timeout=30)


def stop(process: subprocess.Popen, signum: int = signal.SIGTERM, timeout: float = 60.0):
    """Sends ``signum`` and returns (exit code, stdout, stderr)."""
    process.send_signal(signum)
    out, err = process.communicate(timeout=timeout)
    return process.returncode, out, err
