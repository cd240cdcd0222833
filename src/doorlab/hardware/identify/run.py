"""``doorlab identify``: the rehearsal calibrated on the lab's arm.

Over LCM, as ``doorlab run --hardware`` (the same checks: a driver within ``--wait``, the plan
shown and confirmed unless ``--yes``, the start guard, the status watchdog, every command
checked against ``station.safety``'s limits before it goes out, Ctrl-C and SIGTERM stop
commanding at once), it runs the script of :mod:`.script`, fits the arm's parameters
(:mod:`.analysis`) and writes, atomically, the folder:

- ``identified.yaml``: the arm preset with the identified values (loadable with
  ``--config``), each value's tolerance in a comment;
- ``fit.json``: every estimate with its standard error, tolerance and samples; how it ended;
- ``identify_log.npz``: every status and the command that answered it (the raw log);
- ``script.json``: the segments (kind, joint, rows, what the script measured).

A run that stops (``driver_lost``, ``safety_stop``, ``interrupted``) writes the raw log, the
segments and ``fit.json`` with its status, and no ``identified.yaml``: a stopped calibration
identifies nothing.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from doorlab.cell.frames import ARM_JOINTS
from doorlab.cell.safety import SafetyLimits
from doorlab.config import Scenario, validate
from doorlab.errors import ConfigError, interrupt_exit_code
from doorlab.hardware.identify.script import Script, ScriptSettings
from doorlab.hardware.identify.session import SessionOutcome, run_session
from doorlab.hardware.link import DriverLink, Status
from doorlab.outputs.runs import EXIT_CODES
from doorlab.runtime.folders import (
    check_replaceable,
    commit_output,
    discard_output,
    prepare_output,
    write_json,
)

IDENTIFIED_FILE = "identified.yaml"
FIT_FILE = "fit.json"
LOG_FILE = "identify_log.npz"
SCRIPT_FILE = "script.json"


@dataclass(frozen=True)
class IdentifyOutcome:
    """What ``doorlab identify`` did.

    Attributes:
        status: ``ok``, ``driver_lost``, ``safety_stop``, ``interrupted`` or ``declined``.
        exit_code: The process's exit code. out_dir: The folder written (None: nothing).
        message: Why it stopped. identified: The identified scenario (None unless ok).
        fits: fit.json's content (None unless ok).
    """

    status: str
    exit_code: int
    out_dir: Path | None
    message: str
    identified: Scenario | None = None
    fits: dict | None = None


def check_scenario(scenario: Scenario) -> None:
    """identify calibrates KUKA's loop: the scenario must be the arm's (the preset)."""
    if scenario.station.inner_loop.kind != "kuka_joint_impedance":
        raise ConfigError(
            "doorlab identify calibrates KUKA's joint impedance: give it the arm preset "
            "(--config examples/kuka_arm.yaml); station.inner_loop.kind is "
            f"{scenario.station.inner_loop.kind!r}"
        )


def describe_script(
    settings: ScriptSettings, status: Status, limits: SafetyLimits, url: str
) -> str:
    """What the arm is about to do, for the confirmation."""
    dq = np.asarray(settings.q_calibration) - status.q
    joint = int(np.argmax(np.abs(dq)))
    joints = ", ".join(str(j + 1) for j in settings.joints)
    rows = [
        (
            "motions",
            f"move {math.degrees(abs(dq[joint])):.1f} deg ({ARM_JOINTS[joint]}) to the "
            f"calibration pose in {settings.move_duration:g} s; rest "
            f"{settings.rest_duration:g} s; per joint ({joints}): {settings.repeats} x 2 "
            f"feed-forward ramps (up to {settings.breakaway_torque_max:g} N m, stopped once "
            f"the joint moves {math.degrees(settings.breakaway_travel):.2g} deg), "
            f"{settings.repeats} x 2 steps of {math.degrees(settings.step_size):.2g} deg, "
            f"{settings.repeats} x 2 single-cycle steps",
        ),
        ("duration", f"at most {settings.duration_estimate():.0f} s"),
        ("arm now", "q = [" + ", ".join(f"{v:.3f}" for v in status.q) + "] rad"),
        ("driver", f"IIWA_STATUS on {url}"),
        (
            "safety",
            "every command checked (joint limits, position gap, joint speed, feed-forward "
            f"torque <= {', '.join(f'{v:g}' for v in limits.tau_max)} N m); watchdog 50 ms",
        ),
    ]
    lines = ["doorlab identify: the calibration script"]
    lines += [f"  {name:<12}{value}" for name, value in rows]
    return "\n".join(lines)


def run_identify(
    scenario: Scenario,
    out_dir: Path,
    *,
    link: DriverLink,
    wait: float,
    confirm: Callable[[str], bool],
    settings: ScriptSettings | None = None,
    force: bool = False,
    first: Status | None = None,
) -> IdentifyOutcome:
    """Runs the calibration on the arm behind ``link`` and writes its folder (module doc).

    Args:
        scenario: The arm preset the lab runs (validated here): KUKA's stiffness, the
            safety limits, the friction observer's band.
        out_dir: The folder to create. force: Replace it (doorlab's own only).
        link: The LCM link. wait: How long to wait for a status [s].
        confirm: Shown the script; True lets the arm move.
        settings: The script's amplitudes and durations.
        first: The driver's first status if the caller already waited for it.

    Raises:
        NoDriver: No status within ``wait`` (nothing written).
        ConfigError, OutputError: Bad input (nothing written).
    """
    validate(scenario)
    check_scenario(scenario)
    settings = settings or ScriptSettings()
    out_dir = Path(out_dir)
    check_replaceable(out_dir, force=force)
    first = first or link.wait_first_status(wait)
    limits = SafetyLimits.from_config(scenario.station.safety, first.q)
    q_c = np.asarray(settings.q_calibration, float)
    outside = np.abs(q_c) > limits.q_max
    if outside.any():
        joint = int(np.argmax(outside))
        raise ConfigError(
            f"the calibration pose's {ARM_JOINTS[joint]} ({q_c[joint]:.3f} rad) is outside "
            f"the joint limit less the margin ({limits.q_max[joint]:.3f} rad)"
        )
    if not confirm(describe_script(settings, first, limits, link.url)):
        return IdentifyOutcome("declined", 1, None, "not confirmed: nothing moved")
    script = Script(settings, first.q, tau_limit=limits.tau_max, speed_limit=limits.speed_max)
    staging = prepare_output(out_dir, force=force)
    try:
        outcome = run_session(script, link, limits, wait=wait)
        result = _write(staging, scenario, script, outcome, settings, link.url)
        commit_output(staging, out_dir)
    except BaseException:
        discard_output(staging)
        raise
    identified, fits = result
    if outcome.interrupt is not None:
        code = interrupt_exit_code(outcome.interrupt)
    else:
        code = EXIT_CODES[outcome.status]
    return IdentifyOutcome(outcome.status, code, out_dir, outcome.message, identified, fits)


def _write(
    staging: Path,
    scenario: Scenario,
    script: Script,
    outcome: SessionOutcome,
    settings: ScriptSettings,
    url: str,
):
    """The folder's files (module docstring); returns (identified scenario, fits) or Nones."""
    arrays = outcome.log.arrays()
    np.savez_compressed(staging / LOG_FILE, **arrays)
    segments = [asdict(s) for s in script.segments]
    (staging / SCRIPT_FILE).write_text(
        json.dumps({"settings": _settings_dict(settings), "segments": segments}, indent=1) + "\n"
    )
    head = {
        "status": outcome.status,
        "message": outcome.message,
        "lcm_url": url,
        "statuses": len(outcome.log.utime),
        "commands_sent": int(np.sum(arrays["sent"])) if len(arrays["sent"]) else 0,
        "stale_commands_dropped": outcome.log.stale,
        "skipped_statuses": outcome.log.skipped,
    }
    if outcome.violation is not None:
        head["stop"] = {
            "limit": outcome.violation.limit,
            "joint": ARM_JOINTS[outcome.violation.joint],
            "value": outcome.violation.value,
            "bound": outcome.violation.bound,
            "t": outcome.violation.t,
        }
    if outcome.status != "ok":
        write_json(staging / FIT_FILE, head)
        return None, None
    from doorlab.cell.station import kuka_joint_damping
    from doorlab.hardware.identify.analysis import (
        analyse,
        fits_dict,
        identified_scenario,
        preset_yaml,
    )

    found = analyse(
        arrays,
        script.segments,
        stiffness=np.asarray(scenario.station.inner_loop.kuka_stiffness, float),
        band=scenario.station.arm.friction_compensation_band,
        q_calibration=np.asarray(settings.q_calibration, float),
    )
    identified = identified_scenario(scenario, found)
    fits = {
        **head,
        **fits_dict(found),
        "nominal_damping_Nms": kuka_joint_damping(scenario.station.inner_loop).tolist(),
    }
    write_json(staging / FIT_FILE, fits)
    (staging / IDENTIFIED_FILE).write_text(
        preset_yaml(identified, found, source=f"doorlab identify on {url}")
    )
    return identified, fits


def _settings_dict(settings: ScriptSettings) -> dict:
    out = asdict(settings)
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in out.items()}


def identify_summary(outcome: IdentifyOutcome) -> str:
    """The one-screen summary ``doorlab identify`` prints."""
    lines = [f"doorlab identify: {outcome.out_dir}", f"  {'status':<24}{outcome.status}"]
    if outcome.message:
        lines.append(f"  {'note':<24}{outcome.message}")
    fits = outcome.fits
    if not fits:
        return "\n".join(lines)

    def per_joint(key: str, scale: float = 1.0) -> str:
        values = []
        for entry in fits[key].values():
            values.append(
                "n/a"
                if entry is None or entry["value"] is None
                else (f"{scale * entry['value']:.3g}")
            )
        return ", ".join(values)

    rows = [
        ("damping [N m s/rad]", per_joint("damping")),
        ("effective inertia", per_joint("effective_inertia") + " kg m^2"),
        ("stiction [N m]", per_joint("stiction")),
        ("Coulomb friction [N m]", per_joint("coulomb_friction")),
        (
            "load data",
            f"{fits['load_mass']['value']:.3g} kg (+- {fits['load_mass']['tolerance']:.2g})",
        ),
        (
            "latency",
            f"{1e3 * fits['latency']['value']:.2f} ms "
            f"(+- {1e3 * fits['latency']['tolerance']:.2f}), jitter +- "
            f"{1e3 * (fits['latency_jitter']['value'] or 0.0):.2f} ms",
        ),
        ("torque noise [N m]", per_joint("external_torque_noise")),
        ("preset", f"{outcome.out_dir}/{IDENTIFIED_FILE} (--config)"),
    ]
    lines += [f"  {name:<24}{value}" for name, value in rows]
    return "\n".join(lines)
