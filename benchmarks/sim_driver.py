#!/usr/bin/env python3
"""``doorlab sim-driver``: its CPU share and real-time rate over an episode's length, and the
command -> status round trip and command jitter a simple Python client sees.

Usage::

    python benchmarks/sim_driver.py [--duration 24] [--repeats 2] [--out FILE.json]

Variants, run round-robin ``--repeats`` times, each a fresh driver process on a bus of its
own (``udpm://239.255.76.67:PORT?ttl=0``, a random port):

``paced``
    ``doorlab sim-driver --duration D`` (as a user runs it) with the client below answering
    every status.
``paced_idle``
    The same driver, the client listening only (no commands): what commands cost.
``no_tick``
    The paced driver and client, the driver without its read tick (the C++ ZeroOrderHold that
    starts a simulator step 1 us before each cycle's events, ``doorlab.hardware.sim_cell``):
    the bus is then read at the plant step before them, what the tick buys in timing.
``unpaced``
    ``SimDriver.run(duration=D, realtime_rate=0)`` with no client: the simulation's own cost
    of D seconds of the cell, the floor the paced CPU share is compared with.

The client (this process): a ``DrakeLcm`` handler that answers each ``IIWA_STATUS`` at once
with an ``IIWA_COMMAND`` (q_home, joint 1 offset by 1e-5 rad times the command's number, so
each command is recognisable; zero torque), after waiting 0.3 s out of the start guard.
Measured:

- driver CPU share: the driver process's CPU time (``/proc/PID/stat``, user + system) between
  the client's first and last status, over that wall time [cores];
- real-time rate: statuses sent (from utime) times 5 ms over the wall span they arrived in;
- commands late: of the commands the driver applied, how many it applied a cycle or more
  after the one following the status they answer (kuka_driver's timing), and the mean delay
  (``driver.json``: the drivers record their ground truth, ``--out``);
- round trip: from sending command k to receiving the first status whose
  ``joint_position_commanded`` reports it (median, p99, max) [ms]: applied at the next cycle,
  it shows in the status after that one;
- command interval: between consecutive commands sent (the client's jitter: median, std,
  p1, p99, max) [ms], and status intervals as received;
- the machine's load: other processes' cores while the variant ran (``/proc/stat``) and the
  load average at the end.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import random
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

BENCH_DIR = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH_DIR))
from common import CpuWatch, subprocess_env  # noqa: E402

NO_TICK_SCRIPT = """
import sys
import json
import doorlab.hardware.sim_cell as cell
from doorlab.hardware.sim_driver import SimDriver
cell._add_read_tick = lambda builder, offset: None  # the bus read at whatever step comes first
from doorlab.config import Scenario
driver = SimDriver(Scenario(), lcm_url=sys.argv[1], record=True)
print(driver.run(duration=float(sys.argv[2])), flush=True)
print("SUMMARY", json.dumps(driver.summary()), flush=True)
"""
UNPACED_SCRIPT = """
import sys, time
from doorlab.config import Scenario
from doorlab.hardware.sim_driver import SimDriver
driver = SimDriver(Scenario(), lcm_url=sys.argv[1])
cpu = time.process_time()
outcome = driver.run(duration=float(sys.argv[2]), realtime_rate=0.0)
print("CPU", time.process_time() - cpu, "WALL", outcome.wall_time_s, flush=True)
"""
VARIANTS = ("paced", "paced_idle", "no_tick", "unpaced")
STEP = 1e-5
"""The client's joint-1 offset per command [rad]."""


def _process_cpu_s(pid: int) -> float | None:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _url() -> str:
    return f"udpm://239.255.76.67:{random.SystemRandom().randrange(20000, 60000)}?ttl=0"


def _stats_ms(values: np.ndarray) -> dict:
    values = 1e3 * np.asarray(values, float)
    return {
        "median": float(np.median(values)),
        "std": float(np.std(values)),
        "p1": float(np.percentile(values, 1)),
        "p99": float(np.percentile(values, 99)),
        "max": float(values.max()),
    }


def run_client(variant: str, duration: float) -> dict:
    """One paced driver process and the answering client; returns the figures."""
    from drake import lcmt_iiwa_command, lcmt_iiwa_status
    from pydrake.lcm import DrakeLcm

    from doorlab.constants import Q_HOME

    url = _url()
    lcm = DrakeLcm(url)
    statuses: list[tuple[float, int, float]] = []  # (received, utime, commanded joint 1)
    sent: list[float] = []  # send time of command k (index k - 1)
    q = Q_HOME.copy()
    q[3] = -2.07  # inside the driver's 1 deg clamp: commands are applied as sent
    state = {"answer_from": None, "answer": variant != "paced_idle"}
    message = lcmt_iiwa_command()
    message.num_joints = 7
    message.num_torques = 7
    message.joint_torque = [0.0] * 7

    def handle(data: bytes) -> None:
        received = time.monotonic()
        status = lcmt_iiwa_status.decode(data)
        statuses.append((received, status.utime, status.joint_position_commanded[0]))
        if state["answer_from"] is None:
            state["answer_from"] = received + 0.3
        if state["answer"] and received >= state["answer_from"]:
            q[0] = STEP * (len(sent) + 1)
            message.utime = status.utime
            message.joint_position = list(q)
            lcm.Publish("IIWA_COMMAND", message.encode())
            sent.append(time.monotonic())

    lcm.Subscribe("IIWA_STATUS", handle)
    env = subprocess_env()
    scratch = Path(tempfile.mkdtemp(prefix="sim_driver_bench."))
    if variant in ("paced", "paced_idle"):
        command = [sys.executable, "-m", "doorlab.cli", "sim-driver", "--lcm-url", url]
        command += ["--duration", str(duration), "--out", str(scratch / "gt")]
    else:
        command = [sys.executable, "-c", NO_TICK_SCRIPT, url, str(duration)]
    watch = CpuWatch()
    driver = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    cpu_first = cpu_last = None
    try:
        deadline = time.monotonic() + 120
        while not statuses and time.monotonic() < deadline:
            lcm.HandleSubscriptions(5)
        cpu_first = _process_cpu_s(driver.pid)
        wall_first = time.monotonic()
        while driver.poll() is None:
            lcm.HandleSubscriptions(5)
            if statuses and statuses[-1][1] >= (duration - 0.05) * 1e6 and cpu_last is None:
                cpu_last, wall_last = _process_cpu_s(driver.pid), time.monotonic()
        out, err = driver.communicate(timeout=60)
    finally:
        if driver.poll() is None:
            driver.kill()
            driver.communicate()
    other = watch.other_cores()
    if driver.returncode != 0:
        raise RuntimeError(f"{variant}: the driver exited {driver.returncode}: {err[-300:]!r}")
    if (scratch / "gt" / "driver.json").is_file():
        facts = json.loads((scratch / "gt" / "driver.json").read_text())
    else:
        facts = json.loads(out.decode().split("SUMMARY", 1)[1])
    shutil.rmtree(scratch, ignore_errors=True)

    received = np.array([s[0] for s in statuses])
    utimes = np.array([s[1] for s in statuses])
    shown = np.array([round(s[2] / STEP) for s in statuses])
    sent_t = np.array(sent)
    round_trips = []
    for k in range(1, len(sent_t) + 1):  # first status reporting command k (or a newer one)
        i = np.searchsorted(shown, k)
        if i < len(shown) and received[i] > sent_t[k - 1]:
            round_trips.append(received[i] - sent_t[k - 1])
    span = received[-1] - received[0]
    return {
        "variant": variant,
        "statuses_received": len(statuses),
        "statuses_sent": int(utimes[-1] // 5000 + 1),
        "commands_sent": len(sent),
        "commands_applied": facts["iiwa_commands_applied"],
        "commands_late": facts["iiwa_commands_late"],
        "command_delay_mean_ms": 1e3 * (facts["iiwa_command_delay_mean_s"] or 0.0),
        "realtime_rate": float((utimes[-1] - utimes[0]) * 1e-6 / span),
        "status_rate_hz": float((utimes[-1] - utimes[0]) / 5000 / span),
        "driver_cpu_share": (
            (cpu_last - cpu_first) / (wall_last - wall_first)
            if cpu_first is not None and cpu_last is not None
            else None
        ),
        "round_trip_ms": _stats_ms(round_trips) if round_trips else None,
        "command_interval_ms": _stats_ms(np.diff(sent_t)) if len(sent_t) > 1 else None,
        "status_interval_ms": _stats_ms(np.diff(received)),
        "other_cores": other,
        "loadavg": os.getloadavg()[0],
    }


def run_unpaced(duration: float) -> dict:
    watch = CpuWatch()
    result = subprocess.run(
        [sys.executable, "-c", UNPACED_SCRIPT, _url(), str(duration)],
        env=subprocess_env(),
        capture_output=True,
        text=True,
        check=True,
    )
    words = result.stdout.split()
    cpu, wall = float(words[words.index("CPU") + 1]), float(words[words.index("WALL") + 1])
    return {
        "variant": "unpaced",
        "cpu_s": cpu,
        "wall_s": wall,
        "cpu_per_sim_s": cpu / duration,
        "other_cores": watch.other_cores(),
        "loadavg": os.getloadavg()[0],
    }


def _median(runs: list[dict], *keys: str) -> float:
    values = []
    for run in runs:
        value = run
        for key in keys:
            value = value.get(key) if value is not None else None
        values.append(np.nan if value is None else value)
    return float(np.median(values))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=24.0, help="seconds per run (24)")
    parser.add_argument("--repeats", type=int, default=2, help="rounds of the variants (2)")
    parser.add_argument("--out", type=Path, default=BENCH_DIR / "results" / "sim_driver.json")
    args = parser.parse_args(argv)
    runs: list[dict] = []
    for repeat in range(args.repeats):
        for variant in VARIANTS:
            run = run_unpaced(args.duration) if variant == "unpaced" else None
            run = run or run_client(variant, args.duration)
            run["repeat"] = repeat
            if run.get("commands_applied"):
                run["late_fraction"] = run["commands_late"] / run["commands_applied"]
            runs.append(run)
            print(json.dumps(run), flush=True)
    by = {v: [r for r in runs if r["variant"] == v] for v in VARIANTS}
    busy = ", ".join(f"{r['other_cores']:.2f}" for r in runs if r["other_cores"] is not None)
    print(f"\n{args.repeats} repeats of {args.duration:g} s, medians (other cores busy: {busy})")
    print(
        "| variant | CPU share [cores] | real-time rate | status Hz | commands late [%] / mean "
        "delay [ms] | round trip median / p99 / max [ms] | command interval median / std / p1 "
        "/ p99 / max [ms] | status interval (same) [ms] |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for variant in ("paced", "paced_idle", "no_tick"):
        group = by[variant]
        rt = [_median(group, "round_trip_ms", k) for k in ("median", "p99", "max")]
        ci = [
            _median(group, "command_interval_ms", k) for k in ("median", "std", "p1", "p99", "max")
        ]
        si = [
            _median(group, "status_interval_ms", k) for k in ("median", "std", "p1", "p99", "max")
        ]
        print(
            f"| {variant} | {_median(group, 'driver_cpu_share'):.3f} | "
            f"{_median(group, 'realtime_rate'):.4f} | {_median(group, 'status_rate_hz'):.2f} | "
            f"{100 * _median(group, 'late_fraction'):.1f} / "
            f"{_median(group, 'command_delay_mean_ms'):.2f} | "
            + " / ".join(f"{v:.2f}" for v in rt)
            + " | "
            + " / ".join(f"{v:.2f}" for v in ci)
            + " | "
            + " / ".join(f"{v:.2f}" for v in si)
            + " |"
        )
    unpaced = _median(by["unpaced"], "cpu_per_sim_s")
    print(
        f"| unpaced (no client, as fast as possible) | {unpaced:.3f} CPU s per simulated s | "
        f"{args.duration / _median(by['unpaced'], 'wall_s'):.1f} | | | | | |"
    )
    summary = {
        "date": datetime.datetime.now().isoformat(timespec="seconds"),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "duration_s": args.duration,
        "repeats": args.repeats,
        "runs": runs,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(summary, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
