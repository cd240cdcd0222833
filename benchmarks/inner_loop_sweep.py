#!/usr/bin/env python3
"""The stiffness inner loop's damping trade-off, measured: one row per Dq scale.

The problem set's inner loop is tau = Kq (q_ref - q) - Dq qdot + g(q) + tau_ff. Its damping Dq pulls
two ways (docs/explanation/model.md, "Inner loop gains"):

- the position plans (IK, velocity) want a well damped joint loop (no ringing, a small lag
  Dq/Kq x joint speed);
- the impedance plan sends q_ref = q, so Dq qdot is all that resists its J^T F: the more
  damping, the further the door trails the 10 s arc.

For each ``station.inner_loop.dq_scale`` the script runs IK (10 knots) and velocity with the
doors closed and open, and the impedance plan with both, and tabulates the tracking errors, the
door at the arc's end (t = 21 s), the door's largest lag behind the plan and the statuses.
Every figure comes from ``doorlab.episode.metrics.compute_metrics``.

Usage::

    python benchmarks/inner_loop_sweep.py [--scales 0.25 0.5 1 2 4] [--jobs 2]
        [--set KEY=VALUE ...] [--out benchmarks/results/inner_loop_sweep.json] [--quick]

``--quick`` runs only the closed-door impedance and velocity plans at two scales (a smoke
test). Writes a JSON file and prints a markdown table.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import math
import sys
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parent
DEFAULT_SCALES = (0.25, 0.5, 1.0, 2.0, 4.0)
RUNS = (
    ("ik", "closed"),
    ("velocity", "closed"),
    ("impedance", "closed"),
    ("ik", "open"),
    ("velocity", "open"),
    ("impedance", "open"),
)
QUICK_RUNS = (("velocity", "closed"), ("impedance", "closed"))


def _scenario(controller: str, doors: str, scale: float, overrides: list[str]):
    from doorlab.cli.commands import apply_overrides
    from doorlab.config import Scenario

    scenario = apply_overrides(Scenario(controller=controller, doors=doors), overrides)
    scenario.station.inner_loop.dq_scale = scale
    return scenario


def run_one(controller: str, doors: str, scale: float, overrides: list[str]) -> dict:
    """Worker: one episode, its metrics as a dict (status ``error`` if it raised)."""
    from doorlab.cell.geometry import true_door_geometry
    from doorlab.episode.controllers import run_controller
    from doorlab.episode.metrics import compute_metrics

    scenario = _scenario(controller, doors, scale, overrides)
    row = {"controller": controller, "doors": doors, "dq_scale": scale}
    try:
        result, _ = run_controller(scenario)
    except Exception as e:  # one failed run must not lose the sweep
        return {**row, "status": "error", "message": f"{type(e).__name__}: {e}"}
    m = compute_metrics(result, scenario, true_door_geometry(scenario))
    return {**row, **m.to_dict(), "dq": [d * scale for d in scenario.station.inner_loop.dq]}


def _deg(x: float | None) -> str:
    return "-" if x is None else f"{math.degrees(x):.1f}"


def table(rows: list[dict]) -> str:
    """Markdown: one line per scale, the runs' key figures side by side."""
    by = {(r["dq_scale"], r["controller"], r["doors"]): r for r in rows}
    scales = sorted({r["dq_scale"] for r in rows})
    runs = [run for run in RUNS if any((s, *run) in by for s in scales)]
    head = ["Dq scale"]
    for controller, doors in runs:
        name = f"{controller} {doors}"
        if doors == "closed":
            head += [f"{name}: max radial [mm]", f"{name}: door at 21 s / lag [deg]"]
        else:
            head += [f"{name}: max / RMS radial [mm]"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for s in scales:
        cells = [f"{s:g}"]
        for controller, doors in runs:
            r = by.get((s, controller, doors))
            if r is None or r["status"] == "error":
                cells += ["error"] * (2 if doors == "closed" else 1)
                continue
            flag = "" if r["status"] == "ok" else f" ({r['status']})"
            radial = 1e3 * r["max_radial_error_m"]
            if doors == "closed":
                cells += [
                    f"{radial:.2f}{flag}",
                    f"{_deg(r['door_opening_arc_end_rad'])} / {_deg(r['door_lag_max_rad'])}",
                ]
            else:
                cells += [f"{radial:.2f} / {1e3 * r['rms_radial_error_m']:.2f}{flag}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scales", type=float, nargs="+", default=list(DEFAULT_SCALES))
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    parser.add_argument("--out", type=Path, default=BENCH_DIR / "results" / "inner_loop_sweep.json")
    parser.add_argument("--quick", action="store_true", help="two scales, two closed runs")
    args = parser.parse_args(argv)
    scales = args.scales[:2] if args.quick else args.scales
    runs = QUICK_RUNS if args.quick else RUNS
    if any(s < 0 or not math.isfinite(s) for s in scales) or args.jobs < 1:
        print("error: --scales must be finite numbers >= 0 and --jobs >= 1", file=sys.stderr)
        return 2
    try:
        _scenario("velocity", "closed", 1.0, args.overrides)
    except Exception as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    tasks = [(c, d, s, args.overrides) for s in scales for c, d in runs]
    with concurrent.futures.ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(run_one, *zip(*tasks, strict=True)))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"overrides": args.overrides, "rows": rows}, indent=1))
    print(table(rows))
    print(f"\nwritten: {args.out}")
    return 1 if any(r["status"] == "error" for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
