#!/usr/bin/env python3
"""``doorlab identify`` on the simulated driver: the figures the real-arm guide's calibration
section quotes (docs/guides/real-arm.md, "The calibration: doorlab identify").

Usage::

    python benchmarks/identify.py [--lcm] [--out benchmarks/results/identify.json]

Variants (each the default script: ``--repeats 2``, all seven joints):

``truth`` (memq://, stepped, deterministic: tests/stepped_driver.py)
    The arm tests/test_identify.py's ``TRUTH`` describes (damping, stiction, load data,
    latency and noise 30 % or more off the preset's, which identify is not told): each
    estimate with its tolerance against the truth, the Coulomb friction, the effective
    inertia against the model's, the preset written, the CPU time; then each plan in one
    process on the identified preset against the true arm (the door at the arc's end, the
    status; the adaptive plan also with the noise set aside on both sides).
``preset`` (memq://)
    The arm preset as shipped (``examples/kuka_arm.yaml``: no friction, no noise, no latency
    beyond the cycle), the guide's rehearsal: the exit, the lines of the values kept, the
    estimates, the impedance plan's door under the identified preset against the preset's.
``short`` (memq://)
    The guide's shortened rehearsal, ``--joints 4,7 --repeats 1``: how long its motions take.
``lcm`` (``--lcm``; real time, about 4 min)
    The guide's rehearsal as a reader runs it: ``doorlab sim-driver --config
    examples/kuka_arm.yaml`` and ``doorlab identify --yes`` as two processes on loopback
    multicast (a port of its own; LCM's route must exist: in a fresh network namespace ``ip
    link set lo up; ip route add 224.0.0.0/4 dev lo``): wall time, exit, the lines kept,
    commands late and dropped, the host's load; the impedance door under its
    identified.yaml against the preset's. Both processes at real-time priority where it can
    be had (tests/realtime_priority.py), as a lab runs its arm's driver and client: on a
    shared host without it a descheduled client misses the 50 ms watchdog.
"""

from __future__ import annotations

import argparse
import copy
import datetime
import json
import math
import os
import platform
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

BENCH_DIR = Path(__file__).resolve().parent
REPO_DIR = BENCH_DIR.parent
PRESET = REPO_DIR / "examples" / "kuka_arm.yaml"
sys.path.insert(0, str(REPO_DIR / "tests"))  # the stepped driver and TRUTH of the tests

PLANS = ("ik", "velocity", "impedance", "adaptive")


def _door(scenario, controller: str, *, no_noise: bool = False) -> dict:
    """One plan in one process: its status and the door at the arc's end [deg]."""
    from doorlab.cell.geometry import true_door_geometry
    from doorlab.episode.controllers import run_controller
    from doorlab.episode.metrics import compute_metrics
    from doorlab.errors import RunStopped

    scenario = copy.deepcopy(scenario)
    scenario.controller = controller
    if no_noise:
        scenario.station.arm.external_torque_noise = [0.0] * 7
    try:
        result, _ = run_controller(scenario)
    except RunStopped as e:
        v = getattr(e, "violation", None)
        stop = None if v is None else {"limit": v.limit, "joint": int(v.joint) + 1, "t": v.t}
        return {"status": e.status, "door_deg": None, "stop": stop}
    metrics = compute_metrics(result, scenario, true_door_geometry(scenario))
    return {"status": metrics.status, "door_deg": math.degrees(metrics.door_opening_arc_end_rad)}


def _identify_memq(scenario_true, out: Path, settings=None) -> tuple[dict, float]:
    """identify against the stepped driver simulating ``scenario_true``: (summary, CPU s)."""
    from stepped_driver import SteppedDriver

    from doorlab.config import load_scenario
    from doorlab.hardware.identify.run import run_identify
    from doorlab.hardware.link import DriverLink

    load = _load()
    began = time.process_time()
    stepped = SteppedDriver(scenario_true)
    link = DriverLink(stepped.lcm, clock=stepped.clock, pump=stepped.pump)
    link.wait_first_status(1.0)
    outcome = run_identify(
        load_scenario(PRESET), out, link=link, wait=1.0, confirm=lambda _: True, settings=settings
    )
    cpu = time.process_time() - began
    summary = _summary(outcome, out)
    summary["load_average_before_after"] = [load, _load()]
    return summary, cpu


def _summary(outcome, out: Path) -> dict:
    """What a run of identify gave: exit, the lines kept, the estimates, the preset written."""
    from doorlab.config import load_scenario

    fits = json.loads((out / "fit.json").read_text())
    with np.load(out / "identify_log.npz") as log:
        statuses = len(log["q"])
    summary = {
        "status": outcome.status,
        "exit_code": outcome.exit_code,
        "statuses": statuses,
        "script_s": statuses * 0.005,
        "kept": list(outcome.kept),
        "fits": {
            k: fits.get(k)
            for k in (
                "load_mass",
                "external_torque_noise",
                "damping",
                "effective_inertia",
                "model_inertia_kg_m2",
                "stiction",
                "coulomb_friction",
                "latency",
                "latency_jitter",
                "nominal_damping_Nms",
                "stale_commands_dropped",
                "timed_step_latencies_s",
            )
        },
    }
    if (out / "identified.yaml").is_file():
        arm = load_scenario(out / "identified.yaml").station.arm
        summary["written"] = {
            "latency_s": arm.latency,
            "latency_jitter_s": arm.latency_jitter,
            "load_mass_kg": arm.load_mass,
            "stiction_Nm": list(arm.stiction),
            "coulomb_friction_Nm": list(arm.coulomb_friction),
            "external_torque_noise_Nm": list(arm.external_torque_noise),
        }
    return summary


def _recovery(summary: dict, truth) -> dict:
    """Each estimate against the truth: (value, truth, tolerance, |error| <= tolerance,
    tolerance / truth)."""
    from doorlab.cell.station import kuka_joint_damping

    fits = summary["fits"]
    arm = truth.station.arm
    h = truth.station.time_step
    rows = {}

    def row(name, entry, true):
        rows[name] = {
            "value": entry["value"],
            "truth": true,
            "tolerance": entry["tolerance"],
            "within": abs(entry["value"] - true) <= entry["tolerance"],
            "tolerance_share": entry["tolerance"] / abs(true) if true else None,
        }

    damping = kuka_joint_damping(truth.station.inner_loop)
    for j, entry in enumerate(fits["damping"].values()):
        row(f"damping_{j + 1}", entry, float(damping[j]))
    for j, entry in enumerate(fits["stiction"].values()):
        row(f"stiction_{j + 1}", entry, float(arm.stiction[j]))
    for j, entry in enumerate(fits["coulomb_friction"].values()):
        if entry is not None:
            row(f"coulomb_{j + 1}", entry, float(arm.coulomb_friction[j]))
    row("load_mass", fits["load_mass"], float(arm.load_mass))
    # the simulator realizes the arm's latency L as L - h/2 (identify.analysis)
    row("latency_as_simulated", fits["latency"], arm.latency - h / 2)
    row("latency_jitter", fits["latency_jitter"], arm.latency_jitter)
    for j, entry in enumerate(fits["external_torque_noise"].values()):
        row(f"noise_{j + 1}", entry, float(arm.external_torque_noise[j]))
    return rows


def _doors(identified_path: Path, true_scenario, plans) -> dict:
    from doorlab.config import load_scenario

    out = {}
    for plan in plans:
        found = _door(load_scenario(identified_path), plan)
        true = _door(true_scenario, plan)
        out[plan] = {"identified": found, "true": true}
        if plan == "adaptive":
            out["adaptive_no_noise"] = {
                "identified": _door(load_scenario(identified_path), plan, no_noise=True),
                "true": _door(true_scenario, plan, no_noise=True),
            }
    for row in out.values():
        a, b = row["identified"]["door_deg"], row["true"]["door_deg"]
        row["difference_deg"] = None if a is None or b is None else a - b
    return out


def truth_variant(tmp: Path) -> dict:
    from test_identify import truth

    summary, cpu = _identify_memq(truth(), tmp / "truth")
    summary["cpu_s"] = cpu
    summary["recovery"] = _recovery(summary, truth())
    summary["doors"] = _doors(tmp / "truth" / "identified.yaml", truth(), PLANS)
    return summary


def preset_variant(tmp: Path) -> dict:
    from doorlab.config import load_scenario

    summary, cpu = _identify_memq(load_scenario(PRESET), tmp / "preset")
    summary["cpu_s"] = cpu
    identified = tmp / "preset" / "identified.yaml"
    summary["doors"] = _doors(identified, load_scenario(PRESET), ("impedance",))
    return summary


def short_variant(tmp: Path) -> dict:
    """The guide's shortened rehearsal (``--joints 4,7 --repeats 1``) on the preset: how long
    its motions take (memq)."""
    from doorlab.config import load_scenario
    from doorlab.hardware.identify.script import ScriptSettings

    settings = ScriptSettings(joints=(3, 6), repeats=1)
    summary, cpu = _identify_memq(load_scenario(PRESET), tmp / "short", settings)
    summary["cpu_s"] = cpu
    summary["duration_estimate_s"] = settings.duration_estimate()
    return summary


def _load() -> float:
    return os.getloadavg()[0]


def lcm_variant(tmp: Path) -> dict:
    """The reader's rehearsal over loopback multicast (module docstring)."""
    import realtime_priority

    from doorlab.config import load_scenario

    url = f"udpm://239.255.76.67:{random.randrange(20000, 60000)}?ttl=0"
    doorlab = [sys.executable, "-m", "doorlab.cli"]
    preexec = realtime_priority.preexec()  # SCHED_FIFO where it can be had, as a lab runs
    out, gt = tmp / "lcm", tmp / "gt"
    load_before = _load()
    driver = subprocess.Popen(
        [*doorlab, "sim-driver", "--config", str(PRESET), "--lcm-url", url, "--out", str(gt)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=preexec,
    )
    try:
        began = time.monotonic()
        run = subprocess.run(
            [*doorlab, "identify", "--yes", "--wait", "60", "--lcm-url", url, "--out", str(out)],
            capture_output=True,
            text=True,
            timeout=900,
            preexec_fn=preexec,
        )
        wall = time.monotonic() - began
    finally:
        driver.send_signal(2)
        driver.communicate(timeout=60)
    facts = json.loads((gt / "driver.json").read_text()) if (gt / "driver.json").is_file() else {}
    fits = json.loads((out / "fit.json").read_text())
    summary = {
        "exit_code": run.returncode,
        "wall_s": wall,
        "stdout": run.stdout.splitlines(),
        "stderr_tail": run.stderr.splitlines()[-5:],
        "statuses": fits.get("statuses"),
        "stale_commands_dropped": fits.get("stale_commands_dropped"),
        "commands_late": facts.get("iiwa_commands_late"),
        "commands_applied": facts.get("iiwa_commands_applied"),
        "load_average_before_after": [load_before, _load()],
        "realtime_priority": realtime_priority.problem() or "SCHED_FIFO",
        "kept": fits.get("kept_from_preset"),
        "files": sorted(p.name for p in out.iterdir()),
    }
    if (out / "identified.yaml").is_file():
        summary["doors"] = _doors(out / "identified.yaml", load_scenario(PRESET), ("impedance",))
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lcm", action="store_true", help="also the rehearsal over LCM")
    parser.add_argument("--out", type=Path, default=BENCH_DIR / "results" / "identify.json")
    args = parser.parse_args(argv)
    result = {
        "date": datetime.datetime.now().isoformat(timespec="seconds"),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
    }
    with tempfile.TemporaryDirectory(prefix="doorlab_identify_bench_") as tmp:
        tmp = Path(tmp)
        result["preset"] = preset_variant(tmp)
        print("preset done", flush=True)
        result["short"] = short_variant(tmp)
        print("short done", flush=True)
        result["truth"] = truth_variant(tmp)
        print("truth done", flush=True)
        if args.lcm:
            result["lcm"] = lcm_variant(tmp)
            print("lcm done", flush=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
