#!/usr/bin/env python3
"""What advancing an episode in chunks costs (issue 19), side by side with one AdvanceTo.

``doorlab.episode.simulation.advance_interruptibly`` calls ``Simulator.AdvanceTo`` every
``ADVANCE_CHUNK_S`` of simulated time, so that Python's signal handlers (Ctrl-C, SIGTERM)
run during an episode of C++ systems only (IK) or under real-time pacing. This script runs
the default 24 s episode of IK (10 knots) and of the velocity plan, doors closed, with the
chunks and with one call (``ADVANCE_CHUNK_S = inf``), alternating per repeat, and prints per
variant the median CPU time of the advance (``time.process_time``, which other processes on
a shared machine disturb far less than wall time), the ratio chunked / one call per repeat
(median), the longest stretch without a return to Python (the Ctrl-C latency), and checks
that the logs are bit-identical. On a loaded machine the CPU ratio scatters by tens of
percent either way; the robust figure is the fixed cost of one ``AdvanceTo`` call (timed over
2,000 calls that advance 1 ns each, after the episode) times the extra calls, against the
advance's CPU time.

Usage::

    python benchmarks/chunked_advance.py [--repeats N] [--out FILE.json]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

LOG_CHANNELS = (
    "t",
    "q_commanded",
    "q_measured",
    "v_measured",
    "tau_external",
    "tau_feedforward",
    "tau_commanded",
    "door_angles",
    "wsg_width",
    "plant_positions",
)


PROBE_CALLS = 2000
"""AdvanceTo calls over 1 ns each after an episode, timed to give the fixed cost of a call."""


def _timed_episode(controller: str, chunk: float, default: float) -> tuple[dict, float, object]:
    """One episode; (CPU s of the advance, its AdvanceTo calls and the fixed CPU s of one;
    the longest wall s between returns to Python; the result)."""
    import doorlab.episode.simulation as simulation
    from doorlab.config import Scenario
    from doorlab.episode.controllers import run_controller

    original = simulation.advance_interruptibly
    advance_to = simulation.Simulator.AdvanceTo
    measured = {}
    gaps = [0.0]

    def timed_advance(simulator, t_final, **kwargs):
        def step(self, t):  # one AdvanceTo: the time Python waits for C++
            start = time.perf_counter()
            advance_to(self, t)
            gaps.append(time.perf_counter() - start)

        simulator_type = type(simulator)
        simulator_type.AdvanceTo = step
        cpu = time.process_time()
        try:
            original(simulator, t_final, **kwargs)
        finally:
            simulator_type.AdvanceTo = advance_to
        measured["cpu"] = time.process_time() - cpu
        measured["calls"] = len(gaps) - 1
        # The fixed cost of one call: AdvanceTo over 1 ns (no event in it), many times.
        t, calls = t_final, PROBE_CALLS
        cpu = time.process_time()
        for k in range(1, calls + 1):
            advance_to(simulator, t + k * 1e-9)
        measured["per_call"] = (time.process_time() - cpu) / calls

    simulation.ADVANCE_CHUNK_S = chunk
    simulation.advance_interruptibly = timed_advance
    try:
        result, _ = run_controller(Scenario(controller=controller, doors="closed"))
    finally:
        simulation.advance_interruptibly = original
        simulation.ADVANCE_CHUNK_S = default
    return measured, max(gaps), result


def _load() -> float:
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error("--repeats must be >= 1")
    from doorlab.episode.simulation import ADVANCE_CHUNK_S as chunk

    report = {"load_before": _load(), "chunk_s": chunk, "controllers": {}}
    for controller in ("ik", "velocity"):
        _timed_episode(controller, chunk, chunk)  # warm-up: imports, caches
        rows = {"chunked": [], "one_call": [], "ratio": [], "gap_chunked": [], "gap_one": []}
        rows.update(calls=[], per_call_us=[], overhead=[])
        for _ in range(args.repeats):
            one_cpu, gap_one, one = _timed_episode(controller, math.inf, chunk)
            chunked_cpu, gap_chunked, chunked = _timed_episode(controller, chunk, chunk)
            for name in LOG_CHANNELS:
                if not np.array_equal(getattr(one, name), getattr(chunked, name)):
                    print(f"{controller}: log {name} differs between the variants")
                    return 1
            rows["one_call"].append(one_cpu["cpu"])
            rows["chunked"].append(chunked_cpu["cpu"])
            rows["ratio"].append(chunked_cpu["cpu"] / one_cpu["cpu"])
            rows["gap_chunked"].append(gap_chunked)
            rows["gap_one"].append(gap_one)
            rows["calls"].append(chunked_cpu["calls"])
            rows["per_call_us"].append(1e6 * chunked_cpu["per_call"])
            extra_calls = chunked_cpu["calls"] - one_cpu["calls"]
            rows["overhead"].append(extra_calls * chunked_cpu["per_call"] / one_cpu["cpu"])
        summary = {key: statistics.median(values) for key, values in rows.items()}
        summary["ratio_min"], summary["ratio_max"] = min(rows["ratio"]), max(rows["ratio"])
        summary["bit_identical"] = True
        report["controllers"][controller] = {"median": summary, "samples": rows}
        print(
            f"{controller:9s} advance CPU: one call {summary['one_call']:.3f} s, chunked "
            f"{summary['chunked']:.3f} s (ratio {summary['ratio']:.3f}, "
            f"[{summary['ratio_min']:.3f}, {summary['ratio_max']:.3f}]); "
            f"{summary['calls']:.0f} calls of {summary['per_call_us']:.1f} us fixed cost = "
            f"{100 * summary['overhead']:.3f} % of the advance; longest wait for C++: "
            f"one call {summary['gap_one']:.2f} s, chunked {1e3 * summary['gap_chunked']:.0f} "
            "ms; logs bit-identical"
        )
    report["load_after"] = _load()
    print(
        f"load average (1 min) before/after: {report['load_before']:.2f} / "
        f"{report['load_after']:.2f} on {os.cpu_count()} cores"
    )
    if args.out is not None:
        args.out.write_text(json.dumps(report, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
