"""The ``--hardware`` branch of ``doorlab run``: options, the confirmation, the summary."""

from __future__ import annotations

import argparse
import atexit
import os
import sys
from pathlib import Path

from doorlab.config import Scenario
from doorlab.errors import ConfigError, NoDriver
from doorlab.hardware.protocol import resolve_lcm_url
from doorlab.runs import EXIT_CODES


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
    url = resolve_lcm_url(args.lcm_url)  # a second process: not memq
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
        return _exit_promptly(EXIT_CODES["driver_lost"])
    print(hardware_summary(outcome), flush=True)
    return _exit_promptly(outcome.exit_code)


def _exit_promptly(code: int) -> int:
    """Returns ``code``; when this process is the ``doorlab`` program, it also ends it as
    soon as the interpreter starts to exit, skipping the 0.1-0.5 s that tearing down Drake's
    objects takes: the folder is written, the streams are flushed (a stopped arm's client
    should be gone at once). Not when called in-process (tests, notebooks)."""
    main = sys.modules.get("__main__")
    spec = getattr(main, "__spec__", None)
    program = os.path.basename(sys.argv[0]) == "doorlab" or (
        spec is not None and spec.name == "doorlab.cli"
    )
    if program:

        def leave() -> None:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)

        atexit.register(leave)
    return code
