"""``doorlab run --hardware``: one controller on the real arm, into the same run folder.

The order of things: wait for the driver (``--wait``; none: exit 7, nothing written), build
the plans (IK), print the plan and ask for confirmation (``--yes`` skips the question), run
the episode (:mod:`doorlab.hardware.episode`), write the folder. A run that completes writes
what a simulated run writes (``log.npz``, ``metrics.json``, ``scenario.yaml``, the plots and
``replay.html``, of the measured arm). A stopped run (``driver_lost``, ``safety_stop``,
``interrupted``) writes ``log.npz``, ``metrics.json`` and ``scenario.yaml`` with what was
logged up to the stop, and no plots or replay, so that the process ends at once.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from doorlab.cell.frames import ARM_JOINTS, p_L7Q
from doorlab.cell.geometry import true_door_geometry
from doorlab.config import Scenario, validate
from doorlab.episode.metrics import Kinematics
from doorlab.episode.plugins import display_name
from doorlab.episode.schedule import PLAN_SETTLE_TIME
from doorlab.errors import IkError, interrupt_exit_code
from doorlab.hardware.episode import HardwareOutcome, run_hardware_episode
from doorlab.hardware.link import DriverLink, Status
from doorlab.hardware.metrics import HardwareMetrics, compute_hardware_metrics
from doorlab.outputs.runs import EXIT_CODES
from doorlab.runtime.folders import (
    check_replaceable,
    commit_output,
    discard_output,
    prepare_output,
    write_json,
)


@dataclass(frozen=True)
class HardwareRunOutcome:
    """What ``doorlab run --hardware`` did.

    Attributes:
        status: The run's status (``ok``, ``slipped``, ``speed_limit``, ``driver_lost``,
            ``safety_stop``, ``interrupted``, ``ik_failed``, ``declined``).
        exit_code: The process's exit code.
        out_dir: The folder written (None when nothing was).
        metrics: The figures (None when the arm did not move).
        message: Why it stopped ("" when it did not).
    """

    status: str
    exit_code: int
    out_dir: Path | None
    metrics: HardwareMetrics | None
    message: str


def describe_plan(scenario: Scenario, q_start: np.ndarray, status: Status, url: str) -> str:
    """What the arm is about to do: controller, doors, duration, the distance to the start."""
    timeline = scenario.timeline
    phases = [
        ("hold", timeline.hold_duration),
        ("move", timeline.approach_duration),
        ("grasp", timeline.grasp_duration),
        ("arc", timeline.arc_duration),
    ]
    total = sum(d + PLAN_SETTLE_TIME for _, d in phases) + timeline.extra_time
    parts = ", ".join(f"{name} {d + PLAN_SETTLE_TIME:g}" for name, d in phases)
    dq = np.asarray(q_start) - status.q
    joint = int(np.argmax(np.abs(dq)))
    kinematics = Kinematics()
    X_now, X_start = kinematics.poses(np.vstack([status.q, q_start]))
    dQ = float(np.linalg.norm(X_start @ p_L7Q - X_now @ p_L7Q))
    safety = scenario.station.safety
    knots = f" ({scenario.ik.knots} knots)" if scenario.controller == "ik" else ""
    rows = [
        ("controller / doors", f"{display_name(scenario.controller)}{knots} / {scenario.doors}"),
        ("duration", f"{total:g} s ({parts}, extra {timeline.extra_time:g} s)"),
        (
            "start pose",
            f"{math.degrees(abs(dq[joint])):.1f} deg away ({ARM_JOINTS[joint]}); "
            f"Q moves {dQ:.3f} m there in {timeline.approach_duration:g} s",
        ),
        ("arm now", "q = [" + ", ".join(f"{v:.3f}" for v in status.q) + "] rad"),
        ("driver", f"IIWA_STATUS on {url}"),
        (
            "safety",
            f"joint limits less {math.degrees(safety.joint_limit_margin):.1f} deg, "
            f"|q_ref - q| <= speed limit x {1e3 * safety.gap_time:g} ms, joint speed <= "
            f"{safety.speed_fraction:g} x, |tau_ff| <= {safety.torque_fraction:g} x the data "
            "sheet's; watchdog 50 ms",
        ),
    ]
    lines = ["doorlab run --hardware: the plan"]
    lines += [f"  {name:<20}{value}" for name, value in rows]
    return "\n".join(lines)


def check_out_dir(out_dir: Path, *, force: bool) -> None:
    """Refuses an ``out_dir`` that may not be written
    (:func:`doorlab.runtime.folders.check_replaceable`: exists without ``force``, or holds a file
    doorlab did not write) before anything waits or moves;
    :func:`doorlab.runtime.folders.prepare_output` checks again when the folder is made."""
    check_replaceable(out_dir, force=force)


def run_hardware_to_folder(
    scenario: Scenario,
    out_dir: Path,
    *,
    link: DriverLink,
    wait: float,
    confirm: Callable[[str], bool],
    force: bool = False,
    replay: bool = True,
    plots: bool = True,
    first: Status | None = None,
    answer_delay: float = 0.0,
) -> HardwareRunOutcome:
    """Runs ``scenario``'s controller on the real cell behind ``link`` and writes its folder.

    Args:
        scenario: The run (validated here); ``station.safety``'s limits apply always.
        out_dir: The folder to create. force: Replace it if it exists.
        link: The LCM link to the drivers.
        wait: How long to wait for the driver's first status [s].
        confirm: Shown the plan; True lets the arm move (``--yes``: always True).
        replay, plots: Write ``replay.html`` and the PNG plots (a completed run only).
        first: The driver's first status if the caller already waited for it.
        answer_delay: For tests: hold each command until this long after its status [s]
            (:func:`doorlab.hardware.episode.run_hardware_episode`).

    Raises:
        NoDriver: No status within ``wait`` (nothing written).
        ConfigError, OutputError: Bad input (nothing written).
    """
    from doorlab.episode.controllers import episode_plans

    validate(scenario)
    out_dir = Path(out_dir)
    check_out_dir(out_dir, force=force)
    first = first or link.wait_first_status(wait)
    base = {
        "controller": display_name(scenario.controller),
        "doors": scenario.doors,
        "cell": "hardware",
    }
    try:
        plans, widths, arc = episode_plans(scenario)
    except IkError as e:
        staging = prepare_output(out_dir, force=force)
        write_json(staging / "metrics.json", {**base, "status": "ik_failed", "error": str(e)})
        commit_output(staging, out_dir)
        return HardwareRunOutcome("ik_failed", EXIT_CODES["ik_failed"], out_dir, None, str(e))
    if not confirm(describe_plan(scenario, arc.q_start, first, link.url)):
        return HardwareRunOutcome("declined", 1, None, None, "not confirmed: nothing moved")
    staging = prepare_output(out_dir, force=force)
    try:
        outcome = run_hardware_episode(
            scenario,
            plans,
            widths,
            q_start=arc.q_start,
            link=link,
            wait=wait,
            answer_delay=answer_delay,
        )
        metrics = compute_hardware_metrics(outcome, scenario, lcm_url=link.url)
        _write(staging, outcome, metrics, scenario, plots=plots, replay=replay)
        commit_output(staging, out_dir)
    except BaseException:
        discard_output(staging)
        raise
    if outcome.interrupt is not None:
        code = interrupt_exit_code(outcome.interrupt)
    else:
        code = EXIT_CODES[metrics.status]
    return HardwareRunOutcome(metrics.status, code, out_dir, metrics, outcome.message)


def _write(
    staging: Path,
    outcome: HardwareOutcome,
    metrics: HardwareMetrics,
    scenario: Scenario,
    *,
    plots: bool,
    replay: bool,
) -> None:
    """The folder's files; the plots and the replay only for a run that completed."""
    result = outcome.result
    result.save(staging / "log.npz")
    write_json(staging / "metrics.json", metrics.to_dict())
    (staging / "scenario.yaml").write_text(result.scenario_yaml)
    if outcome.status != "ok":
        return
    if plots:
        from doorlab.outputs.plots import save_run_plots

        save_run_plots(result, true_door_geometry(scenario), staging)
    if replay:
        from doorlab.outputs.replay import save_replay

        save_replay(result, staging / "replay.html", scenario=scenario)


def hardware_summary(outcome: HardwareRunOutcome) -> str:
    """The one-screen summary ``doorlab run --hardware`` prints."""
    lines = [f"doorlab run --hardware: {outcome.out_dir}", f"  {'status':<29}{outcome.status}"]
    m = outcome.metrics
    if m is None:
        return "\n".join([*lines, f"  {outcome.message}"])

    def mm(x: float) -> str:
        return "n/a" if not math.isfinite(x) else f"{1e3 * x:.3f}"

    def deg(x: float | None) -> str:
        return "n/a" if x is None else f"{math.degrees(x):.1f} deg"

    link = m.link
    rows = [
        ("controller / doors", f"{m.controller} / {m.doors}"),
        (
            "radial error of Q, max / rms",
            f"{mm(m.max_radial_error_m)} / {mm(m.rms_radial_error_m)} mm",
        ),
        (
            "door opened (estimated)",
            f"{deg(m.door_opening_arc_end_estimated_rad)} at the arc's end",
        ),
        ("fingers on the handle", {True: "yes", False: "no"}.get(m.fingers_on_handle, "n/a")),
        ("peak |external torque|", f"{m.peak_external_torque_Nm:.2f} N m"),
        ("episode / wall time", f"{m.duration_s:.2f} s / {m.wall_time_s:.2f} s"),
        (
            "link",
            f"{link['commands']} commands, round trip median "
            f"{link['round_trip_median_ms']:.2f} ms, max {link['round_trip_max_ms']:.2f} ms",
        ),
    ]
    lines += [f"  {name:<29}{value}" for name, value in rows]
    if outcome.message:
        lines.append(f"  note                         {outcome.message}")
    return "\n".join(lines)
