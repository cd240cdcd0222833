#!/usr/bin/env python3
"""doorlab's eight experiments next to the original station's (``doorlab.studies.reference``).

Reads the ``metrics.json`` of two ``doorlab report`` folders (no simulation is re-run):

- doorlab with its default inner loop (the problem set's stiffness law), and
- doorlab with ``station.inner_loop.kind=inverse_dynamics`` (the original's ID-PID: like for
  like with the reference),

and writes a markdown table (and the same figures as JSON) with, per run: max / RMS radial
error [mm], max orientation error [deg], the door at the arc's end (t = 21 s) [deg] and peak
arc contact torque [N m], for the reference, doorlab (stiffness) and doorlab (ID-PID).

Usage::

    doorlab report --out /tmp/r_stiffness
    doorlab report --out /tmp/r_id --set station.inner_loop.kind=inverse_dynamics
    python benchmarks/fidelity_table.py /tmp/r_stiffness /tmp/r_id \\
        [--out benchmarks/results/fidelity.md]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from doorlab.studies.reference import ORIGINAL_STATION, ReferenceRun

BENCH_DIR = Path(__file__).resolve().parent
LABELS = {
    "ik_2_open": "IK 2 knots, open",
    "ik_5_open": "IK 5, open",
    "ik_10_open": "IK 10, open",
    "ik_10_closed": "IK 10, closed",
    "velocity_open": "velocity, open",
    "velocity_closed": "velocity, closed",
    "impedance_open": "impedance, open",
    "impedance_closed": "impedance, closed",
}


def load_metrics(report_dir: Path) -> dict[str, dict]:
    """{run name: metrics.json} of a report folder (runs/<name>/metrics.json)."""
    out = {}
    for path in sorted(report_dir.glob("runs/*/metrics.json")):
        out[path.parent.name] = json.loads(path.read_text())
    return out


def figures(m: dict | None) -> dict | None:
    """The reference table's columns from one metrics.json (None if the run is missing)."""
    if m is None or "max_radial_error_m" not in m:
        return None
    door = m.get("door_opening_arc_end_rad")
    return {
        "status": m.get("status"),
        "max_radial_mm": 1e3 * m["max_radial_error_m"],
        "rms_radial_mm": 1e3 * m["rms_radial_error_m"],
        "max_orientation_deg": math.degrees(m["max_orientation_error_rad"]),
        "door_arc_end_deg": None if m["doors"] == "open" else math.degrees(door),
        "door_lag_deg": None
        if m.get("door_lag_max_rad") is None
        else math.degrees(m["door_lag_max_rad"]),
        "peak_arc_contact_Nm": m["peak_external_torque_arc_Nm"],
    }


def _cell(f: dict | ReferenceRun | None) -> list[str]:
    if f is None:
        return ["missing"] * 4
    g = f.__dict__ if isinstance(f, ReferenceRun) else f
    door = g["door_arc_end_deg"]
    status = g.get("status")
    flag = "" if status in (None, "ok") else f" **{status}**"
    return [
        f"{g['max_radial_mm']:.2f} / {g['rms_radial_mm']:.2f}{flag}",
        f"{g['max_orientation_deg']:.2f}",
        "-" if door is None else f"{door:.1f}",
        f"{g['peak_arc_contact_Nm']:.2f}",
    ]


def table(stiffness: dict[str, dict], inverse_dynamics: dict[str, dict]) -> tuple[str, dict]:
    """Markdown table and JSON-ready rows."""
    head = (
        "| run | source | max / RMS radial [mm] | max orientation [deg] | door at 21 s [deg] "
        "| peak arc contact torque [N m] |"
    )
    lines = [head, "|---|---|---|---|---|---|"]
    rows = {}
    for name, label in LABELS.items():
        ref = ORIGINAL_STATION[name]
        ours = figures(stiffness.get(name))
        like = figures(inverse_dynamics.get(name))
        rows[name] = {"reference": ref.__dict__, "stiffness": ours, "inverse_dynamics": like}
        for source, f in (
            ("original (ID-PID)", ref),
            ("doorlab, stiffness", ours),
            ("doorlab, ID-PID", like),
        ):
            lines.append(f"| {label} | {source} | " + " | ".join(_cell(f)) + " |")
    return "\n".join(lines), rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("stiffness", type=Path, help="report folder, default inner loop")
    parser.add_argument("inverse_dynamics", type=Path, help="report folder, ID-PID inner loop")
    parser.add_argument("--out", type=Path, default=BENCH_DIR / "results" / "fidelity.md")
    args = parser.parse_args(argv)
    reports = [load_metrics(p) for p in (args.stiffness, args.inverse_dynamics)]
    if not all(reports):
        print(
            "error: both folders must be doorlab report folders (runs/*/metrics.json)",
            file=sys.stderr,
        )
        return 2
    text, rows = table(*reports)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text + "\n")
    args.out.with_suffix(".json").write_text(json.dumps(rows, indent=1))
    print(text)
    print(f"\nwritten: {args.out} and {args.out.with_suffix('.json').name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
