"""The ``--hardware`` branch of ``doorlab run``: options, the confirmation, the summary."""

from __future__ import annotations

import argparse
import atexit
import math
import os
import sys
from pathlib import Path

from doorlab.config import Scenario
from doorlab.errors import ConfigError, NoDriver
from doorlab.hardware.protocol import resolve_lcm_url
from doorlab.outputs.runs import EXIT_CODES


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


ANSWER_DELAY_ENV = "DOORLAB_TEST_ANSWER_DELAY_MS"
"""A test's knob: each command leaves this many milliseconds after its status arrived (a
client that slow to answer), 0-20 ms. Not for the arm: a real run leaves it unset."""


def _answer_delay() -> float:
    """The test knob's delay [s] (0 when unset)."""
    text = os.environ.get(ANSWER_DELAY_ENV)
    if not text:
        return 0.0
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0.0 <= value <= 20.0:
        raise ConfigError(f"{ANSWER_DELAY_ENV} must be a number of ms in [0, 20], got {text!r}")
    print(
        f"doorlab run --hardware: test knob {ANSWER_DELAY_ENV}: each answer leaves "
        f"{value:g} ms after its status",
        flush=True,
    )
    return 1e-3 * value


def run_hardware_command(args: argparse.Namespace, scenario: Scenario) -> int:
    """``doorlab run --hardware``; returns the exit code."""
    from doorlab.hardware.link import DriverLink
    from doorlab.hardware.run import check_out_dir, hardware_summary, run_hardware_to_folder

    if args.meshcat or args.realtime is not None:
        raise ConfigError(
            "--meshcat and --realtime do not apply to --hardware (it runs on the arm)"
        )
    url = resolve_lcm_url(args.lcm_url)  # a second process: not memq
    answer_delay = _answer_delay()
    from doorlab.episode.plugins import display_name

    name = display_name(scenario.controller)
    out = args.out or Path("doorlab_out") / f"{name}_{scenario.doors}_hardware"
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
            answer_delay=answer_delay,
        )
    except NoDriver as e:
        print(f"doorlab run: error: {e}", file=sys.stderr)
        return _exit_promptly(EXIT_CODES["driver_lost"])
    print(hardware_summary(outcome), flush=True)
    if outcome.status == "controller_error":  # a broken plug-in: its one line, exit 2
        print(f"doorlab run: error: {outcome.message}", file=sys.stderr, flush=True)
    return _exit_promptly(outcome.exit_code)


def _exit_promptly(code: int) -> int:
    """Returns ``code``; when this process is the ``doorlab`` program, it also ends it as
    soon as the interpreter starts to exit, skipping the 0.1-0.5 s that tearing down Drake's
    objects takes: the folder is written, the streams are flushed (a stopped arm's client
    should be gone at once). Not when called in-process (tests, notebooks)."""
    main = sys.modules.get("__main__")
    spec = getattr(main, "__spec__", None)
    program = os.path.basename(sys.argv[0]) == "doorlab" or (
        spec is not None and spec.name == "doorlab.cli.__main__"
    )
    if program:

        def leave() -> None:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)

        atexit.register(leave)
    return code


ANALYSE_EXCLUDES = ("lcm_url", "wait", "yes", "out", "repeats", "joints")
"""The options of an identification run that ``--analyse`` (no arm, no LCM) does not take."""


def run_identify_command(args: argparse.Namespace, scenario: Scenario) -> int:
    """``doorlab identify`` (the calibration over LCM, or ``--analyse DIR``); returns the exit
    code."""
    from doorlab.hardware.identify.run import (
        analyse_folder,
        check_scenario,
        identify_summary,
        run_identify,
    )
    from doorlab.hardware.identify.script import ScriptSettings
    from doorlab.hardware.link import DriverLink
    from doorlab.runtime.folders import check_replaceable

    check_scenario(scenario)
    if args.analyse is not None:
        given = [
            f"--{name.replace('_', '-')}"
            for name in ANALYSE_EXCLUDES
            if getattr(args, name) not in (None, False)
        ]
        if given or args.force:
            raise ConfigError(
                f"--analyse fits a recording (no arm, no LCM): it takes --config and --set "
                f"only, not {', '.join(given + (['--force'] if args.force else []))}"
            )
        outcome = analyse_folder(args.analyse, scenario)
        print(identify_summary(outcome), flush=True)
        return outcome.exit_code
    out = args.out if args.out is not None else Path("doorlab_out") / "identify"
    wait = args.wait if args.wait is not None else 5.0
    url = resolve_lcm_url(args.lcm_url)
    check_replaceable(out, force=args.force)
    settings = ScriptSettings(
        joints=args.joints if args.joints is not None else ScriptSettings().joints,
        repeats=args.repeats if args.repeats is not None else ScriptSettings().repeats,
    )
    link = DriverLink(url=url)
    print(
        f"doorlab identify: waiting up to {wait:g} s for IIWA_STATUS on {link.url}",
        flush=True,
    )
    try:
        first = link.wait_first_status(wait)
        outcome = run_identify(
            scenario,
            out,
            link=link,
            wait=wait,
            confirm=_confirm(args.yes),
            settings=settings,
            force=args.force,
            first=first,
        )
    except NoDriver as e:
        print(f"doorlab identify: error: {e}", file=sys.stderr)
        return _exit_promptly(EXIT_CODES["driver_lost"])
    print(identify_summary(outcome), flush=True)
    return _exit_promptly(outcome.exit_code)
