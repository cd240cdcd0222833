"""Makes the site's figures from real runs: ``python docs/tools/make_figures.py [TARGET ...]``.

Each target runs one doorlab command (or benchmark) into a temporary folder and copies the
figures the pages show into ``docs/figures/TARGET/``; the pages show each figure with the
command that made it (the ``<!-- doorlab:figure TARGET/NAME -->`` marker of
``docs/tools/reference.py`` reads :data:`TARGETS`). A target's tables (Markdown written from
its output, e.g. the report's ``summary.json``) go to ``docs/figures/TARGET/NAME.txt`` and into
every page between the markers ``<!-- figures:TARGET/NAME ... -->`` and
``<!-- /figures:TARGET/NAME -->`` (tests/test_docs.py checks that the pages hold the files'
text). Without arguments every target is made (the report with all its sections is the
longest: docs/guides/experiments.md, "What each section costs").

``--keep DIR`` runs into DIR and keeps the outputs there; a target already run there is
not run again, only its figures copied (to change which figures a page shows).
"""

from __future__ import annotations

import argparse
import json
import math
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FIGURES = ROOT / "docs" / "figures"


@dataclass(frozen=True)
class Target:
    """One command and the figures taken from its output folder."""

    command: str  # run from the repository's root; {out} is the output folder
    figures: dict[str, tuple[str, str]]  # name -> (file in {out}, caption)
    text: dict[str, str] | None = None  # name -> what to keep of the command's stdout
    tables: dict[str, Callable[[Path], str]] | None = None  # name -> Markdown from {out}


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


TARGETS = {
    "run": Target(
        "doorlab run --out {out}",
        {
            "q_path": ("q_path.png", "Q's path in the xy plane against the handle's arc"),
            "radial_error": ("radial_error.png", "Radial tracking error of Q over the arc"),
            "door_angle": ("door_angle.png", "The left door's hinge angle over the episode"),
            "external_torques": ("external_torques.png", "External (contact) joint torques"),
        },
        text={"summary": "the summary it prints"},
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
    ),
    "sweep_hinge_error": Target(
        "doorlab sweep examples/sweep_hinge_error.yaml --out {out}",
        {
            "yaw_error": (
                "figures/axis_0.png",
                "All four controllers against the cupboard's yaw error, doors closed",
            ),
        },
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


def make(name: str, work: Path, *, reuse: bool = False) -> None:
    """Runs target ``name`` into ``work/name`` (``reuse``: unless a run left it there) and
    copies its figures into docs/figures/name."""
    target = TARGETS[name]
    out, stdout = work / name, work / f"{name}.stdout.txt"
    if not (reuse and out.is_dir() and stdout.is_file()):
        shutil.rmtree(out, ignore_errors=True)
        print(f"== {name}: {target.command.format(out=out)}", flush=True)
        done = subprocess.run(_command(target, out), cwd=ROOT, capture_output=True, text=True)
        sys.stdout.write(done.stdout)
        if done.returncode not in (0, 1):  # 1: the report or a sweep had a run not ok
            sys.stderr.write(done.stderr)
            raise SystemExit(f"{name}: exit {done.returncode}")
        stdout.write_text(done.stdout)
    dest = FIGURES / name
    dest.mkdir(parents=True, exist_ok=True)
    for figure, (source, _) in target.figures.items():
        shutil.copyfile(out / source, dest / f"{figure}.png")
    for text_name in target.text or {}:
        text = stdout.read_text().replace(str(out), "doorlab_out/velocity_closed")
        (dest / f"{text_name}.txt").write_text(text)
    for table, write in (target.tables or {}).items():
        markdown = write(out)
        (dest / f"{table}.txt").write_text(markdown + "\n")
        for page in sorted((ROOT / "docs").rglob("*.md")):
            text = page.read_text()
            replaced = replace_block(text, f"{name}/{table}", markdown)
            if replaced != text:
                page.write_text(replaced)
                print(f"   {page.relative_to(ROOT)}: {name}/{table}")


BLOCK_BEGIN = "<!-- figures:{key} (python docs/tools/make_figures.py {target}) -->"
BLOCK_END = "<!-- /figures:{key} -->"


def _block_pattern(key: str) -> re.Pattern:
    begin = BLOCK_BEGIN.format(key=key, target=key.split("/")[0])
    return re.compile(
        "(" + re.escape(begin) + r"\n)(.*?)(\n" + re.escape(BLOCK_END.format(key=key)) + ")", re.S
    )


def replace_block(page_text: str, key: str, markdown: str) -> str:
    """``page_text`` with the block ``key`` (``TARGET/NAME``) holding ``markdown``."""
    return _block_pattern(key).sub(lambda m: m.group(1) + markdown + m.group(3), page_text)


def quoted_blocks(page_text: str) -> dict[str, str]:
    """The blocks a page holds: {``TARGET/NAME``: its text}."""
    keys = re.findall(r"<!-- figures:([\w./-]+) \(python docs/tools/make_figures.py", page_text)
    out = {}
    for key in keys:
        match = _block_pattern(key).search(page_text)
        if match:
            out[key] = match.group(2)
    return out


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
    args = parser.parse_args(argv)
    unknown = [t for t in args.targets if t not in TARGETS]
    if unknown:
        parser.error(f"unknown targets {unknown}; valid: {', '.join(TARGETS)}")
    names = args.targets or list(TARGETS)
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
        for name in names:
            make(name, args.keep.resolve(), reuse=True)
        return 0
    with tempfile.TemporaryDirectory(prefix="doorlab_figures_") as work:
        for name in names:
            make(name, Path(work))
    return 0


if __name__ == "__main__":
    sys.exit(main())
