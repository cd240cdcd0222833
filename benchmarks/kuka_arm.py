#!/usr/bin/env python3
"""The arm preset's modelling choices, measured side by side (docs/guides/real-arm.md).

KUKA does not publish how its joint impedance turns the dimensionless damping d into N m s/rad.
doorlab takes D_i = 2 d sqrt(K_i M_ii) with M_ii the model's joint inertia at the problem
set's grasp pose (``examples/kuka_arm.yaml``, :func:`doorlab.cell.station.loop_gains`). This script
runs the four controllers on the preset, doors closed, three ways:

- ``grasp_pose``: the preset (M_ii at Q_GRASP, constant);
- ``each_step``: M_ii(q) of the arm as it stands, the joints' damping set before every plant
  step (Python per step: a study, not a product path);
- ``step_2ms``: the preset with doorlab's default 2 ms plant step instead of 2.5 ms (the
  preset's step puts two plant steps in each 5 ms cycle).

and tabulates the door at the arc's end, Q's max radial error, whether the handle was held,
the peak |external torque| against kuka_driver's freeze limits, and how far D moved over the
episode (``each_step``). Every figure comes from ``doorlab.episode.metrics.compute_metrics``.

Usage::

    python benchmarks/kuka_arm.py [--controllers ik velocity impedance adaptive]
        [--set KEY=VALUE ...] [--out benchmarks/results/kuka_arm.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

BENCH_DIR = Path(__file__).resolve().parent
PRESET = BENCH_DIR.parent / "examples" / "kuka_arm.yaml"
VARIANTS = ("grasp_pose", "each_step", "step_2ms")


def _scenario(controller: str, variant: str, overrides: list[str]):
    from doorlab.cli.commands import apply_overrides
    from doorlab.config import load_scenario, validate

    scenario = apply_overrides(load_scenario(PRESET), overrides)
    scenario.controller, scenario.doors = controller, "closed"
    if variant == "step_2ms":
        scenario.station.time_step = 0.002
    return validate(scenario)


def _each_step_episode(scenario):
    """The preset's episode with the joints' damping set from M_ii(q) before every plant step."""
    from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator

    from doorlab.cell.frames import ARM_JOINTS
    from doorlab.cell.station import make_controller_plant
    from doorlab.constants import Q_HOME
    from doorlab.episode.controllers import episode_plans
    from doorlab.episode.schedule import make_schedule
    from doorlab.episode.simulation import _result, build_simulated_episode
    from doorlab.kuka import CYCLE_PERIOD, kuka_damping

    plans, widths, arc = episode_plans(scenario)
    schedule = make_schedule(
        plans, widths, q_initial=Q_HOME, q_start=arc.q_start, scenario=scenario
    )
    episode = build_simulated_episode(scenario, schedule, q_initial=Q_HOME)
    simulator = Simulator(episode.diagram)
    h = scenario.station.time_step
    ResetIntegratorFromFlags(simulator, "explicit_euler", h)
    context = simulator.get_mutable_context()
    episode.arm.initialize(context, door_angles=scenario.initial_door_angles())
    simulator.Initialize()
    plant, iiwa = episode.station.plant, episode.station.iiwa
    plant_context = plant.GetMyMutableContextFromRoot(context)
    joints = [plant.GetJointByName(name, iiwa) for name in ARM_JOINTS]
    model = make_controller_plant()
    model_context = model.CreateDefaultContext()
    loop = scenario.station.inner_loop
    stiffness = np.asarray(loop.kuka_stiffness, float)
    unlock_at = CYCLE_PERIOD + episode.arm.offset + 1e-6
    dampings = []
    n_steps = int(math.ceil(episode.t_final / h - 1e-9))
    for n in range(n_steps + 1):
        model.SetPositions(model_context, plant.GetPositions(plant_context, iiwa))
        inertia = np.diag(model.CalcMassMatrix(model_context))
        damping = kuka_damping(stiffness, loop.kuka_damping, inertia) + h * stiffness
        dampings.append(damping)
        for joint, d in zip(joints, damping, strict=True):
            joint.SetDamping(plant_context, float(d))
        t_next = min((n + 0.5) * h, episode.t_final)
        if context.get_time() < unlock_at <= t_next:
            episode.commands.advance_to(simulator, unlock_at)
            episode.arm.unlock(context)
        episode.commands.advance_to(simulator, t_next)  # the plan runner's ticks on the way
    result, _ = _result(episode, simulator, scenario, 0.0, len(plans) + 1)
    return result, np.array(dampings)


def run_case(controller: str, variant: str, overrides: list[str]) -> dict:
    from doorlab.cell.geometry import true_door_geometry
    from doorlab.episode.controllers import run_controller
    from doorlab.episode.metrics import compute_metrics
    from doorlab.errors import RunStopped
    from doorlab.kuka import external_torque_limits

    scenario = _scenario(controller, variant, overrides)
    row = {"controller": controller, "variant": variant}
    try:
        if variant == "each_step":
            result, dampings = _each_step_episode(scenario)
            low, high = dampings.min(axis=0), dampings.max(axis=0)
            row["damping_range_Nms"] = [low.tolist(), high.tolist()]
        else:
            result, _ = run_controller(scenario)
    except RunStopped as e:
        return {**row, "status": e.status, "error": str(e)}
    metrics = compute_metrics(result, scenario, true_door_geometry(scenario))
    limits = external_torque_limits(scenario.station.driver.external_torque_limit)
    peak = np.max(np.abs(result.tau_external), axis=0)
    return {
        **row,
        "status": metrics.status,
        "door_arc_end_deg": math.degrees(metrics.door_opening_arc_end_rad),
        "max_radial_error_mm": 1e3 * metrics.max_radial_error_m,
        "handle_held": metrics.handle_held,
        "peak_external_torque_Nm": metrics.peak_external_torque_Nm,
        "peak_external_torque_over_freeze_limit": float(np.max(peak / limits)),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--controllers", nargs="+", default=["ik", "velocity", "impedance", "adaptive"]
    )
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    parser.add_argument("--out", type=Path, default=BENCH_DIR / "results" / "kuka_arm.json")
    args = parser.parse_args(argv)
    rows = []
    for controller in args.controllers:
        for variant in VARIANTS:
            row = run_case(controller, variant, args.overrides)
            rows.append(row)
            print(json.dumps(row), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"overrides": args.overrides, "rows": rows}, indent=2) + "\n")
    print("| controller | variant | status | door at arc end [deg] | max radial [mm] | held |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        door = r.get("door_arc_end_deg")
        radial = r.get("max_radial_error_mm")
        print(
            f"| {r['controller']} | {r['variant']} | {r['status']} | "
            f"{'' if door is None else f'{door:.2f}'} | "
            f"{'' if radial is None else f'{radial:.3f}'} | {r.get('handle_held', '')} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
