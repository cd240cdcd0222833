"""Every controller against an unknown hinge: door opened, contact torque, largest yaw error.

Runs IK, velocity, impedance and adaptive side by side on the same cupboard yaw errors (the
acceptance grid by default), then, per controller and side, scans outwards in ``--step``
degrees from the grid's last success to the first failure and bisects there: the largest yaw
error up to which it opens the door (>= 39 deg at the arc's end, handle held). Writes
``robustness.json``, the Markdown table ``robustness.md`` and the figures ``robustness.png``
and ``hinge_convergence.png`` into ``--out`` and prints the tables.

    python benchmarks/robustness.py [--jobs N] [--yaw DEG ...] [--no-search] [--out DIR]
        [--step DEG] [--tolerance DEG] [--set KEY=VALUE ...]

Every number printed is measured by this run.
"""

from __future__ import annotations

import concurrent.futures
import json
import math
import multiprocessing
import os
import sys
import time
from pathlib import Path

from doorlab.cli.commands import apply_overrides
from doorlab.config import CONTROLLERS, Scenario
from doorlab.errors import DoorlabError
from doorlab.outputs.plots import plot_hinge_convergence
from doorlab.runtime.argtypes import OneLineParser, bounded_int
from doorlab.studies.robustness import (
    ACCEPTANCE_YAW_ERRORS_DEG,
    largest_opening_yaw,
    plot_robustness,
    robustness_table,
    run_case,
    run_grid,
)

BENCH_DIR = Path(__file__).resolve().parent


def _search(
    base: Scenario, controller: str, sign: int, opened: float, step: float, tolerance: float
):
    return largest_opening_yaw(
        base, controller, sign, opened_rad=opened, step_rad=step, tolerance_rad=tolerance
    )


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="robustness", description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=bounded_int(1), default=os.cpu_count() or 1)
    parser.add_argument(
        "--yaw",
        type=float,
        nargs="+",
        default=list(ACCEPTANCE_YAW_ERRORS_DEG),
        help="cupboard yaw errors of the grid [deg]",
    )
    parser.add_argument("--no-search", action="store_true", help="skip the bisection")
    parser.add_argument("--tolerance", type=float, default=0.5, help="bisection bracket [deg]")
    parser.add_argument("--step", type=float, default=2.5, help="scan step past the grid [deg]")
    parser.add_argument("--out", type=Path, default=BENCH_DIR / "results" / "robustness")
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    args = parser.parse_args(argv)
    try:
        base = apply_overrides(Scenario(), args.overrides)
    except DoorlabError as e:
        print(f"robustness: error: {e}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    yaw = [math.radians(y) for y in args.yaw]

    start = time.perf_counter()
    rows = run_grid(base, CONTROLLERS, yaw, jobs=args.jobs)
    grid_wall = time.perf_counter() - start
    table = robustness_table(rows)
    print(table)
    print(f"\n{len(rows)} episodes in {grid_wall:.0f} s wall ({args.jobs} jobs)")

    largest = []
    if not args.no_search:
        # Start each side's scan at the largest |yaw| of the grid that opened with every
        # smaller one on that side opening too (none if 0 itself fails).
        tasks = []
        for controller in CONTROLLERS:
            for sign in (-1, 1):
                side = sorted(
                    (r for r in rows if r.controller == controller and sign * r.yaw_error_rad >= 0),
                    key=lambda r: abs(r.yaw_error_rad),
                )
                opened, failed = 0.0, None
                for r in side:
                    if r.opened:
                        opened = abs(r.yaw_error_rad)
                    else:
                        failed = abs(r.yaw_error_rad)
                        break
                if failed == 0.0:  # fails without any yaw error: nothing to search
                    largest.append((controller, sign, float("nan"), 0.0, 0))
                    continue
                tasks.append((controller, sign, opened))
        start = time.perf_counter()
        context = multiprocessing.get_context("spawn")
        with concurrent.futures.ProcessPoolExecutor(args.jobs, mp_context=context) as pool:
            futures = [
                pool.submit(
                    _search, base, c, s, o, math.radians(args.step), math.radians(args.tolerance)
                )
                for c, s, o in tasks
            ]
            for f in futures:
                r = f.result()
                largest.append((r.controller, r.sign, r.opened_rad, r.failed_rad, r.runs))
        search_wall = time.perf_counter() - start
        print("\nLargest cupboard yaw error up to which each controller opens the door")
        print("| controller | side | opens at [deg] | fails at [deg] | episodes |")
        print("|---|---|---|---|---|")
        for controller, sign, opened, failed, runs in sorted(largest):
            fails = f"{math.degrees(failed):.2f}" if math.isfinite(failed) else "none up to 45"
            opens = f"{math.degrees(opened):.2f}" if math.isfinite(opened) else "never"
            print(f"| {controller} | {'+' if sign > 0 else '-'} | {opens} | {fails} | {runs} |")
        print(f"\nscan + bisection: {sum(r[4] for r in largest)} episodes in {search_wall:.0f} s")

    # Figures (from the rows; the convergence plot reruns the adaptive grid's episodes,
    # since the grid's worker processes return rows only).
    from doorlab.cell.geometry import true_door_geometry
    from doorlab.outputs.plots import save_figure
    from doorlab.studies.robustness import case_scenario

    save_figure(plot_robustness(rows), args.out / "robustness.png")
    episodes = {}
    for y in yaw:
        _, result = run_case(base, "adaptive", y)
        if result is not None:
            geometry = true_door_geometry(case_scenario(base, "adaptive", y))
            episodes[f"yaw {math.degrees(y):+.0f} deg"] = (result, geometry)
    save_figure(plot_hinge_convergence(episodes), args.out / "hinge_convergence.png")
    (args.out / "robustness.md").write_text(table + "\n")
    (args.out / "robustness.json").write_text(
        json.dumps(
            {
                "grid": [r.to_dict() for r in rows],
                "largest_yaw": [
                    {
                        "controller": c,
                        "sign": s,
                        "opened_rad": o,
                        "failed_rad": f,
                        "episodes": n,
                    }
                    for c, s, o, f, n in largest
                ],
                "grid_wall_s": grid_wall,
                "jobs": args.jobs,
            },
            indent=2,
            allow_nan=True,
        )
        + "\n"
    )
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
