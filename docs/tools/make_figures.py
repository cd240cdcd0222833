"""Makes the site's figures and measured texts from real runs: ``python docs/tools/make_figures.py
[TARGET ...]``.

Each target runs one doorlab command (or benchmark) into a temporary folder, times it, and
copies what the pages show into ``docs/figures/TARGET/``: its figures, the texts it keeps (a
part of what the command printed, a table made from its output files) and ``time.md``, how
long the command took on this machine. Then it writes every page's measured regions from them
(``<!-- measured: TARGET/NAME -->`` ... ``<!-- /measured -->``; docs/tools/doorlab_reference/
measured.py), so that a page quotes a run only as the run wrote it. Without arguments every
target is made; ``--pages`` only writes the pages again from docs/figures.

``--keep DIR`` runs into DIR and keeps the outputs there; a target already run there is
not run again, only its figures and texts made again (to change what a page shows).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[2]
FIGURES = ROOT / "docs" / "figures"


@dataclass(frozen=True)
class Target:
    """One command and what is taken from its output folder."""

    command: str  # run from the repository's root; {out} is the output folder
    figures: dict[str, tuple[str, str]]  # name -> (file in {out}, caption)
    text: dict[str, Callable[[str], str]] | None = None  # name -> what to keep of its stdout
    tables: dict[str, Callable[[Path], str]] | None = None  # name -> Markdown from {out}
    timed: bool = True  # write time.md (False: the command only prints what a run recorded)
    host_reference: bool = False  # time.md also gives the main job's CPU, measured just before


def _rows(out: Path) -> list[dict[str, str]]:
    with open(out / "results.csv", newline="") as f:
        return list(csv.DictReader(f))


def _pytest_summary(stdout: str) -> str:
    """pytest's last line (``862 passed in 352.10s (0:05:52)``), how many workers ran and
    the CPU the run used (tests/run_cost.py)."""
    lines = [line.strip("= ") for line in stdout.splitlines() if line.strip()]
    workers = next((line for line in lines if line.startswith("created:")), "")
    cpu = next((line for line in lines if line.startswith("CPU: ")), "")
    return "\n".join(x for x in (workers, cpu, lines[-1]) if x) + "\n"


def _deg(value: str) -> float:
    return abs(math.degrees(float(value)))


def _cell(row: dict[str, str]) -> str:
    """Door opened at the arc's end [deg] / peak |external torque| in the arc [N m]."""
    slipped = "*" if row.get("handle_held") == "False" else ""
    door = _deg(row["door_opening_arc_end_rad"])
    return f"{door:.1f}{slipped} / {float(row['peak_external_torque_arc_Nm']):.2f}"


def impedance_table(out: Path) -> str:
    """The impedance sweep: dq_scale down, Kv across, door / torque in each cell."""
    rows = _rows(out)
    kvs = sorted({float(r["impedance.kv"]) for r in rows})
    scales = sorted({float(r["station.inner_loop.dq_scale"]) for r in rows})
    cell = {
        (float(r["station.inner_loop.dq_scale"]), float(r["impedance.kv"])): _cell(r) for r in rows
    }
    lines = ["| dq_scale \\ Kv [N/m] | " + " | ".join(f"{k:g}" for k in kvs) + " |"]
    lines.append("|---" * (len(kvs) + 1) + "|")
    for scale in scales:
        lines.append(f"| {scale:g} | " + " | ".join(cell[(scale, k)] for k in kvs) + " |")
    return "\n".join(lines) + "\n"


def yaw_error_table(out: Path) -> str:
    """The hinge-error sweep: per controller a row of doors (* slipped) and one of torques."""
    rows = _rows(out)
    yaws = sorted({float(r["station.cupboard_yaw_error"]) for r in rows})
    controllers = list(dict.fromkeys(r["controller"] for r in rows))
    by = {(r["controller"], float(r["station.cupboard_yaw_error"])): r for r in rows}
    header = "| yaw error [deg] | " + " | ".join(f"{math.degrees(y):.0f}" for y in yaws) + " |"
    lines = [header, "|---" * (len(yaws) + 1) + "|"]
    for name in controllers:
        doors = [_cell(by[(name, y)]).split(" / ")[0] for y in yaws]
        torques = [f"{float(by[(name, y)]['peak_external_torque_arc_Nm']):.1f}" for y in yaws]
        lines.append(f"| {name}, door | " + " | ".join(doors) + " |")
        lines.append(f"| {name}, torque | " + " | ".join(torques) + " |")
    return "\n".join(lines) + "\n"


def _span(values: list[float], digits: int) -> str:
    """``a-b`` (or ``a`` when the two print the same) at ``digits`` decimals."""
    low, high = f"{min(values):.{digits}f}", f"{max(values):.{digits}f}"
    return low if low == high else f"{low}-{high}"


def _yaws(values: list[float]) -> str:
    """Yaw errors [rad] as the table heads them: ``-15, -10 and +10`` [deg]."""
    words = [f"{math.degrees(y):+.0f}" for y in values]
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


def yaw_error_summary(out: Path) -> str:
    """What the hinge-error sweep's table shows, in words, with the numbers from its rows
    (and the adaptive plan's final hinge estimate, which the table leaves out)."""
    rows = _rows(out)
    by: dict[str, dict[float, dict[str, str]]] = {}
    for r in rows:
        by.setdefault(r["controller"], {})[float(r["station.cupboard_yaw_error"])] = r

    def doors(name: str) -> dict[float, float]:
        return {y: _deg(r["door_opening_arc_end_rad"]) for y, r in by[name].items()}

    def torques(name: str) -> list[float]:
        return [float(r["peak_external_torque_arc_Nm"]) for r in by[name].values()]

    def slipped(name: str) -> list[float]:
        return sorted(y for y, r in by[name].items() if r.get("handle_held") == "False")

    def grows(name: str) -> bool:  # larger at both ends of the range than without error
        ends = (min(by[name]), max(by[name]))
        at = {y: float(r["peak_external_torque_arc_Nm"]) for y, r in by[name].items()}
        return all(at[end] > at[0.0] for end in ends)

    lost = [f"{label} at {_yaws(slipped(name))}" for name, label in
            (("ik", "IK"), ("velocity", "velocity")) if slipped(name)]  # fmt: skip
    position = (
        "The two position-controlled plans force the handle along an arc about the wrong axis"
        + (": their contact torque grows with the error on both sides" if grows("ik") and
           grows("velocity") else "")
        + (f", and they lose the handle ({'; '.join(lost)})." if lost else ".")
    )  # fmt: skip
    impedance, velocity = doors("impedance"), doors("velocity")
    lag = [velocity[y] - impedance[y] for y in impedance]
    widest = min(impedance)
    held = (
        "keeps the handle over the whole range"
        if not slipped("impedance")
        else (f"loses the handle at {_yaws(slipped('impedance'))}")
    )
    yields = (
        f"The impedance plan yields: its contact torque stays at {_span(torques('impedance'), 1)} "
        f"N m and it {held}, its door {impedance[0.0] - impedance[widest]:.1f} deg less open at "
        f"{math.degrees(widest):+.0f} deg than without error (it trails the velocity plan by "
        f"{_span(lag, 0)} deg: the damping lag above)."
    )
    adaptive = by["adaptive"]
    hinge = [
        1e3 * float(r["hinge_estimate_error_m"])
        for r in adaptive.values()
        if r.get("hinge_estimate_error_m") not in (None, "")
    ]
    estimate = (
        f", and its final hinge estimate is {_span(hinge, 1)} mm from the true axis"
        if hinge
        else ""
    )
    knows = (
        f"The adaptive plan, which knows only the grasp, opens the door "
        f"{_span(list(doors('adaptive').values()), 1)} deg by the arc's end over the whole range "
        f"with {_span(torques('adaptive'), 2)} N m of contact torque{estimate}."
    )
    return "\n".join([position, yields, knows]) + "\n"


def _number(value: float | None, scale: float = 1.0) -> str:
    """3 significant digits, as the report prints them."""
    if value is None or not math.isfinite(value):
        return "-"
    from doorlab.outputs.pages import format_number

    return format_number(value * scale)


RUN_LABELS = {
    "ik_2_open": "IK, 2 knots, open",
    "ik_5_open": "IK, 5 knots, open",
    "ik_10_open": "IK, 10 knots, open",
    "ik_10_closed": "IK, 10 knots, closed",
}


def report_runs_table(out: Path) -> str:
    """The report's runs (summary.json): errors, the door and the contact torque."""
    summary = json.loads((out / "summary.json").read_text())
    deg, mm = 180.0 / math.pi, 1000.0
    rows = [
        "| run | max / RMS radial error of Q [mm] | max orientation error [deg] | door at 21 s / "
        "24 s / lag [deg] | peak contact torque in the arc [N m] |",
        "|---|---|---|---|---|",
    ]
    for run in summary["runs"]:
        name = run["name"]
        label = RUN_LABELS.get(name, name.replace("_", ", ", 1).replace("_", " "))
        door = "-"
        if run.get("doors") == "closed":
            door = " / ".join(
                _number(run.get(k), deg)
                for k in ("door_opening_arc_end_rad", "door_opening_rad", "door_lag_max_rad")
            )
        rows.append(
            f"| {label} | {_number(run.get('max_radial_error_m'), mm)} / "
            f"{_number(run.get('rms_radial_error_m'), mm)} | "
            f"{_number(run.get('max_orientation_error_rad'), deg)} | {door} | "
            f"{_number(run.get('peak_external_torque_arc_Nm'))} |"
        )
    return "\n".join(rows)


def report_beyond_answer(out: Path) -> str:
    """The report's comparison beyond the problem set: its generated answer, as Markdown."""
    summary = json.loads((out / "summary.json").read_text())
    return "\n\n".join(summary["beyond"]["answer_markdown"])


def _report_time(name: str) -> Callable[[Path], str]:
    """A block of what benchmarks/report_time.py measured (its results file)."""

    def block(out: Path) -> str:  # noqa: ARG001 (the benchmark writes its results file)
        module = _report_time_module()
        results = json.loads(module.RESULTS.read_text())
        return module.block(name, results) + "\n"

    return block


def _report_time_module() -> ModuleType:
    """benchmarks/report_time.py: its results and how it times a doorlab command."""
    import importlib.util

    path = ROOT / "benchmarks" / "report_time.py"
    spec = importlib.util.spec_from_file_location("doorlab_bench_report_time", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


BENCH_CARD = "benchmarks/results/bench_card_200.json"
"""The benchmark card at 200 episodes per built-in (benchmarks/bench_scale.py's local run)."""


def _stdout_path(out: Path) -> Path:
    """Where :func:`make` keeps the stdout of the command that wrote ``out``."""
    return out.parent / f"{out.name}.stdout.txt"


def _bench_table(out: Path) -> str:
    """The card's table, as ``benchmarks/bench_scale.py --table`` printed it."""
    return _stdout_path(out).read_text()


TARGETS = {
    "run": Target(
        "doorlab run --out {out}",
        {
            "q_path": ("q_path.png", "Q's path in the xy plane against the handle's arc"),
            "radial_error": ("radial_error.png", "Radial tracking error of Q over the arc"),
            "door_angle": ("door_angle.png", "The left door's hinge angle over the episode"),
            "external_torques": ("external_torques.png", "External (contact) joint torques"),
        },
        text={"summary": lambda stdout: stdout},  # the summary it prints
    ),
    "report": Target(
        "doorlab report --robustness --arm --out {out}",
        {
            "radial_error_ik": (
                "figures/t1q1_radial_error.png",
                "Radial error of Q, IK with 2, 5 and 10 knots, doors open",
            ),
            "radial_error_open": (
                "figures/overlay_open_radial_error.png",
                "Radial error of Q, every run with the doors open",
            ),
            "door_angle_closed": (
                "figures/overlay_closed_door_angle.png",
                "The left door's angle, every run with the doors closed",
            ),
            "external_torque_closed": (
                "figures/overlay_closed_external_torque_norm.png",
                "Norm of the external joint torques, every run with the doors closed",
            ),
            "beyond_radial_open": (
                "figures/beyond_open_radial_error.png",
                "Radial error of Q: IK, velocity, impedance, diffik and osc, doors open",
            ),
            "beyond_orientation_open": (
                "figures/beyond_open_orientation_error.png",
                "L7's orientation error: the five controllers, doors open",
            ),
            "beyond_door_closed": (
                "figures/beyond_closed_door_angle.png",
                "The left door's angle: the five controllers, doors closed",
            ),
            "robustness": (
                "figures/robustness.png",
                "Door opened and peak contact torque in the arc against the cupboard's yaw error",
            ),
            "hinge_convergence": (
                "figures/hinge_convergence.png",
                "The adaptive plan's hinge estimate error over time, per yaw error",
            ),
            "arm_band": (
                "figures/arm_band.png",
                "The left door on the arm, each plan under each plausible model of the arm",
            ),
        },
        tables={"runs": report_runs_table, "beyond": report_beyond_answer},
    ),
    "sweep_impedance": Target(
        "doorlab sweep examples/sweep_impedance.yaml --out {out}",
        {
            "heatmap": (
                "figures/heatmap_impedance_kv_station_inner_loop_dq_scale.png",
                "The impedance plan: Kv against the joint damping's scale (dq_scale)",
            ),
        },
        tables={"table": impedance_table},
    ),
    "sweep_hinge_error": Target(
        "doorlab sweep examples/sweep_hinge_error.yaml --out {out}",
        {
            "yaw_error": (
                "figures/axis_0.png",
                "The controllers against the cupboard's yaw error, doors closed",
            ),
        },
        tables={"table": yaw_error_table, "summary": yaw_error_summary},
    ),
    "report_time": Target(
        "python benchmarks/report_time.py",
        {},
        tables={name: _report_time(name) for name in ("summary", "table", "arm")},
    ),
    "bench_200": Target(
        f"python benchmarks/bench_scale.py --table {BENCH_CARD}",
        {},
        tables={"table": _bench_table},
        timed=False,  # a table printed from the card: the card holds what its episodes cost
    ),
    "suite": Target(
        "python -m pytest -p no:cacheprovider",
        {},
        text={"summary": lambda stdout: _pytest_summary(stdout)},
        host_reference=True,
    ),
    "quick_tier": Target(
        'python -m pytest -m "not slow" -p no:cacheprovider',
        {},
        text={"summary": lambda stdout: _pytest_summary(stdout)},
        host_reference=True,
    ),
}
"""What each figure of the site is and which command makes it."""


def _command(target: Target, out: Path) -> list[str]:
    words = shlex.split(target.command.format(out=shlex.quote(str(out))))
    bin_dir = Path(sys.executable).parent
    if words[0] == "doorlab":
        words[0] = str(bin_dir / "doorlab")
    elif words[0] == "python":
        words[0] = sys.executable
    return words


def _time_md(
    command: str, seconds: float, load: float, reference: dict[str, float] | None = None
) -> str:
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    text = (
        f"`{command}` took {seconds:.0f} s of wall time when these figures were made, on a "
        f"machine of {cores} cores (load average {load:.1f} at its start)."
    )
    if reference:
        text += (
            f" Just before it, on the same machine, the README's main job (`doorlab run`) took "
            f"{reference['cpu']:.1f} CPU-s: the CPU line above is {reference['ratio']:.0f} "
            "main jobs' worth."
        )
    return text + "\n"


def _cpu_seconds(stdout: str) -> float:
    """The CPU line's total (``CPU: 1491 CPU-s ...``, tests/run_cost.py) [CPU-s]."""
    match = re.search(r"^CPU: (\d+(?:\.\d+)?) CPU-s", stdout, re.MULTILINE)
    if match is None:
        raise SystemExit("no CPU line in pytest's output (tests/run_cost.py)")
    return float(match.group(1))


def _main_job_cpu(work: Path) -> float:
    """The CPU one run of the README's main job (``doorlab run``) takes on this machine now,
    the run and every process it waited for [CPU-s] (benchmarks/report_time.py's timing): how
    fast the machine is, in the project's own unit of work."""
    module = _report_time_module()
    shutil.rmtree(work / "main_job", ignore_errors=True)
    try:
        run = module.timed(module.cli("run", "--out", "main_job"), work)
    except RuntimeError as error:
        raise SystemExit(f"the main job: {error}") from None
    if run["exit_code"] != 0:
        raise SystemExit(f"the main job: exit {run['exit_code']} (a run not ok)")
    return run["cpu_s"]


def make(name: str, work: Path, *, reuse: bool = False) -> None:
    """Runs target ``name`` into ``work/name`` (``reuse``: unless a run left it there) and
    copies its figures and texts into docs/figures/name."""
    target = TARGETS[name]
    out = work / name
    stdout = _stdout_path(out)
    timing = work / f"{name}.time.json"
    if not (reuse and out.is_dir() and stdout.is_file()):
        shutil.rmtree(out, ignore_errors=True)
        print(f"== {name}: {target.command.format(out=out)}", flush=True)
        main_job = _main_job_cpu(work) if target.host_reference else None
        load, start = os.getloadavg()[0], time.perf_counter()
        done = subprocess.run(_command(target, out), cwd=ROOT, capture_output=True, text=True)
        seconds = time.perf_counter() - start
        sys.stdout.write(done.stdout)
        if done.returncode not in (0, 1):  # 1: the report or a sweep had a run not ok
            sys.stderr.write(done.stderr)
            raise SystemExit(f"{name}: exit {done.returncode}")
        stdout.write_text(done.stdout)
        measured = {"seconds": seconds, "load": load}
        if main_job is not None:
            ratio = _cpu_seconds(done.stdout) / main_job
            measured["reference"] = {"cpu": main_job, "ratio": ratio}
        timing.write_text(json.dumps(measured))
    dest = FIGURES / name
    dest.mkdir(parents=True, exist_ok=True)
    for figure, (source, _) in target.figures.items():
        shutil.copyfile(out / source, dest / f"{figure}.png")
    for text_name, keep in (target.text or {}).items():
        text = keep(stdout.read_text().replace(str(out), "doorlab_out/velocity_closed"))
        (dest / f"{text_name}.txt").write_text(text)
    for table_name, table in (target.tables or {}).items():
        (dest / f"{table_name}.md").write_text(table(out))
    if target.timed and timing.is_file():
        measured = json.loads(timing.read_text())
        command = target.command.replace(" --out {out}", "").format(out="DIR")
        (dest / "time.md").write_text(
            _time_md(command, measured["seconds"], measured["load"], measured.get("reference"))
        )


def write_pages() -> None:
    """Every page's measured regions from docs/figures (doorlab_reference.measured)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from doorlab_reference.measured import write_pages as write

    changed, missing = write()
    for page in changed:
        print(f"wrote the measured regions of {page}")
    if missing:
        raise SystemExit("regions left as they were:\n" + "\n".join(missing))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("targets", nargs="*", metavar="TARGET", help=", ".join(TARGETS))
    parser.add_argument(
        "--keep",
        type=Path,
        default=None,
        metavar="DIR",
        help="run into DIR and keep the outputs; a target whose outputs are there is not run "
        "again (its figures are copied again)",
    )
    parser.add_argument(
        "--pages",
        action="store_true",
        help="only write the pages' measured regions again from docs/figures",
    )
    args = parser.parse_args(argv)
    if args.pages:
        write_pages()
        return 0
    unknown = [t for t in args.targets if t not in TARGETS]
    if unknown:
        parser.error(f"unknown targets {unknown}; valid: {', '.join(TARGETS)}")
    names = args.targets or list(TARGETS)
    # The pages are written after each target, so that the next one runs in a consistent
    # tree: the suite's targets check that every page is what docs/figures holds.
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
        for name in names:
            make(name, args.keep.resolve(), reuse=True)
            write_pages()
        return 0
    with tempfile.TemporaryDirectory(prefix="doorlab_figures_") as work:
        for name in names:
            make(name, Path(work))
            write_pages()
    return 0


if __name__ == "__main__":
    sys.exit(main())
