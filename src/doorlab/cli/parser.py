"""The ``doorlab`` command: ``doorlab run`` (one controller), ``doorlab report`` (all),
``doorlab sweep`` (scenario fields over a grid or random samples), ``doorlab bench`` (the
benchmark card: :mod:`doorlab.cli.bench`) and ``doorlab sim-driver`` (the simulated cell
behind the real drivers' LCM protocol).

Bad input prints one line naming the valid choices and exits with code 2; a run's status
sets the exit code otherwise (see :data:`doorlab.outputs.runs.EXIT_CODES`).

The commands themselves live in :mod:`doorlab.cli.commands`, the argument types in
:mod:`doorlab.runtime.argtypes`, ``doorlab pset``'s subcommands' parsers in
:mod:`doorlab.cli.pset_parser` and the options several commands share in
:mod:`doorlab.cli.options`.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from doorlab.cli import commands
from doorlab.cli.bench import add_bench_parser, bench
from doorlab.cli.options import add_config_options, add_scheduler_options
from doorlab.cli.pset_parser import add_pset_parser
from doorlab.config import (
    CONTROLLERS,
    DOOR_STATES,
)
from doorlab.errors import (
    ConfigError,
    DoorlabError,
    OutputError,
    interrupt_exit_code,
)
from doorlab.runtime.argtypes import (
    MIN_REALTIME_RATE,
    USAGE_ERROR,
    OneLineParser,
    bounded_int,
    realtime_rate,
    seconds,
)
from doorlab.runtime.interrupts import install_signal_handlers

__all__ = ["MIN_REALTIME_RATE", "USAGE_ERROR", "OneLineParser", "bounded_int", "main"]


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``doorlab``."""
    parser = OneLineParser(
        prog="doorlab",
        description="Open a cupboard door with a simulated KUKA iiwa 7 six ways "
        "(pointwise IK, Jacobian velocity mapping, Jacobian-transpose impedance, an "
        "adaptive plan that does not know the hinge, differential IK with joint limits and "
        "operational-space impedance).",
    )
    parser.add_argument("--version", action="version", version=_version())
    sub = parser.add_subparsers(
        dest="command",
        metavar="{run,report,sweep,bench,pset,sim-driver,identify}",
        parser_class=OneLineParser,
    )

    run = sub.add_parser("run", help="run one controller and write its metrics, logs and plots")
    run.add_argument(
        "--controller",
        default=None,
        metavar="NAME",
        help=f"which controller: a built-in ({', '.join(CONTROLLERS)}), an installed plug-in's "
        "name, or a plug-in FILE.py:NAME or MODULE:NAME (docs/guides/controllers.md; default: "
        "velocity, or the config's)",
    )
    run.add_argument(
        "--doors",
        choices=DOOR_STATES,
        default=None,
        help="start with the doors open (free-space arc) or closed (default)",
    )
    run.add_argument(
        "--knots",
        type=bounded_int(2, 100),
        default=None,
        help="IK knot points along the arc, 2-100 (controller ik; default 10)",
    )
    run.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output folder (default: doorlab_out/<controller>_<doors>)",
    )
    add_config_options(run)
    run.add_argument(
        "--meshcat",
        action="store_true",
        help="draw the run live in Meshcat (prints the URL; runs in real time)",
    )
    run.add_argument(
        "--realtime",
        type=realtime_rate,
        default=None,
        help="real-time rate (0: as fast as possible; default 0, 1 with --meshcat)",
    )
    run.add_argument("--no-replay", action="store_true", help="skip replay.html (faster)")
    add_hardware_options(run)

    report = sub.add_parser("report", help="run the problem set's experiments and write index.html")
    report.add_argument(
        "--out",
        type=Path,
        default=Path("doorlab_report"),
        help="output folder (default: doorlab_report)",
    )
    _controllers(
        report,
        "also report this controller beside the built-ins (repeatable): an installed "
        "plug-in's name, FILE.py:NAME or MODULE:NAME; it runs with the doors open and closed, "
        "in the robustness grid and On the arm",
    )
    report.add_argument(
        "--jobs",
        type=bounded_int(1),
        default=None,
        help="parallel runs (default: the number of cores)",
    )
    report.add_argument(
        "--pdf",
        action="store_true",
        help="also print the page to report.pdf (needs headless Chromium)",
    )
    report.add_argument(
        "--robustness",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="also run the robustness section: every controller against five yaw errors of "
        "the cupboard, doors closed (more episodes than the rest of the report; what each "
        "section costs: docs/guides/experiments.md)",
    )
    report.add_argument(
        "--arm",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="also run the 'On the arm' section: every plan on the lab's iiwa (kuka_driver, "
        "KUKA's loop) with its verdict over the band of plausible arm models (the costliest "
        "section: docs/guides/experiments.md)",
    )
    report.add_argument(
        "--no-arm-band",
        action="store_true",
        help="with --arm: the arm preset only, without the band of plausible arm models (each "
        "plan's verdict then rests on the preset's assumptions)",
    )
    add_scheduler_options(report)
    add_config_options(report)

    sweep = sub.add_parser(
        "sweep",
        help="run scenario fields over a grid or random samples; write a table and a page",
    )
    sweep.add_argument(
        "spec",
        type=Path,
        nargs="?",
        default=None,
        metavar="SPEC.yaml",
        help="the sweep (see examples/sweep_impedance.yaml); optional with --grid",
    )
    sweep.add_argument(
        "--grid",
        action="append",
        default=[],
        metavar="KEY=V1,V2,...",
        help="sweep a scenario field over these values (repeatable; adds to SPEC's axes)",
    )
    _controllers(
        sweep,
        "sweep this controller instead of the SPEC's controllers (repeatable): a built-in, "
        "an installed plug-in's name, FILE.py:NAME or MODULE:NAME",
    )
    sweep.add_argument(
        "--out",
        type=Path,
        default=Path("doorlab_sweep"),
        help="output folder (default: doorlab_sweep)",
    )
    sweep.add_argument(
        "--jobs",
        type=bounded_int(1),
        default=None,
        help="local worker processes (default: the number of cores)",
    )
    add_scheduler_options(sweep)
    sweep.add_argument(
        "--resume", action="store_true", help="keep the runs already in --out's table"
    )
    sweep.add_argument(
        "--force", action="store_true", help="start over in an existing output folder"
    )
    add_bench_parser(sub, add_scheduler_options, add_config_options)
    add_pset_parser(sub)
    add_sim_driver_parser(sub)
    add_identify_parser(sub)
    return parser


def add_hardware_options(run: argparse.ArgumentParser) -> None:
    """``doorlab run --hardware [--lcm-url URL] [--wait S] [--yes]`` (docs/guides/real-arm.md)."""
    group = run.add_argument_group("the real arm (docs/guides/real-arm.md)")
    group.add_argument(
        "--hardware",
        action="store_true",
        help="run on the real iiwa + WSG over LCM (drake-iiwa-driver, drake-schunk-driver, "
        "or doorlab sim-driver)",
    )
    group.add_argument(
        "--lcm-url",
        default=None,
        metavar="URL",
        help="the drivers' LCM URL (default: Drake's, $LCM_DEFAULT_URL or "
        "udpm://239.255.76.67:7667?ttl=0)",
    )
    group.add_argument(
        "--wait",
        type=seconds(0.01, 3600.0),
        default=5.0,
        metavar="S",
        help="seconds to wait for the driver's first status (default 5)",
    )
    group.add_argument(
        "--yes", action="store_true", help="do not ask before the arm moves (the plan is printed)"
    )


def _controllers(parser: argparse.ArgumentParser, text: str) -> None:
    """A repeatable ``--controller NAME`` (a built-in or a plug-in)."""
    parser.add_argument("--controller", action="append", default=[], metavar="NAME", help=text)


def add_sim_driver_parser(sub) -> None:
    """``doorlab sim-driver``: the simulated cell behind the real drivers' LCM protocol."""
    driver = sub.add_parser(
        "sim-driver",
        help="serve the simulated cell over LCM as the iiwa and WSG drivers do (until Ctrl-C)",
    )
    driver.add_argument(
        "--lcm-url",
        default=None,
        metavar="URL",
        help="udpm://GROUP:PORT?ttl=N (default: $LCM_DEFAULT_URL, else "
        "udpm://239.255.76.67:7667?ttl=0)",
    )
    driver.add_argument(
        "--doors",
        choices=DOOR_STATES,
        default=None,
        help="start with the doors open or closed (default: closed, or the config's)",
    )
    driver.add_argument(
        "--out",
        type=Path,
        default=None,
        help="on exit write the ground truth here (ground_truth.npz, driver.json, scenario.yaml)",
    )
    driver.add_argument(
        "--utime-warmup",
        action="store_true",
        help="send utime -1 in the first 200 statuses, as the real driver does",
    )
    driver.add_argument(
        "--duration",
        type=seconds(0.01, 7 * 86400.0),
        default=None,
        metavar="S",
        help="stop after S seconds (default: run until Ctrl-C or SIGTERM)",
    )
    add_config_options(driver)


def _joints(text: str) -> tuple[int, ...]:
    """``--joints 1,2,7`` -> (0, 1, 6): distinct joint numbers 1-7."""
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if not parts or any(not p.isdigit() or not 1 <= int(p) <= 7 for p in parts):
        raise argparse.ArgumentTypeError(
            f"must be joint numbers 1-7 separated by commas (e.g. 1,2,7), got {text!r}"
        )
    return tuple(sorted({int(p) - 1 for p in parts}))


def add_identify_parser(sub) -> None:
    """``doorlab identify``: the arm's uncertain parameters measured on the arm over LCM."""
    identify = sub.add_parser(
        "identify",
        help="measure the lab arm's damping, friction, load data, latency and torque noise "
        "over LCM and write an arm preset (identified.yaml)",
    )
    identify.add_argument(
        "--lcm-url",
        default=None,
        metavar="URL",
        help="the drivers' LCM URL (default: $LCM_DEFAULT_URL or udpm://239.255.76.67:7667?ttl=0)",
    )
    identify.add_argument(
        "--wait",
        type=seconds(0.01, 3600.0),
        default=None,
        metavar="S",
        help="seconds to wait for the driver's first status (default 5)",
    )
    identify.add_argument(
        "--yes",
        action="store_true",
        help="do not ask before the arm moves (the script is printed)",
    )
    identify.add_argument(
        "--out",
        type=Path,
        default=None,
        help="the folder to write (the recording: identify_log.npz, script.json, "
        "scenario.yaml, written before any fit; then identified.yaml and fit.json; "
        "default doorlab_out/identify)",
    )
    identify.add_argument(
        "--repeats",
        type=bounded_int(1, 10),
        default=None,
        metavar="N",
        help="each joint's breakaways, steps and timed steps per direction (default 2; 1-10)",
    )
    identify.add_argument(
        "--joints",
        type=_joints,
        default=None,
        metavar="LIST",
        help="the joints to identify, e.g. 1,2,7 (default all seven)",
    )
    identify.add_argument(
        "--analyse",
        type=Path,
        default=None,
        metavar="DIR",
        help="fit the recording a run kept in DIR again (no arm, no LCM) and write DIR's "
        "identified.yaml and fit.json; the preset is DIR/scenario.yaml unless --config",
    )
    add_config_options(identify)


def _version() -> str:
    from doorlab import __version__

    return f"doorlab {__version__}"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``doorlab`` console script; returns the exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if args.command is None:
            args = parser.parse_args(["run", *(argv if argv is not None else sys.argv[1:])])
    except SystemExit as e:  # argparse: --help, --version, or a usage error already printed
        return e.code if isinstance(e.code, int) else USAGE_ERROR
    try:
        install_signal_handlers()
        actions = {
            "run": commands.run,
            "report": commands.report,
            "sweep": commands.sweep,
            "bench": bench,
            "pset": commands.pset,
            "sim-driver": commands.sim_driver,
            "identify": commands.identify,
        }
        return actions[args.command](args)
    except DoorlabError as e:
        print(f"doorlab {args.command}: error: {e}", file=sys.stderr)
        return USAGE_ERROR if isinstance(e, (ConfigError, OutputError)) else 1
    except KeyboardInterrupt as e:
        print("doorlab: interrupted", file=sys.stderr)
        return interrupt_exit_code(e)
    except ImportError as e:  # a signal while a C extension initialized ("initialization
        interrupt = _interruption(e)  # failed", caused by the KeyboardInterrupt)
        if interrupt is None:
            name = getattr(e, "name", None) or ""
            if name.startswith("doorlab.") and _students():  # what the handout left out
                from doorlab.pset.handout.edition import left_out

                print(f"doorlab {args.command}: error: {left_out(name)}", file=sys.stderr)
                return USAGE_ERROR
            raise
        print("doorlab: interrupted", file=sys.stderr)
        return interrupt_exit_code(interrupt)


def _students() -> bool:
    """Whether this is the students' doorlab (:mod:`doorlab.pset.handout.edition`)."""
    from doorlab.pset.handout.edition import students

    return students()


def _interruption(error: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt (or Interrupted) that caused ``error``, if one did."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


if __name__ == "__main__":
    sys.exit(main())
