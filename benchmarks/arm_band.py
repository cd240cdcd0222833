#!/usr/bin/env python3
"""Which of the arm's uncertain parameters interact? Every pair, on every plan (the report's
corners, ``doorlab.report.experiments.ARM_CORNERS``, come from here).

``doorlab report``'s "On the arm" runs each plan under the nominal arm model (the preset) and
under each other model of the band one parameter at a time
(:data:`doorlab.report.experiments.ARM_MODELS`). A pair of parameters interacts when the two
together do what neither does alone: this script runs every pair of models of different
parameters on every plan (the four controllers and the tuned plans of ``ARM_TUNING``, doors
closed) and reports, per corner, the door at the arc's end against the one-at-a-time
prediction (nominal + effect of A + effect of B) and whether the verdict ("opened": status
ok, >= 39 deg, handle held) differs from both A's and B's. A corner whose verdict is new, or
whose door moves 1 deg or more from the prediction, is an interaction the report must run.

Usage::

    python benchmarks/arm_band.py [--jobs 2] [--out benchmarks/results/arm_band.json]
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parent
INTERACTION_DEG = 1.0
"""A corner whose door at the arc's end is this far from the one-at-a-time prediction [deg]
interacts."""


def plans() -> list[tuple[str, bool]]:
    from doorlab.episode.controllers import REGISTRY
    from doorlab.report.experiments import ARM_TUNING

    return [(c, False) for c in REGISTRY] + [(c, True) for c in ARM_TUNING]


def corners() -> list[str]:
    from doorlab.report.experiments import ARM_MODELS

    return [
        f"{a.name}+{b.name}"
        for a, b in itertools.combinations(ARM_MODELS, 2)
        if a.parameter != b.parameter
    ]


def run(controller: str, tuned: bool, model: str) -> dict:
    from doorlab.cell.geometry import true_door_geometry
    from doorlab.config import Scenario, update_scenario
    from doorlab.episode.controllers import run_controller
    from doorlab.episode.metrics import compute_metrics
    from doorlab.errors import RunStopped
    from doorlab.report.experiments import ARM_TUNING, apply_arm_model, arm_condition
    from doorlab.studies.robustness import OPEN_THRESHOLD_DEG

    scenario = arm_condition(Scenario(), "arm")
    scenario.controller = controller
    if tuned:
        scenario = update_scenario(scenario, ARM_TUNING[controller])
    scenario = apply_arm_model(scenario, model)
    row = {"controller": controller, "tuned": tuned, "model": model}
    start = time.process_time()
    try:
        result, _ = run_controller(scenario)
    except RunStopped as e:
        return {**row, "status": e.status, "opened": False, "door_deg": None, "error": str(e)}
    m = compute_metrics(result, scenario, true_door_geometry(scenario))
    door = math.degrees(m.door_opening_arc_end_rad)
    return {
        **row,
        "status": m.status,
        "door_deg": door,
        "radial_mm": 1e3 * m.max_radial_error_m,
        "orientation_deg": math.degrees(m.max_orientation_error_rad),
        "held": m.handle_held,
        "opened": bool(m.status == "ok" and m.handle_held and door >= OPEN_THRESHOLD_DEG),
        "cpu_s": time.process_time() - start,
    }


def analyse(rows: list[dict]) -> list[dict]:
    """Per plan and corner: the door against the one-at-a-time prediction, the verdicts."""
    by = {(r["controller"], r["tuned"], r["model"]): r for r in rows}
    out = []
    for controller, tuned in plans():
        nominal = by[(controller, tuned, "")]
        for corner in corners():
            a, b = corner.split("+")
            ra, rb, rab = (by[(controller, tuned, m)] for m in (a, b, corner))
            doors = [r["door_deg"] for r in (nominal, ra, rb, rab)]
            interaction = None
            if None not in doors:
                predicted = doors[1] + doors[2] - doors[0]
                interaction = doors[3] - predicted
            new_verdict = ra["opened"] == rb["opened"] != rab["opened"]
            out.append(
                {
                    "controller": controller,
                    "tuned": tuned,
                    "corner": corner,
                    "opened": [nominal["opened"], ra["opened"], rb["opened"], rab["opened"]],
                    "status": rab["status"],
                    "door_deg": doors,
                    "door_interaction_deg": interaction,
                    "new_verdict": new_verdict,
                    "interacts": new_verdict
                    or (interaction is not None and abs(interaction) >= INTERACTION_DEG),
                }
            )
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", type=Path, default=BENCH_DIR / "results" / "arm_band.json")
    args = parser.parse_args(argv)
    from doorlab.report.experiments import ARM_MODELS

    models = ["", *(m.name for m in ARM_MODELS), *corners()]
    jobs = [(c, tuned, m) for c, tuned in plans() for m in models]
    start = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(run, *zip(*jobs, strict=True)))
    wall = time.perf_counter() - start
    found = analyse(rows)
    interacting = sorted({f["corner"] for f in found if f["interacts"]})
    with open("/proc/loadavg") as f:
        load = f.read().split()[:3]
    result = {
        "runs": len(rows),
        "wall_s": wall,
        "jobs": args.jobs,
        "loadavg": load,
        "interaction_threshold_deg": INTERACTION_DEG,
        "interacting_corners": interacting,
        "corners": found,
        "rows": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    for f in found:
        if f["interacts"]:
            plan = f["controller"] + (" tuned" if f["tuned"] else "")
            print(
                f"{plan:<18} {f['corner']:<36} opened {f['opened']} status {f['status']} "
                f"door {f['door_deg']} interaction {f['door_interaction_deg']}"
            )
    print(f"interacting corners: {interacting}; {len(rows)} runs in {wall:.0f} s (load {load})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
