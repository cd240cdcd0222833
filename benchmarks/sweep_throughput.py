#!/usr/bin/env python3
"""Sweep throughput: episodes per minute of a 16-run sweep, local processes vs a Dask cluster.

Usage::

    python benchmarks/sweep_throughput.py [--runs 16] [--repeats N] [--short] [--out FILE.json]

The sweep: the impedance plan, doors closed, ``impedance.kv`` over ``--runs`` values from 60
to 210 N/m (runs of similar cost). Variants, run round-robin ``--repeats`` times:

``local_1``
    :func:`doorlab.sweep.run_sweep` with 1 local worker process (spawned).
``local_2``
    2 local worker processes.
``dask_2``
    A Dask ``LocalCluster`` on loopback (2 worker processes, 1 thread each), through
    ``scheduler=tcp://127.0.0.1:PORT``. The cluster is started once, before the timings
    (a lab's cluster is already up); its start time is reported separately.

Each variant's wall time covers the whole ``run_sweep`` call (executor start, every run, the
table; no page). Reported: the MEDIAN episodes per minute (runs / wall time * 60), min and max,
and the Dask overhead against ``local_2`` (1 - dask / local_2 throughput; target <= 5 %). The
machine may be shared: ``busy_cores`` is the average number of cores the whole machine kept
busy during each variant (from /proc/stat); above the variant's own worker count, other
processes competed and the timing is noisy.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
import sys
import time
from pathlib import Path

from common import cpu_times, machine

BENCH_DIR = Path(__file__).resolve().parent
RESULTS_DIR = BENCH_DIR / "results"
SHORT_TIMELINE = {
    "arc_duration": 2.0,
    "approach_duration": 2.0,
    "hold_duration": 0.5,
    "extra_time": 0.5,
}
TARGET_OVERHEAD = 0.05


def make_spec(runs: int, short: bool):
    from doorlab.sweep import parse_spec

    data = {
        "controllers": ["impedance"],
        "doors": ["closed"],
        "axes": {"impedance.kv": {"low": 60.0, "high": 210.0, "num": runs}},
    }
    if short:
        data["scenario"] = {"timeline": SHORT_TIMELINE}
    return parse_spec(data)


def time_variant(spec, *, jobs: int = 1, scheduler: str | None = None) -> dict:
    """Runs the sweep once: wall time, throughput, statuses, and the cores the whole machine
    kept busy meanwhile (``busy_cores``; a variant using 2 workers on an idle 2-core machine
    shows ~2: more means other processes competed)."""
    from doorlab.sweep import run_sweep

    before = cpu_times()
    start = time.perf_counter()
    frame = run_sweep(spec, None, jobs=jobs, scheduler=scheduler)
    wall = time.perf_counter() - start
    after = cpu_times()
    busy = None
    if before and after:
        share = (after[0] - before[0]) / max(after[1] - before[1], 1.0)
        busy = share * (os.cpu_count() or 1)
    return {
        "wall_s": wall,
        "episodes_per_min": len(frame) / wall * 60.0,
        "statuses": {str(k): int(v) for k, v in frame["status"].value_counts().items()},
        "busy_cores": busy,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=16, help="runs in the sweep (default 16)")
    parser.add_argument("--repeats", type=int, default=1, help="round-robin repeats")
    parser.add_argument("--short", action="store_true", help="short episodes (~10 s simulated)")
    parser.add_argument("--out", type=Path, default=None, help="JSON file to write")
    args = parser.parse_args(argv)
    if args.runs < 2 or args.repeats < 1:
        parser.error("--runs must be >= 2 and --repeats >= 1")

    from distributed import LocalCluster

    spec = make_spec(args.runs, args.short)
    start = time.perf_counter()
    cluster = LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        silence_logs=40,
    )
    cluster_start = time.perf_counter() - start
    samples: dict[str, list[dict]] = {"local_1": [], "local_2": [], "dask_2": []}
    try:
        for repeat in range(args.repeats):
            for name in samples:
                if name == "dask_2":
                    result = time_variant(spec, scheduler=cluster.scheduler_address)
                else:
                    result = time_variant(spec, jobs=int(name[-1]))
                samples[name].append(result)
                print(
                    f"[{repeat + 1}/{args.repeats}] {name}: {result['episodes_per_min']:.2f} "
                    f"episodes/min ({result['wall_s']:.1f} s, {result['statuses']})",
                    flush=True,
                )
    finally:
        cluster.close()

    summary = {}
    for name, runs in samples.items():
        rates = [r["episodes_per_min"] for r in runs]
        summary[name] = {"median": statistics.median(rates), "min": min(rates), "max": max(rates)}
    overhead = 1.0 - summary["dask_2"]["median"] / summary["local_2"]["median"]
    print(
        f"\n{args.runs}-run sweep ({'short' if args.short else 'full'} episodes), "
        f"{args.repeats} repeat(s), {os.cpu_count()} cores (shared machine: see busy cores)"
    )
    for name, s in summary.items():
        busy = [r["busy_cores"] for r in samples[name] if r["busy_cores"] is not None]
        shown = f", busy cores {statistics.median(busy):.2f}" if busy else ""
        print(
            f"  {name:8s} {s['median']:6.2f} episodes/min (min {s['min']:.2f}, "
            f"max {s['max']:.2f}{shown})"
        )
    print(f"  Dask LocalCluster start {cluster_start:.1f} s (not in the timings)")
    verdict = "pass" if overhead <= TARGET_OVERHEAD else "MISS"
    print(
        f"  Dask overhead vs 2 local processes: {100 * overhead:+.1f} % "
        f"(target <= {100 * TARGET_OVERHEAD:.0f} %: {verdict})"
    )
    speedup = summary["local_2"]["median"] / summary["local_1"]["median"]
    print(f"  2 vs 1 local processes: x{speedup:.2f}")

    out = args.out or RESULTS_DIR / (
        f"sweep-{datetime.datetime.now().strftime('%Y%m%d-%H%M%S')}.json"
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        json.dumps(
            {
                "machine": machine(),
                "settings": {"runs": args.runs, "repeats": args.repeats, "short": args.short},
                "cluster_start_s": cluster_start,
                "samples": samples,
                "summary": summary,
                "dask_overhead": overhead,
            },
            indent=2,
        )
        + "\n"
    )
    print(f"  written to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
