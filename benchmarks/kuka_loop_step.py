#!/usr/bin/env python3
"""KUKA's loop without the simulator's h Kq: is the explicit spring still stable, and what did
the term change? (docs/guides/real-arm.md, "The simulator's step").

doorlab's ``stiffness`` loop damps with Dq + h Kq: the h Kq is what SAP's implicit PD added by
evaluating the spring at the step's end, kept so that doorlab's gains keep their physics. KUKA's
loop runs in the robot, not in the simulator: its damping must not depend on
``station.time_step``, so it is now Dq alone. This script measures, for each damping mapping
of ``station.inner_loop.kuka_damping_model``:

- the spectral radius of one plant step of the linearized arm (explicit spring, implicit
  damping, M(q) at the grasp pose with the rotors) at the preset's 2.5 ms, without and with
  h Kq, and the largest step at which it stays below 1 (bisection);
- each plan's door at the arc's end, Q's max radial error and L7's max orientation error on
  the preset, without h Kq (now) and with it (the damping given as Dq + h Kq values).

Usage::

    python benchmarks/kuka_loop_step.py [--out benchmarks/results/kuka_loop_step.json]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

BENCH_DIR = Path(__file__).resolve().parent
PRESET = BENCH_DIR.parent / "examples" / "kuka_arm.yaml"


def spectral_radius(M: np.ndarray, K: np.ndarray, D: np.ndarray, h: float) -> float:
    n = len(M)
    B = np.linalg.inv(M + h * D)
    A_vv, A_vq = B @ M, -h * B @ K
    A = np.block([[np.eye(n) + h * A_vq, h * A_vv], [A_vq, A_vv]])
    return float(np.max(np.abs(np.linalg.eigvals(A))))


def largest_stable_step(M, K, D, low=1e-4, high=1.0) -> float:
    """The largest plant step [s] at which one step of the linearized loop is stable (up to
    ``high``: the explicit spring with an implicit damping is stable at any step the
    bisection tries when this returns ``high``)."""
    for _ in range(60):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if spectral_radius(M, K, D, mid) < 1.0 else (low, mid)
    return low


def episode(controller: str, model: str, with_hkq: bool) -> dict:
    from doorlab.cell.geometry import true_door_geometry
    from doorlab.cell.station import loop_gains
    from doorlab.config import load_scenario, update_scenario
    from doorlab.episode.controllers import run_controller
    from doorlab.episode.metrics import compute_metrics
    from doorlab.errors import RunStopped

    scenario = load_scenario(PRESET)
    scenario = update_scenario(
        scenario, f"station: {{inner_loop: {{kuka_damping_model: {model}}}}}"
    )
    scenario.controller = controller
    if with_hkq:
        K, D = loop_gains(scenario.station.inner_loop)
        values = [float(v) for v in D + scenario.station.time_step * K]
        fields = f"kuka_damping_model: values, kuka_damping_values: {values}"
        scenario = update_scenario(scenario, f"station: {{inner_loop: {{{fields}}}}}")
    try:
        result, _ = run_controller(scenario)
    except RunStopped as e:
        return {"status": e.status}
    m = compute_metrics(result, scenario, true_door_geometry(scenario))
    return {
        "status": m.status,
        "door_deg": math.degrees(m.door_opening_arc_end_rad),
        "radial_mm": 1e3 * m.max_radial_error_m,
        "orientation_deg": math.degrees(m.max_orientation_error_rad),
        "held": m.handle_held,
    }


def main(argv: list[str] | None = None) -> int:
    from doorlab.cell.station import loop_gains, make_controller_plant
    from doorlab.config import load_scenario, update_scenario
    from doorlab.constants import Q_GRASP

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=BENCH_DIR / "results" / "kuka_loop_step.json")
    parser.add_argument("--models", nargs="+", default=["rotor_link", "link", "driver_kd"])
    args = parser.parse_args(argv)
    plant = make_controller_plant()
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, Q_GRASP)
    M = plant.CalcMassMatrix(context)
    out = {"stability": [], "episodes": []}
    for model in args.models:
        s = update_scenario(
            load_scenario(PRESET), f"station: {{inner_loop: {{kuka_damping_model: {model}}}}}"
        )
        K, D = (np.diag(v) for v in loop_gains(s.station.inner_loop))
        h = s.station.time_step
        row = {
            "model": model,
            "time_step_s": h,
            "radius_without_hkq": spectral_radius(M, K, D, h),
            "radius_with_hkq": spectral_radius(M, K, D + h * K, h),
            "largest_stable_step_without_hkq_s": largest_stable_step(M, K, D),
        }
        out["stability"].append(row)
        print(json.dumps(row), flush=True)
        for controller in ("ik", "velocity", "impedance", "adaptive"):
            for with_hkq in (False, True):
                r = {"model": model, "controller": controller, "hkq": with_hkq}
                r.update(episode(controller, model, with_hkq))
                out["episodes"].append(r)
                print(json.dumps(r), flush=True)
    args.out.write_text(json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
