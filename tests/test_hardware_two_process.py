"""``doorlab sim-driver`` and ``doorlab run --hardware`` as two processes on loopback multicast
(a port of each test's own, tests/lcm_fixtures.py), in real time: the velocity and impedance
plans on the arm preset against the same episode in one process (test_hardware_faults.py: a
client slower than the period, and the ways such a run stops).

kuka_driver's cycle makes the episode independent of the client's speed: a command that
answers status k and reaches the driver before cycle k + 1 acts from cycle k + 1, exactly as
in a one-process run with the same preset (``examples/kuka_arm.yaml``, on both sides). So
with the client's answers held back (the test-only knob ``DOORLAB_TEST_ANSWER_DELAY_MS``: each
command leaves that long after its status arrived) by 0 or 3 ms (the latest a client
answers with the host's scheduling on top still within the 5 ms cycle), the episode is the
one-process run's: the door at the arc's end within 0.05 deg and Q's max radial error within
0.01 mm (with no command late it is the same bit for bit, as on memq: test_hardware_wiring.py;
here the host makes a few late: docs/guides/real-arm.md, "A rehearsal on one machine").

Q's radial error and the door are taken from the driver's ground truth (each 5 ms status's
joint positions, the hinge at the same instant) and from the one-process run's per-cycle log
at the same instants, through the same kinematics.

A loaded host (2 cores, shared) can make a client miss a cycle without the knob: a status or
its answer descheduled for milliseconds. A run whose episode differs from the one-process
run's, with late commands that the host explains (the client's slowest answer plus the
latest status came within 0.5 ms of the period, or the host dropped a stale answer, or the
driver fell behind real time) is skipped with those measurements; late commands the host
does not explain, or a different episode with no late command, fail.

The timelines are short (hold 0.2 s, move 2 s with the position-gap limit relaxed to 80 ms,
grasp 0.5 s, arc 3 s, no extra time): what is compared is the arc's, and each real-time run
costs a worker 12 s of wall time. The two delays bracket the period's first 3 ms; a delay
between them (1.5 ms, run here until issue 42) tells nothing the two do not: each command
reaches the driver before the next cycle or it does not. Each plan runs once, the velocity
plan's positions with no delay and the impedance plan's torques and positions with the 3 ms
one: the delay acts on the link (when a command reaches the driver), which both plans' commands
cross alike, so the two runs cover each plan and each delay (the four pairs, run here until
issue 42, all passed alike).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from lcm_fixtures import (  # noqa: F401
    BusListener,
    lcm_url,
    multicast_route,
    paced_cli,
    sim_driver_process,
    stop,
)

from doorlab.config import Scenario, load_scenario, validate
from doorlab.episode.result import EpisodeResult
from doorlab.hardware.ground_truth import GROUND_TRUTH_FILE, GroundTruth

PRESET = Path(__file__).resolve().parents[1] / "examples" / "kuka_arm.yaml"
ARM_TIMELINE = [
    "timeline.hold_duration=0.2",
    "timeline.approach_duration=2.0",
    "station.safety.gap_time=0.08",
    "timeline.grasp_duration=0.5",
    "timeline.arc_duration=3.0",
    "timeline.extra_time=0.0",
    "timeline.log_period=0.005",
]
DOOR_TOLERANCE = 0.05  # [deg] the bound
RADIAL_TOLERANCE = 1e-5  # [m] the bound (0.01 mm)
PERIOD_MS = 5.0
HOST_MARGIN_MS = 0.5  # a client answer this close to the period may miss it on a busy host


def arm_scenario(controller: str) -> Scenario:
    from doorlab.cli.commands import apply_overrides

    s = apply_overrides(load_scenario(PRESET), ARM_TIMELINE)
    s.controller, s.doors = controller, "closed"
    return validate(s)


_ONE_PROCESS: dict[str, EpisodeResult] = {}


def one_process(controller: str, heavy) -> EpisodeResult:
    """The one-process run with the same preset and timeline (once per controller), through
    ``heavy`` (conftest's: a simulation running flat out, at idle priority beside other
    workers' real-time sections)."""
    if controller not in _ONE_PROCESS:
        from doorlab.episode.controllers import run_controller

        _ONE_PROCESS[controller], _ = heavy(lambda: run_controller(arm_scenario(controller)))
    return _ONE_PROCESS[controller]


def arc_figures(t: np.ndarray, q: np.ndarray, door: np.ndarray, window, s: Scenario):
    """(Q's max |radial error| over the arc [m], the left door opened at the arc's end [rad])
    from per-cycle joint positions q and hinge angles ``door`` at times t (episode time)."""
    from doorlab.cell.frames import p_L7Q
    from doorlab.cell.geometry import true_door_geometry
    from doorlab.episode.metrics import Kinematics

    inside = (t >= window[0] - 1e-6) & (t <= window[1] + 1e-6)
    poses = Kinematics().poses(q[inside])
    radial = true_door_geometry(s).radial_error(np.array([X @ p_L7Q for X in poses]))
    i_end = int(np.argmin(np.abs(t - window[1])))
    assert abs(t[i_end] - window[1]) < 1e-6
    return float(np.max(np.abs(radial))), float(door[0] - door[i_end])


def run_arm_pair(url: str, tmp: Path, controller: str, delay_ms: float, realtime):
    """The driver and the client with the preset, the client's answers held ``delay_ms``.

    Returns (client exit code, its stderr, metrics.json, driver.json, the ground truth, the
    client's log)."""
    sets = [a for s in ARM_TIMELINE for a in ("--set", s)]
    config = ["--config", str(PRESET)]
    gt_dir, out = tmp / "gt", tmp / "run"
    env = {**os.environ, "DOORLAB_TEST_ANSWER_DELAY_MS": f"{delay_ms:g}"}
    with realtime(), sim_driver_process(url, "--doors", "closed", *config, *sets, out=gt_dir) as d:
        command = ["run", "--hardware", "--yes", "--wait", "60", "--lcm-url", url]
        command += ["--controller", controller, "--out", str(out), "--no-replay", *config, *sets]
        run = paced_cli(command, env)
        stdout, stderr = run.communicate(timeout=180)
        code, _, driver_err = stop(d)
        assert code == 143, driver_err
    if run.returncode != 0:
        return run.returncode, stdout + stderr, None, None, None, None
    metrics = json.loads((out / "metrics.json").read_text())
    facts = json.loads((gt_dir / "driver.json").read_text())
    gt = GroundTruth.load(gt_dir / GROUND_TRUTH_FILE)
    return 0, stderr, metrics, facts, gt, EpisodeResult.load(out / "log.npz")


def host_explains(metrics: dict, facts: dict, delay_ms: float) -> tuple[bool, str]:
    """Whether the host, not the product, can explain commands missing their cycle."""
    link = metrics["link"]
    slowest = link["answer_max_ms"] + link["status_lateness_max_ms"]
    measured = (
        f"client answers median {link['answer_median_ms']:.2f} ms, max {link['answer_max_ms']:.2f}"
        f" ms (held {delay_ms:g} ms), statuses up to {link['status_lateness_max_ms']:.2f} ms "
        f"late, {link['stale_commands_dropped']} stale answers dropped, {link['statuses']} "
        f"statuses / {link['commands']} commands; driver real-time rate "
        f"{facts['realtime_rate']:.4f}, {facts['iiwa_commands_late']} of "
        f"{facts['iiwa_commands_applied']} commands late (up to "
        f"{facts['iiwa_command_cycles_late_max']} cycles), "
        f"{facts['iiwa_commands_superseded']} superseded"
    )
    explained = (
        slowest >= PERIOD_MS - HOST_MARGIN_MS
        or link["stale_commands_dropped"] > 0
        or facts["realtime_rate"] < 0.999
    )
    return explained, measured


def compare(controller: str, reference: EpisodeResult, gt: GroundTruth, log: EpisodeResult):
    """(door difference [deg], radial difference [m], door two-process [deg]) against the
    one-process run ``reference``, from per-cycle positions on both sides."""
    s = arm_scenario(controller)
    window = reference.arc_window
    cycles = reference.cycle_log
    radial_one, door_one = arc_figures(
        cycles["t"], cycles["q_measured"], cycles["door_angles"][:, 0], window, s
    )
    t0 = log.status_time[0]  # the client's t = 0 on the driver's clock
    radial_two, door_two = arc_figures(gt.t - t0, gt.q_measured, gt.door_angles[:, 0], window, s)
    return (
        math.degrees(door_two - door_one),
        radial_two - radial_one,
        math.degrees(door_two),
        math.degrees(door_one),
    )


@pytest.mark.slow
@pytest.mark.parametrize(
    ("controller", "delay_ms"),
    [("velocity", 0.0), ("impedance", 3.0)],
)
def test_any_client_within_the_period_gets_the_same_episode(
    realtime,
    heavy,
    lcm_url,  # noqa: F811
    tmp_path,
    controller,
    delay_ms,
):
    """With the arm preset on both sides and the answers held 0 or 3 ms: no command
    late, the door at the arc's end within 0.05 deg and Q's max radial error within 0.01 mm
    of the one-process run (module docstring: a host that could not keep real time skips)."""
    reference = one_process(controller, heavy)  # before the real-time section
    code, stderr, metrics, facts, gt, log = run_arm_pair(
        lcm_url, tmp_path, controller, delay_ms, realtime
    )
    if code == 7:  # the client's watchdog: statuses missing for 50 ms
        pytest.skip(f"the host did not keep real time: {stderr.strip()}")
    assert code == 0, stderr
    door, radial, door_two, door_one = compare(controller, reference, gt, log)
    explained, measured = host_explains(metrics, facts, delay_ms)
    print(
        f"{controller}, answers held {delay_ms:g} ms: door {door_two:.3f} deg at the arc's end "
        f"({door:+.5f} against one process), max radial error {radial * 1e6:+.4f} um; {measured}"
    )
    same = abs(door) <= DOOR_TOLERANCE and abs(radial) <= RADIAL_TOLERANCE
    if facts["iiwa_commands_late"] == 0:
        assert same, (door, radial, measured)
        return
    if same:
        return  # a few late commands, the same episode within the bounds
    if explained:
        pytest.skip(f"the host could not keep real time ({measured}); door {door:+.3f} deg")
    pytest.fail(f"late commands the host does not explain: {measured}; door {door:+.3f} deg")
