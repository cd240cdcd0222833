"""``doorlab sim-driver``: serve the simulated cell on the bus until a signal, then write its
ground truth.

Exit codes: 0 when ``--duration`` ran out, 130 (Ctrl-C) / 143 (SIGTERM) / 129 (SIGHUP) when a
signal stopped it (the normal way), 1 when it aborted (a command within the start guard), the
simulation failed, or LCM delivers nothing on this host; 2 for bad input. With ``--out`` the
folder is written on every one of these ends except bad input and a dead bus, atomically.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

from doorlab.config import Scenario
from doorlab.errors import DoorlabError
from doorlab.hardware.protocol import (
    IIWA_COMMAND_CHANNEL,
    IIWA_STATUS_CHANNEL,
    IIWA_STATUS_PERIOD,
    MULTICAST_ROUTE_HINT,
    WSG_COMMAND_CHANNEL,
    WSG_STATUS_CHANNEL,
    WSG_STATUS_PERIOD,
    lcm_delivers,
)
from doorlab.hardware.sim_driver import SimDriver


class LcmUnavailable(DoorlabError):
    """LCM delivers nothing on this host (no multicast route)."""


def serve(
    scenario: Scenario,
    *,
    lcm_url: str,
    out: Path | None = None,
    force: bool = False,
    utime_warmup: bool = False,
    duration: float = math.inf,
    realtime_rate: float = 1.0,
) -> int:
    """Runs ``doorlab sim-driver``: checks the bus, serves until a signal, writes ``out``.

    Args:
        scenario: The station and its initial state (validated by the caller).
        lcm_url: A checked URL (:func:`doorlab.hardware.protocol.resolve_lcm_url`).
        out: Write the ground truth there on exit (None: nothing is written).
        force: Replace ``out`` if it exists.
        utime_warmup: utime -1 in the first 200 statuses.
        duration: Stop after this much simulated time [s] (default: at a signal).
        realtime_rate: 1 keeps pace with the wall clock.

    Returns:
        The exit code (see the module docstring).

    Raises:
        OutputError: ``out`` cannot be written. LcmUnavailable: nothing arrives on the bus.
    """
    from doorlab.runtime.folders import commit_output, discard_output, prepare_output

    staging = prepare_output(out, force=force) if out is not None else None
    try:
        if lcm_url.startswith("udpm://") and not lcm_delivers(lcm_url):
            raise LcmUnavailable(
                f"LCM on {lcm_url} delivers nothing on this host: {MULTICAST_ROUTE_HINT}"
            )
        driver = SimDriver(
            scenario, lcm_url=lcm_url, utime_warmup=utime_warmup, record=out is not None
        )
        until = f"for {duration:g} s" if math.isfinite(duration) else "until Ctrl-C or SIGTERM"
        print(
            f"doorlab sim-driver: the simulated cell (doors {scenario.doors}) on {lcm_url}, "
            f"{until}: {IIWA_STATUS_CHANNEL} every {1e3 * IIWA_STATUS_PERIOD:g} ms, "
            f"{WSG_STATUS_CHANNEL} every {1e3 * WSG_STATUS_PERIOD:g} ms; reading "
            f"{IIWA_COMMAND_CHANNEL}, {WSG_COMMAND_CHANNEL}"
            + ("; utime -1 in the first 200 statuses" if utime_warmup else ""),
            flush=True,
        )
        outcome = driver.run(duration=duration, realtime_rate=realtime_rate)
        if staging is not None:
            driver.write_output(staging)
            commit_output(staging, out)
    except BaseException:
        if staging is not None:
            discard_output(staging)
        raise
    facts = driver.summary()
    print(
        f"doorlab sim-driver: {outcome.status} at t = {outcome.sim_time_s:.3f} s: "
        f"{facts['iiwa_statuses_sent']} statuses sent, {facts['iiwa_commands_received']} iiwa "
        f"and {facts['wsg_commands_received']} gripper commands read, real-time rate "
        f"{outcome.realtime_rate:.3f}"
        + (
            f"; {facts['iiwa_commands_late']} of {facts['iiwa_commands_applied']} iiwa commands "
            "applied a cycle or more after the one following their status"
            if "iiwa_commands_late" in facts
            else ""
        )
        + (f"; ground truth in {out}" if out is not None else ""),
        flush=True,
    )
    if outcome.status in ("aborted", "failed"):
        print(f"doorlab sim-driver: error: {outcome.message}", file=sys.stderr)
    return outcome.exit_code
