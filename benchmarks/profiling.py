"""Benchmark ``profile/episode``: where one episode's time goes (the ticks, the plant's steps,
set-up; cProfile's top lines; a velocity command inside the episode, and the same command
repeated at once, on warm caches)."""

from __future__ import annotations

import os
import statistics
import sys
import time
from collections.abc import Callable

from common import REPO_DIR, Context, Metric, Settings


def bench_profile(settings: Settings, ctx: Context) -> tuple[list[Metric], dict]:
    """Split of one velocity/closed episode: ticks, plant step, setup; then cProfile."""
    import cProfile
    import io
    import pstats

    from doorlab import Scenario, run_controller
    from doorlab.control.plans import TaskSpaceVelocityPlan
    from doorlab.episode.plan_runner import PlanRunner

    ctx.warm()
    scenario = Scenario(controller="velocity", doors="closed")

    # 1. Unbiased split: a perf_counter around every tick (~1 us of overhead per tick).
    original = PlanRunner._tick
    spent = [0.0, 0]

    def timed_tick(self, *args):
        start = time.perf_counter()
        try:
            return original(self, *args)
        finally:
            spent[0] += time.perf_counter() - start
            spent[1] += 1

    # ... and one around the velocity plan's command, to compare a tick inside an episode
    # (caches shared with the plant step) with the isolated tick/velocity benchmark.
    original_command = TaskSpaceVelocityPlan.command
    commands: list[float] = []

    def timed_command(self, t, state):
        start = time.perf_counter_ns()
        try:
            return original_command(self, t, state)
        finally:
            commands.append((time.perf_counter_ns() - start) / 1e3)

    PlanRunner._tick = timed_tick
    TaskSpaceVelocityPlan.command = timed_command
    try:
        start = time.perf_counter()
        result, _ = run_controller(scenario)
        e2e = time.perf_counter() - start
    finally:
        PlanRunner._tick = original
        TaskSpaceVelocityPlan.command = original_command
    ticks_s, n_ticks = spent
    sim_s = result.wall_time_s
    plant_s = sim_s - ticks_s
    setup_s = e2e - sim_s

    # 2. cProfile (deterministic profiling inflates Python-heavy parts: shares are indicative).
    profiler = cProfile.Profile()
    start = time.perf_counter()
    profiler.enable()
    run_controller(scenario)
    profiler.disable()
    profiled_e2e = time.perf_counter() - start
    stats = pstats.Stats(profiler)

    def cumulative(match: Callable[[tuple], bool]) -> float:
        return sum(v[3] for k, v in stats.stats.items() if match(k))

    cp_ticks = cumulative(lambda k: k[2] == "_tick" and k[0].endswith("plan_runner.py"))
    cp_sim = cumulative(lambda k: k[0] == "~" and k[2].endswith(("AdvanceTo>", "Initialize>")))
    cp_named = {
        label: cumulative(lambda k, f=func: k[2] == f)
        for label, func in (
            ("grasp IK + plan (build_velocity_plan)", "build_velocity_plan"),
            ("controller plant (make_controller_plant)", "make_controller_plant"),
            ("station: parsing + diagram (build_station)", "build_station"),
            ("plan commands (every Plan.command)", "command"),
        )
    }
    text = io.StringIO()
    stats.stream = text
    stats.sort_stats("cumulative").print_stats(18)
    stats.sort_stats("tottime").print_stats(12)
    top = _trim_pstats(text.getvalue())

    # 3. The same command repeated at once inside the episode: the first call of a tick runs
    # on caches the plant's steps (and other processes) left cold, the repeat on warm ones.
    first, repeat = [], []

    def cold_then_warm(self, t, state):
        start = time.perf_counter_ns()
        result = original_command(self, t, state)
        middle = time.perf_counter_ns()
        original_command(self, t, state)  # same inputs, same plan context: the same result
        first.append((middle - start) / 1e3)
        repeat.append((time.perf_counter_ns() - middle) / 1e3)
        return result

    TaskSpaceVelocityPlan.command = cold_then_warm
    try:
        run_controller(scenario)
    finally:
        TaskSpaceVelocityPlan.command = original_command

    split = {
        "episode_e2e_s": e2e,
        "ticks_s": ticks_s,
        "ticks": n_ticks,
        "tick_mean_us": 1e6 * ticks_s / max(n_ticks, 1),
        "plant_step_s": plant_s,
        "setup_and_teardown_s": setup_s,
        "velocity_commands": len(commands),
        "velocity_command_median_us": statistics.median(commands) if commands else None,
        "velocity_command_first_median_us": statistics.median(first),
        "velocity_command_repeat_median_us": statistics.median(repeat),
        "cprofile": {
            "e2e_s": profiled_e2e,
            "ticks_s": cp_ticks,
            "plant_step_s": cp_sim - cp_ticks,
            "setup_and_teardown_s": profiled_e2e - cp_sim,
            "named_cumulative_s": cp_named,
        },
    }
    print(
        f"  profile/episode: e2e {e2e:.2f} s = ticks {ticks_s:.2f} s ({n_ticks} ticks, "
        f"{split['tick_mean_us']:.0f} us each) + plant step {plant_s:.2f} s "
        f"+ setup/teardown {setup_s:.2f} s",
        flush=True,
    )
    if commands:
        print(
            f"  velocity plan command inside the episode: median "
            f"{statistics.median(commands):.0f} us over {len(commands)} calls; repeated at "
            f"once in a tick: {statistics.median(first):.0f} us, then "
            f"{statistics.median(repeat):.0f} us",
            flush=True,
        )
    metrics = [
        Metric("profile/episode/ticks_s", "profile/episode", "s", [ticks_s]),
        Metric("profile/episode/plant_step_s", "profile/episode", "s", [plant_s]),
        Metric("profile/episode/setup_s", "profile/episode", "s", [setup_s]),
    ]
    if commands:
        metrics.append(
            Metric(
                "profile/episode/velocity_command_us",
                "profile/episode",
                "us",
                [statistics.median(commands)],
                info={"what": "median TaskSpaceVelocityPlan.command inside the episode"},
            )
        )
    return metrics, {"split": split, "top": top}


def _trim_pstats(text: str) -> str:
    """pstats output without its blank lines and with shortened paths."""
    lines = []
    for line in text.splitlines():
        if not line.strip():
            continue
        for prefix in sorted({str(REPO_DIR) + os.sep, sys.prefix + os.sep}, key=len, reverse=True):
            line = line.replace(prefix, "")
        lines.append(line.rstrip())
    return "\n".join(lines)
