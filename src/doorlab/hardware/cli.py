"""The ``--hardware`` branch of ``doorlab run``: options, the confirmation, the summary."""

from __future__ import annotations

import argparse
import ipaddress
import re
import sys
from pathlib import Path

from doorlab.config import Scenario
from doorlab.errors import ConfigError, NoDriver
from doorlab.runs import EXIT_CODES

LCM_PROVIDERS = ("udpm", "memq", "tcpq", "file")


def check_lcm_url(url: str | None) -> str | None:
    """``url`` if LCM can open it (a known provider; for udpm a multicast address and port).

    Raises:
        ConfigError: It cannot (LCM itself would only print a warning and receive nothing).
    """
    if url is None:
        return None
    match = re.fullmatch(r"([a-z]+)://([^?]*)(\?.*)?", url)
    if match is None or match.group(1) not in LCM_PROVIDERS:
        raise ConfigError(
            f"--lcm-url {url!r} is not an LCM URL; use one of "
            f"{', '.join(p + '://...' for p in LCM_PROVIDERS)}, e.g. udpm://239.255.76.67:7667"
        )
    if match.group(1) == "udpm":
        host, _, port = match.group(2).partition(":")
        try:
            multicast = ipaddress.ip_address(host).is_multicast
        except ValueError:
            multicast = False
        if not multicast or not port.isdigit() or not 0 < int(port) < 65536:
            raise ConfigError(
                f"--lcm-url {url!r}: udpm needs a multicast address (224.0.0.0-239.255.255.255) "
                "and a port, e.g. udpm://239.255.76.67:7667"
            )
    return url


def _confirm(yes: bool):
    def confirm(plan: str) -> bool:
        print(plan, flush=True)
        if yes:
            return True
        if not sys.stdin.isatty():
            raise ConfigError("no terminal to confirm on; pass --yes to run without the question")
        try:
            answer = input("Move the arm? [y/N] ")
        except EOFError:
            return False
        return answer.strip().lower() in ("y", "yes")

    return confirm


def run_hardware_command(args: argparse.Namespace, scenario: Scenario) -> int:
    """``doorlab run --hardware``; returns the exit code."""
    from doorlab.hardware.link import DriverLink
    from doorlab.hardware.run import check_out_dir, hardware_summary, run_hardware_to_folder

    if args.meshcat or args.realtime is not None:
        raise ConfigError(
            "--meshcat and --realtime do not apply to --hardware (it runs on the arm)"
        )
    url = check_lcm_url(args.lcm_url)
    out = args.out or Path("doorlab_out") / f"{scenario.controller}_{scenario.doors}_hardware"
    check_out_dir(out, force=args.force)
    link = DriverLink(url=url)
    print(
        f"doorlab run --hardware: waiting up to {args.wait:g} s for IIWA_STATUS on {link.url}",
        flush=True,
    )
    try:
        first = link.wait_first_status(args.wait)
        outcome = run_hardware_to_folder(
            scenario,
            out,
            link=link,
            wait=args.wait,
            confirm=_confirm(args.yes),
            force=args.force,
            replay=not args.no_replay,
            first=first,
        )
    except NoDriver as e:
        print(f"doorlab run: error: {e}", file=sys.stderr)
        return EXIT_CODES["driver_lost"]
    print(hardware_summary(outcome), flush=True)
    return outcome.exit_code
