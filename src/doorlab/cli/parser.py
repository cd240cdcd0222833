"""The ``doorlab`` command: ``doorlab run`` (one controller), ``doorlab report`` (all),
``doorlab sweep`` (scenario fields over a grid or random samples), ``doorlab bench`` (the
benchmark card: :mod:`doorlab.cli.bench`) and ``doorlab sim-driver`` (the simulated cell
behind the real drivers' LCM protocol).

Bad input prints one line naming the valid choices and exits with code 2; a run's status
sets the exit code otherwise (see :data:`doorlab.outputs.runs.EXIT_CODES`).

The commands themselves live in :mod:`doorlab.cli.commands`, the argument types in
:mod:`doorlab.runtime.argtypes`.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from doorlab.cli import commands
from doorlab.cli.bench import add_bench_parser, bench
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
        description="Open a cupboard door with a simulated KUKA iiwa 7 four ways "
        "(pointwise IK, Jacobian velocity mapping, Jacobian-transpose impedance, and an "
        "adaptive plan that does not know the hinge).",
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
    _common(run)
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
        "--no-robustness",
        action="store_true",
        help="skip the robustness runs and section (yaw error sweep)",
    )
    report.add_argument(
        "--no-arm",
        action="store_true",
        help="skip the 'On the arm' runs and section (the lab's iiwa: kuka_driver, KUKA's loop)",
    )
    report.add_argument(
        "--no-arm-band",
        action="store_true",
        help="run 'On the arm' on the arm preset only, without the band of plausible arm "
        "models (each plan's verdict then rests on the preset's assumptions)",
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
    _scheduler(sweep)
    sweep.add_argument(
        "--resume", action="store_true", help="keep the runs already in --out's table"
    )
    sweep.add_argument(
        "--force", action="store_true", help="start over in an existing output folder"
    )
    add_bench_parser(sub, _scheduler, _common)
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


def _scheduler(parser: argparse.ArgumentParser) -> None:
    from doorlab.runtime.executor import CONNECT_TIMEOUT_S

    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="tcp://HOST:PORT",
        help="run on this Dask cluster instead of local processes (workers need doorlab)",
    )
    parser.add_argument(
        "--scheduler-timeout",
        type=seconds(0.1, 600.0),
        default=CONNECT_TIMEOUT_S,
        metavar="SECONDS",
        help="how long each step of connecting to --scheduler may take "
        f"(default {CONNECT_TIMEOUT_S:g}; 0.1-600)",
    )


def add_pset_parser(sub) -> None:
    """``doorlab pset {init,grade,grade-all,autograder,handout,assignment}``: the problem-set
    folder, its grader (one submission, or a whole class), the grader as a Gradescope
    autograder zip, the students' handout and the assignment file."""
    pset = sub.add_parser("pset", help="write the problem-set folder for students, or grade one")
    actions = pset.add_subparsers(
        dest="pset_command",
        metavar="{init,grade,grade-all,autograder,handout,assignment}",
        parser_class=OneLineParser,
        required=True,
    )
    init = actions.add_parser("init", help="write the problem-set folder DIR")
    init.add_argument("dir", type=Path, metavar="DIR", help="the folder to write")
    init.add_argument(
        "--solutions", action="store_true", help="write the reference solutions, not the stubs"
    )
    init.add_argument("--force", action="store_true", help="replace an existing DIR")
    grade = actions.add_parser(
        "grade", help="grade a submission (a problem-set folder, its three files, or a zip)"
    )
    grade.add_argument(
        "dir",
        type=Path,
        metavar="SUBMISSION",
        help="a folder (the problem set's, or holding its student files at any depth) or a .zip",
    )
    grade.add_argument(
        "--out",
        type=Path,
        default=None,
        help="results JSON (Gradescope format; default SUBMISSION/test_results.json, or "
        "NAME_results.json beside a NAME.zip)",
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
    _assignment_option(grade)
    grade.add_argument(
        "--seed",
        type=bounded_int(0, 2**63 - 1),
        default=None,
        metavar="N",
        help="the grading seed of a recorded grading (its results' extra_data.seed.grading): "
        "replays its random inputs",
    )
    grade.add_argument(
        "--insecure",
        action="store_true",
        help="grade even where the student's code cannot be isolated (no bubblewrap, no user "
        "namespaces); the results and the summary say so",
    )
    add_grade_all_parser(actions)
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
    _assignment_option(auto)
    auto.add_argument(
        "--force", action="store_true", help="replace an existing OUT.zip written by doorlab"
    )
    hand = actions.add_parser(
        "handout", help="write the students' zip: the problem-set folder and doorlab's wheel"
    )
    hand.add_argument("out", type=Path, metavar="OUT.zip", help="the zip to write")
    _assignment_option(hand, "the README's points and margins")
    hand.add_argument(
        "--force", action="store_true", help="replace an existing OUT.zip written by doorlab"
    )
    hand.add_argument(
        "--reference",
        type=Path,
        default=None,
        metavar="EARLIER.json",
        help="the practice table's reference episodes from an earlier results file (default: "
        "simulated now)",
    )
    assignment = actions.add_parser(
        "assignment", help="write the default assignment file (points, margins, random seed, ...)"
    )
    assignment.add_argument("out", type=Path, metavar="FILE", help="the YAML file to write")


def add_grade_all_parser(actions) -> None:
    """``doorlab pset grade-all SUBMISSIONS --out DIR``: a whole class into a grade sheet."""
    grade_all = actions.add_parser(
        "grade-all",
        help="grade every submission of a class (Gradescope's export, or a folder of folders "
        "and zips) into DIR/grades.csv and DIR/<submission>/results.json",
    )
    grade_all.add_argument(
        "submissions",
        type=Path,
        metavar="SUBMISSIONS",
        help="Gradescope's 'Export Submissions' folder (submission_metadata.yml names the "
        "students), or any folder of submission folders and .zip files",
    )
    grade_all.add_argument(
        "--out",
        type=Path,
        required=True,
        metavar="DIR",
        help="the class's folder: grades.csv, one results.json per submission, feedback/ "
        "(a page per submission), class.html, summary.json, summary.txt, class.json",
    )
    _assignment_option(grade_all)
    grade_all.add_argument(
        "--jobs",
        type=bounded_int(1),
        default=None,
        help="submissions graded at a time, one local worker process each (default: the "
        "number of cores)",
    )
    _scheduler(grade_all)
    grade_all.add_argument(
        "--reference",
        type=Path,
        default=None,
        metavar="RESULTS_JSON",
        help="grade against the reference episodes of an earlier grading's results (default: "
        "simulate them once for the class)",
    )
    grade_all.add_argument(
        "--resume",
        action="store_true",
        help="regrade the class in DIR: grade what changed (new files, failed gradings, new "
        "submissions), re-score from the stored figures what only points, visibility or "
        "margins need, keep the rest; DIR/changes.csv says what changed",
    )
    grade_all.add_argument(
        "--only",
        action="append",
        default=[],
        metavar="ID",
        help="regrade (simulate again) only this submission of the class in DIR, keeping the "
        "others; repeat for more",
    )
    grade_all.add_argument(
        "--export",
        action="append",
        default=[],
        choices=("canvas", "gradescope"),
        help="also write DIR/canvas.csv (Canvas's gradebook import) or DIR/gradescope.csv "
        "(Gradescope's roster columns with the grade): one row per student; repeat for both",
    )
    grade_all.add_argument(
        "--pdf",
        action="store_true",
        help="print each feedback page to DIR/feedback/<submission>.pdf (headless Chromium)",
    )
    grade_all.add_argument(
        "--published",
        action="store_true",
        help="the course has published its grades: feedback pages show the after_published "
        "tests too",
    )
    grade_all.add_argument(
        "--force", action="store_true", help="start over in a DIR that doorlab wrote"
    )
    grade_all.add_argument(
        "--insecure",
        action="store_true",
        help="grade even where the student's code cannot be isolated (every result says so)",
    )


def _assignment_option(
    parser, what: str = "points, margins, visibility, random seed, helpers"
) -> None:
    parser.add_argument(
        "--assignment",
        type=Path,
        default=None,
        metavar="FILE",
        help=f"the course's assignment file ({what}; doorlab pset assignment FILE writes one)",
    )


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
    _common(driver)


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
        default=5.0,
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
        default=Path("doorlab_out") / "identify",
        help="the folder to write (identified.yaml, fit.json, identify_log.npz, script.json; "
        "default doorlab_out/identify)",
    )
    identify.add_argument(
        "--repeats",
        type=bounded_int(1, 10),
        default=2,
        metavar="N",
        help="each joint's breakaways, steps and timed steps per direction (default 2; 1-10)",
    )
    identify.add_argument(
        "--joints",
        type=_joints,
        default=tuple(range(7)),
        metavar="LIST",
        help="the joints to identify, e.g. 1,2,7 (default all seven)",
    )
    _common(identify)


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
