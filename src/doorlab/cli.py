"""The ``doorlab`` command: ``doorlab run`` (one controller), ``doorlab report`` (all),
``doorlab sweep`` (scenario fields over a grid or random samples) and ``doorlab sim-driver``
(the simulated cell behind the real drivers' LCM protocol).

Bad input prints one line naming the valid choices and exits with code 2; a run's status
sets the exit code otherwise (see :data:`doorlab.runs.EXIT_CODES`).
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

from doorlab.config import (
    CONTROLLERS,
    DOOR_STATES,
    Scenario,
    load_scenario,
    update_scenario,
    validate,
)
from doorlab.errors import (
    ConfigError,
    DoorlabError,
    Interrupted,
    OutputError,
    interrupt_exit_code,
)

USAGE_ERROR = 2


class OneLineParser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage block) and exit code 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(USAGE_ERROR, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def bounded_int(low: int, high: int | None = None):
    """An argparse type: an integer in [low, high] (no upper bound if high is None)."""
    valid = f"an integer in [{low}, {high}]" if high is not None else f"an integer >= {low}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {valid}, got {text!r}") from None
        if value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"must be {valid}, got {value}")
        return value

    return parse


def _rate(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number >= 0, got {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a number >= 0, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``doorlab``."""
    parser = OneLineParser(
        prog="doorlab",
        description="Open a cupboard door with a simulated KUKA iiwa 7 four ways "
        "(pointwise IK, Jacobian velocity mapping, Jacobian-transpose impedance, and an "
        "adaptive plan that does not know the hinge).",
    )
    parser.add_argument("--version", action="version", version=_version())
    sub = parser.add_subparsers(
        dest="command", metavar="{run,report,sweep,pset,sim-driver}", parser_class=OneLineParser
    )

    run = sub.add_parser("run", help="run one controller and write its metrics, logs and plots")
    run.add_argument(
        "--controller",
        choices=CONTROLLERS,
        default=None,
        help="which controller (default: velocity, or the config's)",
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
    _common(run)
    run.add_argument(
        "--meshcat",
        action="store_true",
        help="draw the run live in Meshcat (prints the URL; runs in real time)",
    )
    run.add_argument(
        "--realtime",
        type=_rate,
        default=None,
        help="real-time rate (0: as fast as possible; default 0, 1 with --meshcat)",
    )
    run.add_argument("--no-replay", action="store_true", help="skip replay.html (faster)")
    add_hardware_options(run)

    report = sub.add_parser("report", help="run the seed's experiment set and write index.html")
    report.add_argument(
        "--out",
        type=Path,
        default=Path("doorlab_report"),
        help="output folder (default: doorlab_report)",
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
        "--no-robustness",
        action="store_true",
        help="skip the robustness runs and section (yaw error sweep)",
    )
    _scheduler(report)
    _common(report)

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
    _scheduler(sweep)
    sweep.add_argument(
        "--resume", action="store_true", help="keep the runs already in --out's table"
    )
    sweep.add_argument(
        "--force", action="store_true", help="start over in an existing output folder"
    )
    add_pset_parser(sub)
    add_sim_driver_parser(sub)
    return parser


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number of seconds > 0, got {text!r}") from None
    if not (math.isfinite(value) and 0 < value <= 3600):
        raise argparse.ArgumentTypeError(f"must be a number of seconds in (0, 3600], got {text!r}")
    return value


def add_hardware_options(run: argparse.ArgumentParser) -> None:
    """``doorlab run --hardware [--lcm-url URL] [--wait S] [--yes]`` (README, "On the real arm")."""
    group = run.add_argument_group("the real arm (README: On the real arm)")
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
        type=_seconds,
        default=5.0,
        metavar="S",
        help="seconds to wait for the driver's first status (default 5)",
    )
    group.add_argument(
        "--yes", action="store_true", help="do not ask before the arm moves (the plan is printed)"
    )


def _scheduler(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="tcp://HOST:PORT",
        help="run on this Dask cluster instead of local processes (workers need doorlab)",
    )


def add_pset_parser(sub) -> None:
    """``doorlab pset {init,grade}``: the problem-set folder and its grader."""
    pset = sub.add_parser("pset", help="write the problem-set folder for students, or grade one")
    actions = pset.add_subparsers(
        dest="pset_command", metavar="{init,grade}", parser_class=OneLineParser, required=True
    )
    init = actions.add_parser("init", help="write the problem-set folder DIR")
    init.add_argument("dir", type=Path, metavar="DIR", help="the folder to write")
    init.add_argument(
        "--solutions", action="store_true", help="write the reference solutions, not the stubs"
    )
    init.add_argument("--force", action="store_true", help="replace an existing DIR")
    grade = actions.add_parser("grade", help="grade the problem-set folder DIR")
    grade.add_argument("dir", type=Path, metavar="DIR", help="a folder written by pset init")
    grade.add_argument(
        "--out",
        type=Path,
        default=None,
        help="results JSON (Gradescope format; default DIR/test_results.json)",
    )
    grade.add_argument(
        "--jobs", type=bounded_int(1), default=2, help="tests run at a time (default 2)"
    )


def _pset(args: argparse.Namespace) -> int:
    from doorlab.pset.folder import check_problem_set, init_folder

    if args.pset_command == "init":
        out = init_folder(args.dir, solutions=args.solutions, force=args.force)
        kind = "solutions" if args.solutions else "student stubs"
        print(f"doorlab pset: wrote {out} ({kind}); grade it with: doorlab pset grade {out}")
        return 0
    from doorlab.pset.grader import grade, pretty_format_json_results, write_results

    folder = check_problem_set(args.dir)
    out = args.out or folder / "test_results.json"
    if out.parent and not out.parent.is_dir():
        raise OutputError(f"cannot write {out}: {out.parent} is not a folder")
    results = grade(folder, jobs=args.jobs)
    write_results(results, out)
    print(pretty_format_json_results(out))
    print(f"doorlab pset: wrote {out} in {results['execution_time']:.0f} s")
    return 0


def _duration(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number of seconds > 0, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a number of seconds > 0, got {text!r}")
    return value


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
        type=_duration,
        default=None,
        metavar="S",
        help="stop after S seconds (default: run until Ctrl-C or SIGTERM)",
    )
    _common(driver)


def _sim_driver(args: argparse.Namespace) -> int:
    from doorlab.hardware.protocol import resolve_lcm_url
    from doorlab.hardware.serve import serve

    scenario = _scenario(args)
    return serve(
        scenario,
        lcm_url=resolve_lcm_url(args.lcm_url),
        out=args.out,
        force=args.force,
        utime_warmup=args.utime_warmup,
        duration=args.duration if args.duration is not None else math.inf,
    )


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="scenario YAML (see examples/scenario.yaml); options override it",
    )
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override one scenario field, e.g. --set station.time_step=0.001",
    )
    parser.add_argument("--force", action="store_true", help="replace an existing output folder")


def _version() -> str:
    from doorlab import __version__

    return f"doorlab {__version__}"


def _apply_overrides(scenario: Scenario, overrides: Sequence[str]) -> Scenario:
    """Applies ``KEY=VALUE`` overrides (dotted keys, YAML values) to a scenario."""
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep or not key or any(not part.isidentifier() for part in key.split(".")):
            raise ConfigError(f"--set expects KEY=VALUE with a dotted KEY, got {item!r}")
        parts = key.split(".")
        document = value
        for depth, part in enumerate(reversed(parts)):
            indent = "  " * (len(parts) - 1 - depth)
            document = f"{indent}{part}:" + (f" {document}" if depth == 0 else f"\n{document}")
        try:
            scenario = update_scenario(scenario, document)
        except ConfigError as e:
            raise ConfigError(f"--set {item}: {e}") from None
    return scenario


def _scenario(args: argparse.Namespace) -> Scenario:
    scenario = load_scenario(args.config) if args.config is not None else Scenario()
    scenario = _apply_overrides(scenario, args.overrides)
    if getattr(args, "controller", None) is not None:
        scenario.controller = args.controller
    if getattr(args, "doors", None) is not None:
        scenario.doors = args.doors
        scenario.door_angles = None
    if getattr(args, "knots", None) is not None:
        if scenario.controller != "ik":
            raise ConfigError(
                f"--knots applies to --controller ik only (got --controller {scenario.controller})"
            )
        scenario.ik.knots = args.knots
    return validate(scenario)


def _summary(outcome) -> str:
    m = outcome.metrics
    lines = [f"doorlab run: {outcome.out_dir}", f"  status                       {outcome.status}"]
    if m is None:
        lines.append(f"  error                        {outcome.message}")
        return "\n".join(lines)
    knots = f" ({m.knots} knots)" if m.knots else ""
    rows = [
        ("controller / doors", f"{m.controller}{knots} / {m.doors}"),
        (
            "radial error of Q, max / rms",
            f"{1e3 * m.max_radial_error_m:.3f} / {1e3 * m.rms_radial_error_m:.3f} mm (measured q)",
        ),
        ("  max from commanded q_ref", f"{1e3 * m.max_radial_error_cmd_m:.3f} mm"),
        (
            "orientation error of L7, max",
            f"{m.max_orientation_error_rad:.4f} rad "
            f"({math.degrees(m.max_orientation_error_rad):.2f} deg)",
        ),
        (
            "final left hinge angle",
            f"{m.final_door_angle_rad:.4f} rad ({math.degrees(m.final_door_angle_rad):.1f} deg)",
        ),
        (
            "door opened at the arc's end",
            "n/a (open)"
            if m.door_lag_max_rad is None
            else f"{math.degrees(m.door_opening_arc_end_rad):.1f} deg "
            f"({math.degrees(m.door_opening_rad):.1f} at the episode's end)",
        ),
        (
            "largest door lag in the arc",
            "n/a (open)"
            if m.door_lag_max_rad is None
            else f"{math.degrees(m.door_lag_max_rad):.1f} deg behind the plan",
        ),
        ("handle held at the end", {True: "yes", False: "no"}.get(m.handle_held, "n/a (open)")),
        (
            "peak |external torque|",
            f"{m.peak_external_torque_Nm:.2f} N m ({m.peak_external_torque_arc_Nm:.2f} in the arc)",
        ),
        ("peak contact force at Q", f"{m.peak_contact_force_arc_N:.2f} N (in the arc)"),
        ("max joint speed", f"{m.max_joint_speed_rad_s:.3f} rad/s"),
        (
            "simulated / wall time",
            f"{m.sim_time_s:.1f} s / {m.wall_time_s:.2f} s ({m.realtime_factor:.1f}x real time)",
        ),
    ]
    if m.hinge_estimate_error_m is not None:
        rows.append(("final hinge estimate error", f"{1e3 * m.hinge_estimate_error_m:.2f} mm"))
    lines += [f"  {name:<29}{value}" for name, value in rows]
    if outcome.message:
        lines.append(f"  note                         {outcome.message}")
    files = sorted(p.name for p in outcome.out_dir.iterdir())
    pngs = [f for f in files if f.endswith(".png")]
    others = [f for f in files if not f.endswith(".png")]
    lines.append(
        f"  files: {', '.join(others)}" + (f" and {len(pngs)} plots (*.png)" if pngs else "")
    )
    return "\n".join(lines)


def _run(args: argparse.Namespace) -> int:
    from doorlab.runs import run_to_folder

    if args.hardware:
        from doorlab.hardware.cli import run_hardware_command

        return run_hardware_command(args, _scenario(args))
    for option, given in (("--lcm-url", args.lcm_url), ("--yes", args.yes)):
        if given:
            raise ConfigError(f"{option} applies to --hardware only")
    scenario = _scenario(args)
    out = args.out or Path("doorlab_out") / f"{scenario.controller}_{scenario.doors}"
    meshcat = None
    if args.meshcat:
        from pydrake.geometry import Meshcat

        meshcat = Meshcat()
        print(f"Meshcat: {meshcat.web_url()}", flush=True)
    outcome = run_to_folder(
        scenario,
        out,
        force=args.force,
        replay=not args.no_replay,
        meshcat=meshcat,
        realtime_rate=args.realtime if args.realtime is not None else (1.0 if meshcat else 0.0),
        parallel=True,
    )
    print(_summary(outcome))
    if meshcat is not None and sys.stdin.isatty():
        # The live view (with the recording to replay) lives as long as this process.
        input(f"Meshcat is still serving {meshcat.web_url()}; press Enter to quit. ")
    return outcome.exit_code


def _report(args: argparse.Namespace) -> int:
    from doorlab.report import run_report

    base = _scenario(args)
    jobs = args.jobs or os.cpu_count() or 1
    chromium = None
    if args.pdf:
        from doorlab.pdf import find_chromium

        chromium = find_chromium()  # before any run: a missing browser is a one-line error
    code = run_report(
        args.out,
        jobs=jobs,
        force=args.force,
        base=base,
        scheduler=args.scheduler,
        robustness=not args.no_robustness,
    )
    if args.pdf:
        from doorlab.pdf import print_pdf

        pdf = print_pdf(args.out / "index.html", args.out / "report.pdf", chromium=chromium)
        print(f"doorlab report: wrote {pdf}")
    return code


def _sweep(args: argparse.Namespace) -> int:
    from doorlab.sweep import load_spec, run_sweep
    from doorlab.sweep.results import RESULTS_PARQUET

    if args.spec is None and not args.grid:
        raise ConfigError("give a SPEC file or at least one --grid KEY=V1,V2,...")
    if args.resume and args.force:
        raise ConfigError("--resume and --force exclude each other")
    spec = load_spec(args.spec, grid=args.grid)
    jobs = args.jobs or os.cpu_count() or 1
    try:
        frame = run_sweep(
            spec,
            args.out,
            jobs=jobs,
            scheduler=args.scheduler,
            resume=args.resume,
            force=args.force,
            progress=True,
        )
    except KeyboardInterrupt:
        from doorlab.sweep import read_table

        table = read_table(args.out)
        done = 0 if table is None else len(table)
        print(
            f"doorlab sweep: interrupted; {done} finished runs are in "
            f"{args.out / RESULTS_PARQUET} (--resume continues)",
            file=sys.stderr,
        )
        return 130
    counts = frame["status"].value_counts()
    statuses = ", ".join(f"{n} {status}" for status, n in counts.items())
    print(f"doorlab sweep: {len(frame)} runs ({statuses}) in {args.out}")
    print(
        f"  table: {args.out / RESULTS_PARQUET} (and results.csv); page: {args.out / 'index.html'}"
    )
    # Failed runs are results of a sweep (the table has them); an exception in a run is not.
    return 1 if (frame["status"] == "error").any() else 0


def _raise_interrupted(signum: int, frame) -> None:
    raise Interrupted(signum)


def install_signal_handlers() -> None:
    """SIGTERM and SIGHUP raise :class:`doorlab.errors.Interrupted` (a KeyboardInterrupt), so
    they leave through the same clean-up as Ctrl-C (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        return
    for signum in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, _raise_interrupted)


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
        commands = {
            "run": _run,
            "report": _report,
            "sweep": _sweep,
            "pset": _pset,
            "sim-driver": _sim_driver,
        }
        return commands[args.command](args)
    except DoorlabError as e:
        print(f"doorlab {args.command}: error: {e}", file=sys.stderr)
        return USAGE_ERROR if isinstance(e, (ConfigError, OutputError)) else 1
    except KeyboardInterrupt as e:
        print("doorlab: interrupted", file=sys.stderr)
        return interrupt_exit_code(e)


if __name__ == "__main__":
    sys.exit(main())
