"""Benchmark group ``episode/*``: whole episodes via ``run_controller``."""

from __future__ import annotations

import gc
import statistics
import time
from collections.abc import Sequence

from common import RTF_TARGET_OPEN, Context, CpuWatch, Metric, Settings


def bench_episodes(names: Sequence[str], settings: Settings, ctx: Context) -> list[Metric]:
    """All selected episodes, round-robin over the repeats (spreads slow phases evenly)."""
    from designs import advance_clock

    from doorlab import Scenario, run_controller

    ctx.warm()
    samples: dict[str, dict[str, list[float]]] = {
        n: {"sim_s": [], "rtf": [], "rtf_cpu": [], "e2e_s": []} for n in names
    }
    info: dict[str, dict] = {n: {} for n in names}
    watches = {n: [] for n in names}
    for _ in range(settings.repeats):
        for name in names:
            controller, doors = name.split("/", 1)[1].split("_")
            watch = CpuWatch()
            start = time.perf_counter()
            with advance_clock() as spent:
                result, _ = run_controller(Scenario(controller=controller, doors=doors))
            e2e = time.perf_counter() - start
            watches[name].append(watch.other_cores())
            s = samples[name]
            s["sim_s"].append(result.wall_time_s)
            s["rtf"].append(result.sim_time_s / result.wall_time_s)
            s["rtf_cpu"].append(result.sim_time_s / spent[1])
            s["e2e_s"].append(e2e)
            info[name] = {
                "sim_time_s": result.sim_time_s,
                "final_left_door_angle_rad": float(result.door_angles[-1, 0]),
            }
            print(
                f"  {name}: sim {result.wall_time_s:.2f} s "
                f"(RTF {result.sim_time_s / result.wall_time_s:.1f}), end to end {e2e:.2f} s",
                flush=True,
            )
            del result
            gc.collect()
    metrics = []
    for name in names:
        other = [w for w in watches[name] if w is not None]
        other_cores = statistics.mean(other) if other else None
        s = samples[name]
        metrics += [
            Metric(f"{name}/sim_s", name, "s", s["sim_s"], info=info[name]),
            Metric(
                f"{name}/rtf",
                name,
                "x",
                s["rtf"],
                better="higher",
                target=(">=", RTF_TARGET_OPEN) if name.endswith("_open") else None,
            ),
            Metric(f"{name}/rtf_cpu", name, "x", s["rtf_cpu"], better="higher"),
            Metric(f"{name}/e2e_s", name, "s", s["e2e_s"]),
        ]
        for m in metrics[-4:]:
            m.other_cpu_cores = other_cores
    return metrics
