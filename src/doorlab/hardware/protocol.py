"""The LCM protocol of the real cell's drivers: channels, rates, utime, the start guard.

Facts read from the drivers' sources (drake-iiwa-driver ``kuka-driver/kuka_driver.cc``,
drake-schunk-driver ``src/schunk_driver.cc``) and Drake's ``manipulation/kuka_iiwa`` and
``manipulation/schunk_wsg`` LCM systems; the messages are Drake's lcmtypes
(``from drake import lcmt_iiwa_status, lcmt_iiwa_command, lcmt_schunk_wsg_status,
lcmt_schunk_wsg_command``).

============================  ==========================  =====================================
channel                       message                     sent
============================  ==========================  =====================================
``IIWA_STATUS``               ``lcmt_iiwa_status``        driver -> client, every FRI step, 5 ms
``IIWA_COMMAND``              ``lcmt_iiwa_command``       client -> driver, one per status
``SCHUNK_WSG_STATUS``         ``lcmt_schunk_wsg_status``  driver -> client, about 20 Hz
``SCHUNK_WSG_COMMAND``        ``lcmt_schunk_wsg_command`` client -> driver
============================  ==========================  =====================================

The iiwa driver (``kuka_driver``, FRI in position or position-and-torque mode):

- **Status.** One ``IIWA_STATUS`` per FRI step (``--time_step 0.005``): joint position
  measured and commanded, ``joint_position_ipo`` (NaN when FRI has none), velocity estimated
  (a 40 Hz low-pass of the position's finite difference), torque measured, commanded and
  external, all 7 joints.
- **utime.** The robot's clock mapped to host time, microseconds since the epoch, by a filter
  of the clock difference; it is **-1 until the filter has 200 samples** (the first second).
  A client must not answer those statuses. A command whose utime is -1 means "no command".
- **Start guard.** A command received before the first status, or within
  :data:`START_COMMAND_GUARD` (0.25 s) of it, makes the driver throw ("First command received
  within guard time. Aborting.") and exit: it guards against a controller left running from
  an earlier session. A client waits (doorlab's waits 0.3 s) before its first command.
- **Commands.** The driver keeps only the newest command (subscription queue 1) and applies
  it at the next FRI cycle: each cycle it handles the commands that arrived, reads the robot
  state, hands FRI the newest command and then publishes that cycle's status, so the command
  that answers status k acts from cycle k + 1 (one period after its state) and the status
  after that reports it as commanded (:mod:`doorlab.kuka`). In position mode a command never
  expires: the arm holds the last one when commands stop; before the first command it holds
  the position measured when FRI entered command mode. ``joint_position`` is clamped to the
  joint limits less
  :data:`JOINT_LIMIT_MARGIN` (1 deg); in position-and-torque mode ``joint_torque`` is the
  feed-forward torque (zero when ``num_torques`` is 0). The joint impedance that tracks the
  position is KUKA's, set in the robot's Java application, not over LCM.
- **External torque.** The driver stops (throws) when the external torque of a joint exceeds
  :data:`EXTERNAL_TORQUE_LIMITS`.

The gripper driver (``schunk_driver``): every 50 ms (``usleep(50000)`` after each task, so a
little under 20 Hz) it applies the newest ``SCHUNK_WSG_COMMAND`` (``target_position_mm``, the
finger separation [mm], and ``force`` [N], its absolute value) and publishes
``SCHUNK_WSG_STATUS`` (``actual_position_mm``, ``actual_speed_mm_per_s``, ``actual_force``),
utime host time [us].

LCM itself: ``udpm://GROUP:PORT?ttl=N`` is UDP multicast; ``ttl=0`` keeps it on this host.
Multicast loops back to the host's own sockets, but only where a route covers the group: a
fresh network namespace has none (``ip route add 224.0.0.0/4 dev lo`` adds one), and without
it LCM only warns and delivers nothing. ``memq://`` is an in-process queue (one process only).
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import sys
import time
from collections.abc import Iterator

from doorlab.errors import ConfigError
from doorlab.kuka import (  # noqa: F401 (the protocol's facts, named here too)
    CYCLE_PERIOD,
    DRIVER_JOINT_LIMITS,
    JOINT_LIMIT_MARGIN,
    external_torque_limits,
)

IIWA_STATUS_CHANNEL = "IIWA_STATUS"
IIWA_COMMAND_CHANNEL = "IIWA_COMMAND"
WSG_STATUS_CHANNEL = "SCHUNK_WSG_STATUS"
WSG_COMMAND_CHANNEL = "SCHUNK_WSG_COMMAND"

IIWA_STATUS_PERIOD = CYCLE_PERIOD
"""The iiwa driver's status period [s] (kuka_driver ``--time_step``, FRI's 5 ms)."""
WSG_STATUS_PERIOD = 0.05
"""The gripper driver's status period [s] (schunk_driver sleeps 50 ms between tasks)."""
START_COMMAND_GUARD = 0.25
"""A command within this long of the first status aborts the iiwa driver [s]
(kuka_driver ``--start_command_guard``)."""
UTIME_WARMUP_STATUSES = 200
"""The iiwa driver sends utime -1 until its clock filter has this many samples."""
NO_COMMAND_UTIME = -1
"""utime of a status before the clock filter is ready, and of a command meaning "none"."""

EXTERNAL_TORQUE_LIMITS = external_torque_limits()
"""|external torque| per joint above which kuka_driver stops [N m] (``--ext_trq_limit`` 60
times its per-joint scale); ``station.driver.external_torque_limit`` sets the 60."""

DEFAULT_LCM_URL = "udpm://239.255.76.67:7667?ttl=0"
"""LCM's default URL (used when neither --lcm-url nor ``LCM_DEFAULT_URL`` is set)."""
MULTICAST_ROUTE_HINT = (
    "is there a multicast route? (`ip route get 239.255.76.67`; as root: "
    "`ip route add 224.0.0.0/4 dev lo`)"
)

_UDPM = re.compile(r"udpm://(\d{1,3})\.(\d{1,3})\.(\d{1,3})\.(\d{1,3}):(\d{1,5})(?:\?(.*))?")
_UDPM_OPTIONS = {"ttl": (0, 255), "recv_buf_size": (1, 2**31 - 1)}


def resolve_lcm_url(url: str | None, *, allow_memq: bool = False) -> str:
    """The LCM URL to use, checked: ``url``, else ``LCM_DEFAULT_URL``, else LCM's default.

    Drake's ``DrakeLcm`` accepts a malformed URL with a printed warning and then delivers
    nothing, so the URL is checked here first.

    Args:
        url: ``udpm://GROUP:PORT[?ttl=N]`` (GROUP a multicast address, 224-239.x.x.x), or
            None for the environment's / LCM's default.
        allow_memq: Also accept ``memq://`` (one process only: the driver and its client in
            the same process).

    Raises:
        ConfigError: The URL is not of that form (the message names the valid forms).
    """
    source = "--lcm-url"
    if url is None:
        url = os.environ.get("LCM_DEFAULT_URL") or DEFAULT_LCM_URL
        source = "LCM_DEFAULT_URL"
    valid = "udpm://GROUP:PORT[?ttl=N] with GROUP in 224.0.0.0-239.255.255.255"
    if allow_memq:
        valid += ", or memq://"
        if url == "memq://":
            return url
    elif url.startswith("memq://"):
        raise ConfigError(
            f"{source} {url!r}: memq:// works inside one process only; the driver and its "
            f"client are two processes here, use {valid}"
        )
    match = _UDPM.fullmatch(url)
    if match is None:
        raise ConfigError(f"{source} {url!r} is not an LCM URL: use {valid}")
    octets = [int(g) for g in match.groups()[:4]]
    port = int(match.group(5))
    if not 224 <= octets[0] <= 239 or any(o > 255 for o in octets):
        raise ConfigError(
            f"{source} {url!r}: {'.'.join(match.groups()[:4])} is not a multicast "
            f"group; use {valid}"
        )
    if not 1 <= port <= 65535:
        raise ConfigError(f"{source} {url!r}: port {port} is not in 1-65535")
    for option in filter(None, (match.group(6) or "").split("&")):
        key, _, value = option.partition("=")
        if key not in _UDPM_OPTIONS:
            raise ConfigError(
                f"{source} {url!r}: unknown option {key!r} (valid: {', '.join(_UDPM_OPTIONS)})"
            )
        low, high = _UDPM_OPTIONS[key]
        if not value.isdigit() or not low <= int(value) <= high:
            raise ConfigError(f"{source} {url!r}: {key} must be an integer in [{low}, {high}]")
    return url


def lcm_delivers(url: str, *, timeout: float = 1.0) -> bool:
    """Whether a message published on ``url`` reaches another socket of this host within
    ``timeout`` [s].

    True on a host with a multicast route, false in a network namespace without one (where
    LCM only warns and delivers nothing between processes). It publishes from one
    ``DrakeLcm`` and listens on a second: one instance hears its own messages even without a
    route. The channel is its own, so it disturbs no one on the bus.
    """
    from pydrake.lcm import DrakeLcm

    with _quiet_stderr():  # without a route LCM prints a page of advice per instance
        sender, receiver = DrakeLcm(url), DrakeLcm(url)
        channel = f"DOORLAB_LOOPBACK_{os.getpid()}_{secrets.token_hex(4)}"
        received = []
        receiver.Subscribe(channel, received.append)
        deadline = time.monotonic() + timeout
        while not received and time.monotonic() < deadline:
            sender.Publish(channel, b"doorlab")
            receiver.HandleSubscriptions(50)
    return bool(received)


@contextlib.contextmanager
def _quiet_stderr() -> Iterator[None]:
    """Sends what C code writes to file descriptor 2 to /dev/null for the block."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
