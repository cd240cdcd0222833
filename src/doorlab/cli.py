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
import re
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
from doorlab.inputs import QUOTE_CHARS, quote_text

USAGE_ERROR = 2


class OneLineParser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage block), values quoted short, exit code 2."""

    def error(self, message: str) -> NoReturn:
        message = " ".join(_LONG_QUOTE.sub(_shorten, message).split())
        self.exit(USAGE_ERROR, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


_LONG_QUOTE = re.compile("'([^']{" + str(QUOTE_CHARS + 1) + ",})'")


def _shorten(match: re.Match) -> str:
    return quote_text(match.group(1))


def bounded_int(low: int, high: int | None = None):
    """An argparse type: an integer in [low, high] (no upper bound if high is None)."""
    valid = f"an integer in [{low}, {high}]" if high is not None else f"an integer >= {low}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {valid}, got {quote_text(text)}") from None
        if value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"must be {valid}, got {value}")
        return value

    return parse


MIN_REALTIME_RATE = 0.01
"""Slowest ``--realtime`` rate: 1/100 of real time already stretches the default episode to
40 minutes; a slower one would outlast anyone watching it (0 still means as fast as possible)."""


def _rate(text: str) -> float:
    valid = f"0 (as fast as possible) or a number >= {MIN_REALTIME_RATE}"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be {valid}, got {quote_text(text)}") from None
    if not (math.isfinite(value) and (value == 0 or value >= MIN_REALTIME_RATE)):
        why = " (slower would take over 40 min)" if 0 < value < MIN_REALTIME_RATE else ""
        raise argparse.ArgumentTypeError(f"must be {valid}{why}, got {quote_text(text)}")
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
        type=_seconds(0.01, 3600.0),
        default=5.0,
        metavar="S",
        help="seconds to wait for the driver's first status (default 5)",
    )
    group.add_argument(
        "--yes", action="store_true", help="do not ask before the arm moves (the plan is printed)"
    )


def _scheduler(parser: argparse.ArgumentParser) -> None:
    from doorlab.executor import CONNECT_TIMEOUT_S

    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="tcp://HOST:PORT",
        help="run on this Dask cluster instead of local processes (workers need doorlab)",
    )
    parser.add_argument(
        "--scheduler-timeout",
        type=_seconds(0.1, 600.0),
        default=CONNECT_TIMEOUT_S,
        metavar="SECONDS",
        help="how long each step of connecting to --scheduler may take "
        f"(default {CONNECT_TIMEOUT_S:g}; 0.1-600)",
    )


def _seconds(low: float, high: float):
    """An argparse type: a duration in [low, high] seconds."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(
                f"must be a number of seconds in [{low:g}, {high:g}], got {quote_text(text)}"
            )
        return value

    return parse


def add_pset_parser(sub) -> None:
    """``doorlab pset {init,grade,autograder}``: the problem-set folder, its grader and the
    grader as a Gradescope autograder zip."""
    pset = sub.add_parser("pset", help="write the problem-set folder for students, or grade one")
    actions = pset.add_subparsers(
        dest="pset_command",
        metavar="{init,grade,autograder}",
        parser_class=OneLineParser,
        required=True,
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
    grade.add_argument(
        "--reference",
        type=Path,
        default=None,
        metavar="RESULTS_JSON",
        help="reuse the reference episodes of an earlier grading's results (saves 3 episodes)",
    )
    auto = actions.add_parser(
        "autograder", help="write a Gradescope autograder zip that grades with this doorlab"
    )
    auto.add_argument("out", type=Path, metavar="OUT.zip", help="the zip to write")
    auto.add_argument(
        "--jobs",
        type=bounded_int(1),
        default=1,
        help="tests run at a time on Gradescope (default 1; 2 with 2 CPUs and 1.5 GB)",
    )
    auto.add_argument(
        "--force", action="store_true", help="replace an existing OUT.zip written by doorlab"
    )


def _pset(args: argparse.Namespace) -> int:
    from doorlab.pset.folder import check_problem_set, init_folder

    if args.pset_command == "init":
        out = init_folder(args.dir, solutions=args.solutions, force=args.force)
        kind = "solutions" if args.solutions else "student stubs"
        print(f"doorlab pset: wrote {out} ({kind}); grade it with: doorlab pset grade {out}")
        return 0
    if args.pset_command == "autograder":
        from doorlab.pset.autograder import write_autograder

        out = write_autograder(args.out, jobs=args.jobs, force=args.force)
        print(
            f"doorlab pset: wrote {out} ({out.stat().st_size / 1e3:.0f} kB); upload it as the "
            "assignment's autograder on Gradescope (base image Ubuntu 22.04 or newer)"
        )
        return 0
    from doorlab.pset import grader
    from doorlab.runs import record_written

    folder = check_problem_set(args.dir)
    out = args.out or folder / "test_results.json"
    _check_writable(out)  # before grading: the grading takes minutes
    reference = None if args.reference is None else grader.load_reference(args.reference)
    results = grader.grade(folder, jobs=args.jobs, reference=reference)
    grader.write_results(results, out)
    record_written(folder, [out])  # doorlab's (pset init --force may replace it)
    print(grader.pretty_format_json_results(out))
    print(f"doorlab pset: wrote {out} in {results['execution_time']:.0f} s")
    return 0


def _check_writable(out: Path) -> None:
    """Raises OutputError unless the file ``out`` can be written: its folder exists and takes
    a new file (tried, for the real answer on any file system and for any user)."""
    import tempfile

    folder = out.parent
    if out.is_dir():
        raise OutputError(f"cannot write {out}: it is a folder")
    if not folder.is_dir():
        raise OutputError(f"cannot write {out}: {folder} is not a folder")
    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=f".{out.name}.", suffix=".probe"):
            pass
        if out.exists():
            with open(out, "ab"):
                pass
    except OSError as e:
        raise OutputError(f"cannot write {out}: {e.strerror or e}") from None


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
        type=_seconds(0.01, 7 * 86400.0),
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
    """Applies ``KEY=VALUE`` overrides (dotted keys, one YAML value each) to a scenario.

    A VALUE is one YAML scalar or flow value on one line (``0.001``, ``[1, 2]``, ``{kind:
    stiffness}``), so it can change only its KEY.
    """
    import yaml

    from doorlab.inputs import load_yaml_value, quote_text

    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep or not key or any(not part.isidentifier() for part in key.split(".")):
            raise ConfigError(f"--set expects KEY=VALUE with a dotted KEY, got {quote_text(item)}")
        shown = quote_text(item)
        try:
            data: object = load_yaml_value(value)
        except ConfigError as e:
            raise ConfigError(f"--set {shown}: {e}") from None
        for part in reversed(key.split(".")):
            data = {part: data}
        try:
            scenario = update_scenario(scenario, yaml.safe_dump(data))
        except ConfigError as e:
            raise ConfigError(f"--set {shown}: {e}") from None
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
    files = sorted(p.name for p in outcome.out_dir.iterdir() if not p.name.startswith("."))
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


def _probe(args: argparse.Namespace) -> None:
    """A --scheduler is checked and asked who it is before anything else is imported or
    built: an address that is no Dask scheduler is one line within --scheduler-timeout."""
    if args.scheduler is not None:
        from doorlab.executor import check_scheduler, probe_scheduler

        probe_scheduler(check_scheduler(args.scheduler), args.scheduler_timeout)


def _report(args: argparse.Namespace) -> int:
    base = _scenario(args)
    _probe(args)
    from doorlab.report import run_report

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
        scheduler_timeout_s=args.scheduler_timeout,
        robustness=not args.no_robustness,
    )
    if args.pdf:
        from doorlab.pdf import print_pdf
        from doorlab.runs import record_written

        pdf = print_pdf(args.out / "index.html", args.out / "report.pdf", chromium=chromium)
        record_written(args.out, [pdf])  # doorlab's, so a later --force may replace it
        print(f"doorlab report: wrote {pdf}")
    return code


def _sweep(args: argparse.Namespace) -> int:
    from doorlab.sweep import load_spec

    if args.spec is None and not args.grid:
        raise ConfigError("give a SPEC file or at least one --grid KEY=V1,V2,...")
    if args.resume and args.force:
        raise ConfigError("--resume and --force exclude each other")
    spec = load_spec(args.spec, grid=args.grid)  # before pandas is imported: refusals stay small
    jobs = args.jobs or os.cpu_count() or 1
    try:
        _probe(args)
        from doorlab.sweep import run_sweep

        frame = run_sweep(
            spec,
            args.out,
            jobs=jobs,
            scheduler=args.scheduler,
            scheduler_timeout_s=args.scheduler_timeout,
            resume=args.resume,
            force=args.force,
            progress=True,
        )
    except KeyboardInterrupt as e:
        print(f"doorlab sweep: interrupted; {_sweep_left(args.out)}", file=sys.stderr)
        return interrupt_exit_code(e)
    from doorlab.sweep.results import RESULTS_PARQUET

    counts = frame["status"].value_counts()
    statuses = ", ".join(f"{n} {status}" for status, n in counts.items())
    print(f"doorlab sweep: {len(frame)} runs ({statuses}) in {args.out}")
    print(
        f"  table: {args.out / RESULTS_PARQUET} (and results.csv); page: {args.out / 'index.html'}"
    )
    # Failed runs are results of a sweep (the table has them); an exception in a run is not.
    return 1 if (frame["status"] == "error").any() else 0


def _sweep_left(out: Path) -> str:
    """What an interrupted sweep left in ``out``: only what is there."""
    if not out.is_dir():
        return "no run had finished; nothing was written"
    from doorlab.sweep import read_table
    from doorlab.sweep.results import RESULTS_PARQUET

    try:
        table = read_table(out)
    except (OSError, ValueError):
        table = None
    if table is None:
        return "no run had finished; nothing was written"
    if len(table) == 0:
        return f"no run had finished; {out / RESULTS_PARQUET} holds an empty table"
    return f"{len(table)} finished runs are in {out / RESULTS_PARQUET} (--resume continues)"


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
    except ImportError as e:  # a signal while a C extension initialized ("initialization
        interrupt = _interruption(e)  # failed", caused by the KeyboardInterrupt)
        if interrupt is None:
            raise
        print("doorlab: interrupted", file=sys.stderr)
        return interrupt_exit_code(interrupt)


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
