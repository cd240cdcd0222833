#!/usr/bin/env python3
"""``doorlab run --hardware`` against ``doorlab sim-driver``: the link as the client sees it.

Usage::

    python benchmarks/hardware_client.py [--repeats 2] [--short] [--out FILE.json]

Variants, round-robin ``--repeats`` times, each a fresh ``doorlab sim-driver`` process and a
``doorlab run --hardware --yes`` process on a bus of their own
(``udpm://239.255.76.67:PORT?ttl=0``, a random port), doors closed: the ``velocity`` and the
``impedance`` plans (``--short``: the pre-arc phases shortened, a 5 s arc). From the client's
own records (``metrics.json``'s ``link``, measured by :mod:`doorlab.hardware.episode`):

- round trip: a command sent -> the first status whose ``joint_position_commanded`` reports
  it (commands equal to the one before are not counted: the hold) [ms];
- command interval: between consecutive commands (the jitter of the client's answers) [ms];
- answer: a status's arrival -> the command answering it (the client's own latency) [ms];
- status lateness: each status's arrival against the driver's clock, less the earliest's [ms].

And from ``/proc``: the CPU time of the client and of the driver over the client's run, as a
share of a core; the other processes' cores meanwhile (``/proc/stat``; the machine is shared)
and the load average at the end. Each figure is the median over the repeats.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH_DIR))
from common import CpuWatch, subprocess_env  # noqa: E402

LINK_KEYS = [
    f"{name}_{stat}_ms"
    for name in ("round_trip", "command_interval", "answer", "status_lateness")
    for stat in ("median", "p99", "max")
] + ["command_interval_std_ms"]
SHORT = [
    "timeline.hold_duration=0.5",
    "timeline.approach_duration=3.0",
    "timeline.grasp_duration=0.5",
    "timeline.arc_duration=5.0",
    "timeline.extra_time=0.5",
]


def _process_cpu_s(pid: int) -> float | None:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_once(controller: str, short: bool) -> dict:
    """One driver process, one client run; the client's link figures and both CPU shares."""
    url = f"udpm://239.255.76.67:{random.SystemRandom().randrange(20000, 60000)}?ttl=0"
    env = subprocess_env()
    doorlab = [sys.executable, "-m", "doorlab.cli"]
    driver = subprocess.Popen(
        [*doorlab, "sim-driver", "--lcm-url", url, "--doors", "closed"],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        with tempfile.TemporaryDirectory(prefix="doorlab-bench-hw-") as tmp:
            out = Path(tmp) / "run"
            command = [*doorlab, "run", "--hardware", "--yes", "--lcm-url", url]
            command += ["--controller", controller, "--out", str(out), "--no-replay"]
            command += ["--wait", "30"]
            for item in SHORT if short else []:
                command += ["--set", item]
            watch = CpuWatch()
            client = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, text=True)
            driver_cpu = _process_cpu_s(driver.pid)
            start = time.perf_counter()
            client_cpu = None
            while client.poll() is None:
                client_cpu = _process_cpu_s(client.pid) or client_cpu
                time.sleep(0.05)
            wall = time.perf_counter() - start
            driver_cpu = (_process_cpu_s(driver.pid) or 0.0) - (driver_cpu or 0.0)
            client.communicate()
            other = watch.other_cores()
            if client.returncode not in (0, 3, 4):  # ok, slipped, speed_limit: it ran through
                raise RuntimeError(f"doorlab run --hardware exited {client.returncode}")
            metrics = json.loads((out / "metrics.json").read_text())
    finally:
        driver.send_signal(signal.SIGTERM)
        driver.communicate(timeout=60)
    link = metrics["link"]
    return {
        **{key: link[key] for key in LINK_KEYS},
        "commands": link["commands"],
        "status": metrics["status"],
        "episode_s": metrics["duration_s"],
        "client_cpu_share": (client_cpu or 0.0) / wall,
        "driver_cpu_share": driver_cpu / wall,
        "other_cores": other,
        "load_average": os.getloadavg()[0],
    }


def _median(values: list[float]) -> float:
    values = sorted(v for v in values if v is not None)
    n = len(values)
    if not n:
        return float("nan")
    return values[n // 2] if n % 2 else 0.5 * (values[n // 2 - 1] + values[n // 2])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--short", action="store_true", help="a 14 s episode, 5 s arc")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    variants = ("velocity", "impedance")
    runs: dict[str, list[dict]] = {v: [] for v in variants}
    for _ in range(args.repeats):
        for variant in variants:
            runs[variant].append(run_once(variant, args.short))
            print(f"{variant}: {json.dumps(runs[variant][-1])}", file=sys.stderr, flush=True)
    keys = [k for k in runs[variants[0]][0] if k != "status"]
    summary = {v: {k: _median([r[k] for r in runs[v]]) for k in keys} for v in variants}
    print(f"| figure (median of {args.repeats}) | " + " | ".join(variants) + " |")
    print("|---|" + "---|" * len(variants))
    for key in keys:
        print(f"| {key} | " + " | ".join(f"{summary[v][key]:.3f}" for v in variants) + " |")
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    out = args.out or BENCH_DIR / "results" / f"hardware-client-{stamp}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    record = {
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "settings": {"repeats": args.repeats, "short": args.short},
        "summary": summary,
        "runs": runs,
    }
    out.write_text(json.dumps(record, indent=2) + "\n")
    print(f"wrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
