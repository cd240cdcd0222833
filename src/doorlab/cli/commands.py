"""What each ``doorlab`` command does once its arguments are parsed (:mod:`doorlab.cli` builds
the parser and turns errors into one line and an exit code): ``run``, ``report``, ``sweep``,
``pset`` and ``sim-driver``, and the scenario every command starts from (``--config``,
``--set``, the options).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from doorlab.config import (
    Scenario,
    load_scenario,
    update_scenario,
    validate,
)
from doorlab.errors import (
    ConfigError,
    OutputError,
    interrupt_exit_code,
)
from doorlab.runtime.inputs import quote_text


def pset(args: argparse.Namespace) -> int:
    """``doorlab pset {init,grade,grade-all,feedback,autograder,handout,assignment}``; returns
    the exit code."""
    from doorlab.pset.handout.folder import init_folder

    if args.pset_command == "init":
        out = init_folder(args.dir, solutions=args.solutions, force=args.force)
        kind = "solutions" if args.solutions else "student stubs"
        print(f"doorlab pset: wrote {out} ({kind}); grade it with: doorlab pset grade {out}")
        return 0
    if args.pset_command == "assignment":
        from doorlab.pset.rules.assignment import write_default_assignment

        out = write_default_assignment(args.out)
        print(
            f"doorlab pset: wrote {out} (the defaults, a fresh random seed); grade with it: "
            f"doorlab pset grade SUBMISSION --assignment {out}"
        )
        return 0
    if args.pset_command == "feedback":
        from doorlab.pset.classroom.handout_feedback import hand_out

        for line in hand_out(args.class_dir, args.out, pdf=args.pdf, force=args.force):
            print(f"doorlab pset feedback: {line}")
        return 0
    if args.pset_command == "cluster-keys":
        from doorlab.pset.classroom.cluster import write_cluster_keys

        hosts = args.host or ["localhost", "127.0.0.1"]
        out = write_cluster_keys(args.out, hosts, force=args.force)
        print(
            f"doorlab pset: wrote {out}: ca.pem (every role's --tls-ca-file), ca.key (keep it "
            "offline), scheduler, worker and client certificates and keys (mode 0600), for "
            f"{', '.join(hosts)}; grade with --scheduler tls://HOST:PORT --cluster-keys {out}"
        )
        return 0
    assignment = _assignment(args.assignment)
    if args.pset_command == "grade-all":
        return _pset_grade_all(args, assignment)
    if args.pset_command == "autograder":
        from doorlab.pset.classroom.gradescope import write_autograder

        out = write_autograder(args.out, jobs=args.jobs, force=args.force, assignment=assignment)
        print(
            f"doorlab pset: wrote {out} ({out.stat().st_size / 1e3:.0f} kB); upload it as the "
            "assignment's autograder on Gradescope (base image: see docs/guides/teaching.md)"
        )
        return 0
    if args.pset_command == "handout":
        from doorlab.pset.classroom.handout_zip import write_handout
        from doorlab.pset.grading.grader import load_reference

        reference = None if args.reference is None else load_reference(args.reference)
        out = write_handout(args.out, force=args.force, assignment=assignment, reference=reference)
        print(
            f"doorlab pset: wrote {out} ({out.stat().st_size / 1e3:.0f} kB): the student "
            "folder and doorlab's wheel; its README says how to install and submit"
        )
        return 0
    return _pset_grade(args, assignment)


def _assignment(path: Path | None):
    if path is None:
        return None
    from doorlab.pset.rules.assignment import load_assignment

    return load_assignment(path)


def _pset_grade(args: argparse.Namespace, assignment) -> int:
    """``doorlab pset grade SUBMISSION``: the one intake, the grader, the results file."""
    from doorlab.pset.grading import grader
    from doorlab.runtime.folders import record_written

    source = Path(args.dir)
    if not source.exists():
        raise OutputError(f"{source} does not exist; grade a folder or a .zip")
    if source.is_dir():
        out = args.out or source / "test_results.json"
    elif source.is_file():  # a zip, or one flat file (taken if it is a student file)
        out = args.out or source.with_name(f"{source.stem}_results.json")
    else:
        raise OutputError(
            f"{source} is not a folder or a file: grade the submission's folder (the problem "
            "set's, or one holding its files), its zip or one of its files"
        )
    _check_writable(out)  # before grading: the grading takes minutes
    from doorlab.pset.isolation.memory import plan

    memory = plan(views=args.jobs, gradings=1)  # one line where the views cannot fit
    reference = None if args.reference is None else grader.load_reference(args.reference)
    results = grader.grade_submission(
        source,
        jobs=args.jobs,
        reference=reference,
        assignment=assignment,
        seed=args.seed,
        require_files=True,
        isolation="insecure" if args.insecure else "require",
        view_memory_bytes=memory.view_bytes,
    )
    grader.write_results(results, out)
    if source.is_dir():
        record_written(source, [out])  # doorlab's (pset init --force may replace it)
    print(grader.pretty_format_json_results(out))
    print(f"doorlab pset: wrote {out} in {results['execution_time']:.0f} s")
    return 0


def _pset_grade_all(args: argparse.Namespace, assignment) -> int:
    """``doorlab pset grade-all SUBMISSIONS --out DIR``: the class graded, its sheet."""
    from doorlab.pset.classroom.grade_all import GRADES_CSV, grade_class
    from doorlab.pset.grading import grader

    if args.resume and args.force:
        raise ConfigError("--resume and --force exclude each other")
    if args.only and args.force:
        raise ConfigError("--only and --force exclude each other (--only keeps the others)")
    from doorlab.pset.classroom.class_outputs import Outputs

    outputs = Outputs(
        exports=tuple(dict.fromkeys(args.export)),
        pdf=args.pdf,
        published=args.published,
        only=tuple(args.only),
    )
    if args.pdf:
        from doorlab.runtime.pdf import find_chromium

        find_chromium()  # before grading: the message names the package
    reference = None if args.reference is None else grader.load_reference(args.reference)
    security = None
    if args.cluster_keys is not None:
        from doorlab.pset.classroom.cluster import cluster_security

        security = cluster_security(args.cluster_keys)
    if args.scheduler is not None:
        require_sweep_extra("--scheduler", ("distributed",))  # what is missing first
        from doorlab.pset.classroom.cluster import plain, refuse
        from doorlab.runtime.executor import check_scheduler

        why = plain(check_scheduler(args.scheduler))
        if why is not None and not args.insecure_cluster:  # before connecting to it
            raise refuse(args.scheduler, why)
        _probe(args, security)
    has_canvas = "canvas" in args.export or (Path(args.out) / "canvas.csv").is_file()
    if args.roster is not None and not has_canvas:
        raise ConfigError("--roster fills the Canvas export: give it with --export canvas")
    jobs = args.jobs or os.cpu_count() or 1
    try:
        outcome = grade_class(
            args.submissions,
            args.out,
            assignment=assignment,
            jobs=jobs,
            scheduler=args.scheduler,
            scheduler_timeout_s=args.scheduler_timeout,
            resume=args.resume,
            force=args.force,
            reference=reference,
            isolation="insecure" if args.insecure else "require",
            progress=True,
            only=args.only,
            outputs=outputs,
            roster=args.roster,
            notice=lambda line: print(f"doorlab pset grade-all: {line}", file=sys.stderr),
            security=security,
            insecure_cluster=args.insecure_cluster,
        )
    except KeyboardInterrupt as e:
        left = getattr(e, "doorlab_left", None) or _class_left(args.out)
        print(f"doorlab pset grade-all: interrupted; {left}", file=sys.stderr)
        return interrupt_exit_code(e)
    for line in outcome.summary:
        print(f"  {line}")
    kept = f" ({len(outcome.kept)} kept from {args.out})" if outcome.kept else ""
    if outcome.rescored:
        kept += f" ({len(outcome.rescored)} re-scored from their stored figures)"
    count = len(outcome.graded)
    print(
        f"doorlab pset grade-all: graded {count} submission{'' if count == 1 else 's'}{kept} on "
        f"{outcome.executor}; sheet: {args.out / GRADES_CSV}; results: "
        f"{args.out}/<submission>/results.json"
    )
    return 1 if outcome.errors or outcome.problems else 0


def _class_left(out: Path) -> str:
    """What an interrupted grade-all left in ``out``: only what is there."""
    from doorlab.pset.classroom.grade_all import GRADES_CSV

    try:
        lines = (out / GRADES_CSV).read_text().splitlines()
    except OSError:
        return "no submission had finished; nothing was written"
    return (
        f"{max(0, len(lines) - 1)} finished submissions are in {out / GRADES_CSV} "
        "(--resume grades the rest)"
    )


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


def sim_driver(args: argparse.Namespace) -> int:
    """``doorlab sim-driver``: serves the simulated cell until stopped; returns the exit code."""
    from doorlab.hardware.protocol import resolve_lcm_url
    from doorlab.hardware.serve import serve

    scenario = scenario_from_args(args)
    return serve(
        scenario,
        lcm_url=resolve_lcm_url(args.lcm_url),
        out=args.out,
        force=args.force,
        utime_warmup=args.utime_warmup,
        duration=args.duration if args.duration is not None else math.inf,
    )


def identify(args: argparse.Namespace) -> int:
    """``doorlab identify``: the calibration on the arm over LCM; returns the exit code."""
    from doorlab.config import arm_preset
    from doorlab.hardware.cli import run_identify_command

    config = args.config
    if config is None and args.analyse is not None:
        from doorlab.hardware.identify.run import SCENARIO_FILE

        recorded = Path(args.analyse) / SCENARIO_FILE  # the preset the run used
        config = recorded if recorded.is_file() else None
    base = load_scenario(config) if config is not None else arm_preset()
    scenario = validate(apply_overrides(base, args.overrides))
    return run_identify_command(args, scenario)


def apply_overrides(scenario: Scenario, overrides: Sequence[str]) -> Scenario:
    """Applies ``KEY=VALUE`` overrides (dotted keys, one YAML value each) to a scenario.

    A VALUE is one YAML scalar or flow value on one line (``0.001``, ``[1, 2]``, ``{kind:
    stiffness}``), so it can change only its KEY.
    """
    import yaml

    from doorlab.runtime.inputs import load_yaml_value

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


def controller_option(text: str) -> str:
    """A ``--controller`` value checked (its form, not its code) and with a plug-in file's
    relative path made absolute against the working directory.

    Raises:
        ConfigError: Not a built-in, an installed plug-in's name or a plug-in's form.
    """
    from doorlab.config import CONTROLLERS
    from doorlab.config_checks import absolute_controller, controller_spec

    try:
        controller_spec(text, CONTROLLERS)
    except ConfigError as e:
        raise ConfigError(f"--controller {quote_text(text)}: {e}") from None
    return absolute_controller(text, Path.cwd())


def load_controller(name: str) -> str:
    """Loads the controller ``name`` names (a plug-in: imported and checked, in this process,
    before anything runs or is written); returns what tables and folders call it.

    Raises:
        ConfigError, PluginError: Unknown, or a plug-in that cannot be used (one line).
    """
    from doorlab.episode.controllers import controller_name

    return controller_name(name)


def scenario_from_args(args: argparse.Namespace) -> Scenario:
    """The scenario a command runs: ``--config`` (or the defaults), then ``--set``, then the
    options (``--controller``, ``--doors``, ``--knots``), validated. A plug-in file's relative
    path is the working directory's (the config file's: its folder's)."""
    from doorlab.config_checks import absolute_controller

    scenario = load_scenario(args.config) if args.config is not None else Scenario()
    scenario = apply_overrides(scenario, args.overrides)
    scenario.controller = absolute_controller(scenario.controller, Path.cwd())
    controller = getattr(args, "controller", None)
    if isinstance(controller, str):
        scenario.controller = controller_option(controller)
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


def run(args: argparse.Namespace) -> int:
    """``doorlab run`` (``--hardware``: on the real cell); returns the exit code."""
    from doorlab.outputs.runs import run_to_folder

    if args.hardware:
        from doorlab.hardware.cli import run_hardware_command

        scenario = scenario_from_args(args)
        load_controller(scenario.controller)  # a plug-in: before the driver is waited for
        return run_hardware_command(args, scenario)
    for option, given in (("--lcm-url", args.lcm_url), ("--yes", args.yes)):
        if given:
            raise ConfigError(f"{option} applies to --hardware only")
    scenario = scenario_from_args(args)
    name = load_controller(scenario.controller)  # a plug-in: before anything is written
    out = args.out or Path("doorlab_out") / f"{name}_{scenario.doors}"
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
    if outcome.status == "controller_error":  # a broken plug-in: its one line, exit 2
        print(f"doorlab run: error: {outcome.message}", file=sys.stderr)
    if meshcat is not None and sys.stdin.isatty():
        # The live view (with the recording to replay) lives as long as this process.
        input(f"Meshcat is still serving {meshcat.web_url()}; press Enter to quit. ")
    return outcome.exit_code


def require_sweep_extra(what: str, modules: tuple[str, ...]) -> None:
    """Raises ConfigError (one line, the install command) if a module of doorlab's ``sweep``
    extra that ``what`` needs is not installed (doorlab itself installs without them)."""
    import importlib

    missing = []
    for module in modules:  # imported now: the command imports them next anyway
        try:
            importlib.import_module(module)
        except ImportError:
            missing.append(module)
    if missing:
        raise ConfigError(
            f"{what} needs {' and '.join(missing)}, of doorlab's sweep extra: "
            'pip install "doorlab[sweep]" (in a clone: pip install -e ".[sweep]")'
        )


def _probe(args: argparse.Namespace, security=None) -> None:
    """A --scheduler is checked and asked who it is before anything else is imported or
    built: an address that is no Dask scheduler is one line within --scheduler-timeout.
    ``security``: a ``distributed.Security`` (default: Dask's configuration's)."""
    if args.scheduler is not None:
        require_sweep_extra("--scheduler", ("distributed",))
        from doorlab.runtime.executor import check_scheduler, probe_scheduler

        probe_scheduler(check_scheduler(args.scheduler), args.scheduler_timeout, security)


def report(args: argparse.Namespace) -> int:
    """``doorlab report``; returns the exit code."""
    if args.no_arm_band and not args.arm:
        raise ConfigError(
            "--no-arm-band applies to the 'On the arm' section: add --arm (the report runs "
            "it only when asked)"
        )
    base = scenario_from_args(args)
    from doorlab.config import CONTROLLERS

    chosen = list(CONTROLLERS)
    for text in args.controller:
        spec = controller_option(text)
        load_controller(spec)  # a plug-in: imported and checked before anything runs
        if spec not in chosen:
            chosen.append(spec)
    _check_names(chosen)
    _probe(args)
    from doorlab.report import run_report

    jobs = args.jobs or os.cpu_count() or 1
    chromium = None
    if args.pdf:
        from doorlab.runtime.pdf import find_chromium

        chromium = find_chromium()  # before any run: a missing browser is a one-line error
    code = run_report(
        args.out,
        jobs=jobs,
        force=args.force,
        base=base,
        scheduler=args.scheduler,
        scheduler_timeout_s=args.scheduler_timeout,
        robustness=args.robustness,
        arm=args.arm,
        arm_band=not args.no_arm_band,
        controllers=chosen,
    )
    if args.pdf:
        from doorlab.runtime.folders import record_written
        from doorlab.runtime.pdf import print_pdf

        pdf = print_pdf(args.out / "index.html", args.out / "report.pdf", chromium=chromium)
        record_written(args.out, [pdf])  # doorlab's, so a later --force may replace it
        print(f"doorlab report: wrote {pdf}")
    broken = _broken_plugin_run(args.out)
    if broken is not None:  # a plug-in that raised in a tick: its one line, exit 2
        print(f"doorlab report: error: {broken}", file=sys.stderr)
        return 2
    return code


def _broken_plugin_run(out: Path) -> str | None:
    """The first of a report's runs that ended ``controller_error`` (its name and error), or
    None."""
    import json

    try:
        runs = json.loads((out / "summary.json").read_text())["runs"]
    except (OSError, ValueError, KeyError):
        return None
    for run in runs:
        if run.get("status") == "controller_error":
            return f"run {run.get('name')} ended controller_error: {run.get('error', '')}"
    return None


def _check_names(controllers: Sequence[str]) -> None:
    """Refuses two controllers of the same name (folders and tables are named after them)."""
    from doorlab.episode.plugins import display_name

    seen: dict[str, str] = {}
    for spec in controllers:
        name = display_name(spec)
        if name in seen and seen[name] != spec:
            raise ConfigError(
                f"--controller {quote_text(spec)} and {quote_text(seen[name])} are both named "
                f"{name!r}; folders and tables tell controllers apart by name"
            )
        seen[name] = spec


def sweep(args: argparse.Namespace) -> int:
    """``doorlab sweep``; returns the exit code."""
    from doorlab.sweep import load_spec

    if args.spec is None and not args.grid:
        raise ConfigError("give a SPEC file or at least one --grid KEY=V1,V2,...")
    if args.resume and args.force:
        raise ConfigError("--resume and --force exclude each other")
    controllers = [controller_option(c) for c in args.controller]
    # before pandas is imported: refusals stay small
    spec = load_spec(args.spec, grid=args.grid, controllers=controllers)
    require_sweep_extra("doorlab sweep", ("pandas", "pyarrow"))
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
    broken = frame[frame["status"] == "controller_error"]
    if len(broken):  # a plug-in that raised in a tick: its first line, exit 2
        first = broken.iloc[0]
        print(
            f"doorlab sweep: error: {len(broken)} runs of {first['controller']} ended "
            f"controller_error; the first: {first['error']}",
            file=sys.stderr,
        )
        return 2
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
