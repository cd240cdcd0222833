#!/usr/bin/env python3
"""Benchmark throughput: ``doorlab bench`` against ``doorlab sweep``, side by side in one run.

Usage::

    python benchmarks/bench_throughput.py [--episodes 16] [--repeats 3] [--jobs 2] [--short]
                                          [--out FILE.json]

Both run the same kind of episode: the velocity plan, the doors closed, the safety limits
checked at every tick (the benchmark's base), the cupboard's yaw error uniform in +-5 deg, the
hinge's damping log-uniform in [0.5, 4] N m s/rad and the fingers' friction uniform in
[0.6, 1.0], ``--episodes`` draws each (the same distribution, each its own draws: the sweep's
SPEC draws ``samples`` from its seed, the benchmark each episode from (seed, episode)).
Variants, run round-robin ``--repeats`` times, each the whole Python call with its outputs
written (the sweep's table and page, the benchmark's table, bench.json and card) into a
temporary folder, on ``--jobs`` local worker processes:

``sweep``
    :func:`doorlab.sweep.run_sweep` of the SPEC above.
``bench``
    :func:`doorlab.bench.run_bench` of the same distribution.

Reported per variant, medians over the repeats:

- episodes per CPU second: episodes / the CPU time of the whole call, this process and its
  worker processes (``getrusage``: the workers are reaped when the call returns); what a core
  of its own gives, whatever else runs on the machine: the figure the target is judged on
  (the sweep's over the benchmark's: at most 1.1);
- episodes per second per core from the wall clock (episodes / wall time / jobs), which the
  machine's load moves (a shared machine: see ``busy_cores``, the cores the whole machine
  kept busy meanwhile, from /proc/stat; above ``--jobs`` other processes competed);
- the median of the episodes' own cost (``run_wall_time_s``: one worker's wall seconds per
  episode, IK, simulation and metrics).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

from common import cpu_times, machine

BENCH_DIR = Path(__file__).resolve().parent
RESULTS_DIR = BENCH_DIR / "results"
SHORT_TIMELINE = {
    "arc_duration": 4.0,
    "approach_duration": 2.0,
    "hold_duration": 0.5,
    "extra_time": 0.5,
}
TARGET_RATIO = 1.1
"""The sweep's throughput per core over the benchmark's: at most this."""


def _cpu_seconds() -> float:
    """CPU seconds (user + system) of this process and its reaped children so far."""
    total = 0.0
    for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN):
        usage = resource.getrusage(who)
        total += usage.ru_utime + usage.ru_stime
    return total


def make_spec(episodes: int, short: bool):
    """The sweep: velocity, closed, yaw error, hinge damping and friction drawn."""
    from doorlab.sweep import parse_spec

    scenario: dict = {"station": {"safety": {"enabled": True}}}
    if short:
        scenario["timeline"] = SHORT_TIMELINE
    data = {
        "controllers": ["velocity"],
        "doors": ["closed"],
        "scenario": scenario,
        "axes": {
            "station.cupboard_yaw_error": {"low": -5.0, "high": 5.0, "unit": "deg"},
            "station.hinge_damping": {"low": 0.5, "high": 4.0, "log": True},
            "station.friction": {"low": 0.6, "high": 1.0},
        },
        "samples": episodes,
        "seed": 0,
    }
    return parse_spec(data)


def bench_arguments(short: bool) -> dict:
    """run_bench's distribution and base: the sweep's fields, nothing else drawn."""
    from doorlab.bench import BenchDistribution, bench_base
    from doorlab.config import Scenario

    base = Scenario()
    if short:
        for key, value in SHORT_TIMELINE.items():
            setattr(base.timeline, key, value)
    distribution = BenchDistribution(
        yaw_error_deg=5.0,
        position_error_mm=[0.0, 0.0, 0.0],
        hinge_damping=[0.5, 4.0],
        friction=[0.6, 1.0],
        grasp_offset_mm=[0.0, 0.0, 0.0],
    )
    return {"base": bench_base(base), "distribution": distribution}


def time_variant(name: str, episodes: int, jobs: int, short: bool, spec) -> dict:
    """Runs one variant into a temporary folder: wall time, throughput per core, the
    episodes' own median cost, statuses, busy cores."""
    before = cpu_times()
    cpu_before = _cpu_seconds()
    with tempfile.TemporaryDirectory(prefix="doorlab_bench_throughput_") as tmp:
        out = Path(tmp) / name
        start = time.perf_counter()
        if name == "sweep":
            from doorlab.sweep import run_sweep

            frame = run_sweep(spec, out, jobs=jobs)
        else:
            from doorlab.bench import run_bench

            frame = run_bench(
                ["velocity"], out, episodes=episodes, jobs=jobs, **bench_arguments(short)
            ).frame
        wall = time.perf_counter() - start
    cpu = _cpu_seconds() - cpu_before
    after = cpu_times()
    busy = None
    if before and after:
        share = (after[0] - before[0]) / max(after[1] - before[1], 1.0)
        busy = share * (os.cpu_count() or 1)
    return {
        "wall_s": wall,
        "episodes": len(frame),
        "cpu_s": cpu,
        "episodes_per_cpu_s": len(frame) / cpu,
        "episodes_per_s_per_core": len(frame) / wall / jobs,
        "episode_cost_median_s": float(frame["run_wall_time_s"].median()),
        "statuses": {str(k): int(v) for k, v in frame["status"].value_counts().items()},
        "busy_cores": busy,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=16, help="episodes (default 16)")
    parser.add_argument("--repeats", type=int, default=3, help="round-robin repeats (3)")
    parser.add_argument("--jobs", type=int, default=2, help="local worker processes (2)")
    parser.add_argument("--short", action="store_true", help="a 9 s episode, not 24 s")
    parser.add_argument("--out", type=Path, default=None, help="JSON file to write")
    args = parser.parse_args(argv)
    if args.episodes < 2 or args.repeats < 1 or args.jobs < 1:
        parser.error("--episodes must be >= 2, --repeats and --jobs >= 1")

    spec = make_spec(args.episodes, args.short)
    samples: dict[str, list[dict]] = {"sweep": [], "bench": []}
    for repeat in range(args.repeats):
        for name in samples:
            result = time_variant(name, args.episodes, args.jobs, args.short, spec)
            samples[name].append(result)
            print(
                f"[{repeat + 1}/{args.repeats}] {name}: {result['episodes_per_cpu_s']:.4f} "
                f"episodes per CPU second ({result['cpu_s']:.1f} CPU s); wall "
                f"{result['episodes_per_s_per_core']:.4f} episodes/s/core ({result['wall_s']:.1f}"
                f" s; episode cost median {result['episode_cost_median_s']:.2f} s; "
                f"{result['statuses']})",
                flush=True,
            )

    summary = {}
    for name, runs in samples.items():
        per_cpu = [r["episodes_per_cpu_s"] for r in runs]
        rates = [r["episodes_per_s_per_core"] for r in runs]
        costs = [r["episode_cost_median_s"] for r in runs]
        busy = [r["busy_cores"] for r in runs if r["busy_cores"] is not None]
        summary[name] = {
            "per_cpu_s_median": statistics.median(per_cpu),
            "per_cpu_s_min": min(per_cpu),
            "per_cpu_s_max": max(per_cpu),
            "median": statistics.median(rates),
            "min": min(rates),
            "max": max(rates),
            "episode_cost_median_s": statistics.median(costs),
            "busy_cores": statistics.median(busy) if busy else None,
        }
    ratio = summary["sweep"]["per_cpu_s_median"] / summary["bench"]["per_cpu_s_median"]
    wall_ratio = summary["sweep"]["median"] / summary["bench"]["median"]
    cost_ratio = (
        summary["bench"]["episode_cost_median_s"] / summary["sweep"]["episode_cost_median_s"]
    )
    print(
        f"\n{args.episodes} episodes ({'short' if args.short else 'full'}), {args.jobs} local "
        f"workers, {args.repeats} repeat(s), {os.cpu_count()} cores (shared: see busy cores)"
    )
    for name, s in summary.items():
        busy = f", busy cores {s['busy_cores']:.2f}" if s["busy_cores"] is not None else ""
        print(
            f"  {name:6s} {s['per_cpu_s_median']:.4f} episodes per CPU second (min "
            f"{s['per_cpu_s_min']:.4f}, max {s['per_cpu_s_max']:.4f}); wall "
            f"{s['median']:.4f} episodes/s/core (min {s['min']:.4f}, max {s['max']:.4f}); an "
            f"episode {s['episode_cost_median_s']:.2f} s of a worker{busy}"
        )
    verdict = "pass" if ratio <= TARGET_RATIO else "MISS"
    print(
        f"  sweep / bench episodes per CPU second: x{ratio:.3f} (target <= {TARGET_RATIO}: "
        f"{verdict}); from the wall clock x{wall_ratio:.3f}; bench / sweep episode cost: "
        f"x{cost_ratio:.3f}"
    )
    out = args.out or RESULTS_DIR / (
        f"bench-throughput-{datetime.datetime.now().strftime('%Y%m%d-%H%M%S')}.json"
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        json.dumps(
            {
                "machine": machine(),
                "settings": vars(args) | {"out": out.name},  # no one machine's path
                "samples": samples,
                "summary": summary,
                "sweep_over_bench_per_cpu_s": ratio,
                "sweep_over_bench_wall": wall_ratio,
                "bench_over_sweep_episode_cost": cost_ratio,
                "target": TARGET_RATIO,
            },
            indent=2,
        )
        + "\n"
    )
    print(f"  written to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
