"""``doorlab identify``: the rehearsal calibrated on the lab's arm.

Over LCM, as ``doorlab run --hardware`` (the same checks: a driver within ``--wait``, the plan
shown and confirmed unless ``--yes``, the start guard, the status watchdog, every command
checked against ``station.safety``'s limits before it goes out, Ctrl-C and SIGTERM stop
commanding at once), it runs the script of :mod:`.script`, then:

1. **the recording**, before any fit, as one folder moved into place at once (nothing of a
   half-written one is ever seen): ``identify_log.npz`` (every status and the command that
   answered it), ``script.json`` (the settings, the segments with their rows, how the run
   ended), ``scenario.yaml`` (the preset it ran with) and ``fit.json`` saying how it ended;
2. **the fit** of that recording (:func:`fit_recording`, :mod:`.analysis`), its files each
   replaced whole: ``identified.yaml`` (the arm preset with the identified values, loadable
   with ``--config``; each value's tolerance in a comment, and a line for each parameter the
   recording could not give, whose preset value is kept) and ``fit.json`` (every estimate
   with its standard error, tolerance and samples; the values kept and why).

A run cut short (``driver_lost``, ``safety_stop``, ``interrupted``) keeps its recording and
fits nothing; ``doorlab identify --analyse DIR`` fits a recording, again or for the first
time (no arm, no LCM). Whatever the fit does, the recording is already in place.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from doorlab.cell.frames import ARM_JOINTS
from doorlab.cell.safety import SafetyLimits
from doorlab.config import Scenario, validate
from doorlab.errors import ConfigError, OutputError, interrupt_exit_code
from doorlab.hardware.identify.script import Script, ScriptSettings, Segment
from doorlab.hardware.identify.session import IdentifyLog, SessionOutcome, run_session
from doorlab.hardware.link import DriverLink, Status
from doorlab.outputs.runs import EXIT_CODES
from doorlab.runtime.folders import (
    check_replaceable,
    commit_output,
    discard_output,
    foreign_file,
    prepare_output,
    record_written,
    write_json,
)
from doorlab.runtime.interrupts import deferred_signals

IDENTIFIED_FILE = "identified.yaml"
FIT_FILE = "fit.json"
LOG_FILE = "identify_log.npz"
SCRIPT_FILE = "script.json"
SCENARIO_FILE = "scenario.yaml"


@dataclass(frozen=True)
class IdentifyOutcome:
    """What ``doorlab identify`` did.

    Attributes:
        status: ``ok``, ``driver_lost``, ``safety_stop``, ``interrupted`` or ``declined``.
        exit_code: The process's exit code. out_dir: The folder written (None: nothing).
        message: Why it stopped, and where its recording is kept. identified: The
            identified scenario (None unless fitted). fits: fit.json's content (None unless
            fitted). kept: One line per parameter not identified (its preset value kept).
    """

    status: str
    exit_code: int
    out_dir: Path | None
    message: str
    identified: Scenario | None = None
    fits: dict | None = None
    kept: tuple[str, ...] = ()


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


def analyse_hint(out_dir: Path) -> str:
    """How to fit a kept recording."""
    return f"doorlab identify --analyse {out_dir}"


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
    """Runs the calibration on the arm behind ``link``, keeps its recording in ``out_dir``,
    then fits it (module doc).

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
    outcome = _record_session(script, link, limits, wait, scenario, settings, out_dir, force)
    kept = (
        f"the recording ({len(outcome.log.utime)} statuses) is kept in {out_dir}: "
        f"`{analyse_hint(out_dir)}` fits it"
    )
    if outcome.status != "ok":
        if outcome.interrupt is not None:
            code = interrupt_exit_code(outcome.interrupt)
        else:
            code = EXIT_CODES[outcome.status]
        return IdentifyOutcome(outcome.status, code, out_dir, f"{outcome.message}; {kept}")
    try:
        identified, fits, lines = fit_recording(
            out_dir, scenario, source=f"doorlab identify on {link.url}"
        )
    except KeyboardInterrupt as e:  # Ctrl-C, SIGTERM during the fit: the recording stays
        return IdentifyOutcome(
            "interrupted", interrupt_exit_code(e), out_dir, f"interrupted during the fit; {kept}"
        )
    except OutputError as e:  # a full disk: one line, and the recording stays
        raise OutputError(f"{e}; {kept}") from None
    except Exception as e:  # a defect of the fit: its traceback, and the recording stays
        e.add_note(f"doorlab identify: {kept}")
        raise
    return IdentifyOutcome("ok", 0, out_dir, "", identified, fits, tuple(lines))


def _record_session(script, link, limits, wait, scenario, settings, out_dir, force):
    """Runs the session and moves its recording into ``out_dir`` in one step, before any fit;
    a session that raises (a defect) keeps its recording too, then raises."""
    staging = prepare_output(out_dir, force=force)
    log = IdentifyLog()
    try:
        try:
            outcome = run_session(script, link, limits, wait=wait, log=log)
        except Exception as e:
            message = f"the session failed: {type(e).__name__}: {e}"
            failed = SessionOutcome("error", message, None, None, log)
            with deferred_signals():
                _write_recording(staging, scenario, script, failed, settings, link.url)
                commit_output(staging, out_dir)
            e.add_note(f"doorlab identify: the recording so far is kept in {out_dir}")
            raise
        try:
            with deferred_signals():  # a Ctrl-C now lands once the recording is in place
                _write_recording(staging, scenario, script, outcome, settings, link.url)
                commit_output(staging, out_dir)
        except KeyboardInterrupt as e:
            if outcome.status == "ok" and out_dir.is_dir() and not staging.exists():
                return SessionOutcome("interrupted", "interrupted", None, e, outcome.log)
            raise
    finally:
        discard_output(staging)  # nothing once committed
    return outcome


def _write_recording(
    staging: Path,
    scenario: Scenario,
    script: Script,
    outcome: SessionOutcome,
    settings: ScriptSettings,
    url: str,
) -> None:
    """The recording's files (module docstring, 1.).

    Raises:
        OutputError: They cannot be written (a full disk: one line, the staging removed).
    """
    try:
        _write_recording_files(staging, scenario, script, outcome, settings, url)
    except OSError as e:
        raise OutputError(
            f"cannot write the recording into {staging.parent}: {e.strerror or e} (the arm "
            "holds its last command)"
        ) from None


def _write_recording_files(staging, scenario, script, outcome, settings, url) -> None:
    from pydrake.common.yaml import yaml_dump_typed

    arrays = outcome.log.arrays()
    np.savez_compressed(staging / LOG_FILE, **arrays)
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
    segments = [asdict(s) for s in script.segments]
    recording = {"run": head, "settings": _settings_dict(settings), "segments": segments}
    (staging / SCRIPT_FILE).write_text(json.dumps(recording, indent=1) + "\n")
    (staging / SCENARIO_FILE).write_text(yaml_dump_typed(scenario))
    write_json(staging / FIT_FILE, {**head, "fit": "none yet: `doorlab identify --analyse DIR`"})


def _settings_dict(settings: ScriptSettings) -> dict:
    out = asdict(settings)
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in out.items()}


def read_recording(folder: Path) -> tuple[dict[str, np.ndarray], dict]:
    """A recording's log arrays and ``script.json``'s content.

    Raises:
        ConfigError: ``folder`` holds no recording doorlab identify wrote (one line).
    """
    folder = Path(folder)
    missing = [n for n in (LOG_FILE, SCRIPT_FILE) if not (folder / n).is_file()]
    if missing:
        raise ConfigError(
            f"--analyse {str(folder)!r} holds no {' or '.join(missing)}: give the folder a "
            "doorlab identify run wrote (its --out)"
        )
    try:
        with np.load(folder / LOG_FILE) as data:
            log = {name: data[name] for name in data.files}
        recording = json.loads((folder / SCRIPT_FILE).read_text())
        recording["segments"] = [Segment(**s) for s in recording["segments"]]
        ScriptSettings(**_settings_tuple(recording["settings"]))
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ConfigError(
            f"--analyse {str(folder)!r}: its recording cannot be read ({e})"
        ) from None
    needed = {"q", "q_commanded", "tau_external", "q_ref", "tau_ff", "sent"}
    if not needed <= set(log) or len(log["q"]) < 2:
        raise ConfigError(f"--analyse {str(folder)!r}: {LOG_FILE} holds no statuses to fit")
    return log, recording


def _settings_tuple(settings: dict) -> dict:
    return {k: (tuple(v) if isinstance(v, list) else v) for k, v in settings.items()}


def fit_recording(
    folder: Path, scenario: Scenario, *, source: str
) -> tuple[Scenario, dict, list[str]]:
    """Fits the recording in ``folder`` (:mod:`.analysis`) and writes ``identified.yaml`` and
    ``fit.json`` there, each replaced whole: (the identified scenario, fit.json's content,
    the lines of the values kept from ``scenario``).

    Args:
        folder: A recording (:func:`run_identify`'s folder). scenario: The arm preset it is
            fitted against (its stiffness, band; its values kept where the recording gives
            none). source: Where the recording came from, for ``identified.yaml``.

    Raises:
        ConfigError: No recording in ``folder`` (:func:`read_recording`).
        OutputError: ``fit.json`` or ``identified.yaml`` there is not doorlab's, unchanged.
    """
    from doorlab.cell.station import kuka_joint_damping
    from doorlab.hardware.identify.analysis import analyse
    from doorlab.hardware.identify.preset import (
        fits_dict,
        identified_scenario,
        kept,
        kept_line,
        preset_yaml,
    )

    validate(scenario)
    check_scenario(scenario)
    folder = Path(folder)
    log, recording = read_recording(folder)
    found_foreign = foreign_file(folder, only=[FIT_FILE, IDENTIFIED_FILE])
    if found_foreign is not None:
        raise OutputError(
            f"{str(folder)!r} holds {found_foreign[0]!r}, {found_foreign[1]}: the fit would "
            "replace it; move it away first"
        )
    settings = recording["settings"]
    found = analyse(
        log,
        recording["segments"],
        stiffness=np.asarray(scenario.station.inner_loop.kuka_stiffness, float),
        band=scenario.station.arm.friction_compensation_band,
        q_calibration=np.asarray(settings["q_calibration"], float),
        joints=tuple(settings["joints"]),
    )
    identified = identified_scenario(scenario, found)
    groups = kept(scenario, found)
    lines = [kept_line(g) for g in groups]
    fits = {
        **recording.get("run", {}),
        **fits_dict(found),
        "kept_from_preset": groups,
        "nominal_damping_Nms": kuka_joint_damping(scenario.station.inner_loop).tolist(),
    }
    text = preset_yaml(identified, found, source=source, kept_from=lines)
    _replace(folder, FIT_FILE, json.dumps(_clean(fits), indent=2) + "\n")
    _replace(folder, IDENTIFIED_FILE, text)
    return identified, fits, lines


def _clean(value):
    """NaN as null (JSON has none)."""
    if isinstance(value, float) and value != value:
        return None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


def _replace(folder: Path, name: str, text: str) -> None:
    """Writes ``folder/name`` whole (a temporary file renamed over it) and records it in the
    folder's manifest.

    Raises:
        OutputError: It cannot be written (the folder keeps its previous files).
    """
    path = folder / name
    tmp = folder / f".{name}.{os.getpid()}.tmp"
    try:
        with deferred_signals():
            try:
                tmp.write_text(text)
                os.replace(tmp, path)
            finally:
                tmp.unlink(missing_ok=True)
            record_written(folder, [path])
    except OSError as e:
        raise OutputError(f"cannot write {str(path)!r}: {e.strerror or e}") from None


def analyse_folder(folder: Path, scenario: Scenario) -> IdentifyOutcome:
    """``doorlab identify --analyse DIR``: fits DIR's recording again (no arm, no LCM) and
    writes DIR's ``identified.yaml`` and ``fit.json`` (:func:`fit_recording`).

    Raises:
        ConfigError, OutputError: No recording in DIR, or a file there the fit would replace
            is not doorlab's, unchanged.
    """
    folder = Path(folder)
    identified, fits, lines = fit_recording(
        folder, scenario, source=f"doorlab identify --analyse {folder}"
    )
    status = fits.get("status", "ok")
    message = "" if status == "ok" else f"a recording cut short ({status}): fitted what it holds"
    return IdentifyOutcome(status, 0, folder, message, identified, fits, tuple(lines))


def identify_summary(outcome: IdentifyOutcome) -> str:
    """The one-screen summary ``doorlab identify`` prints."""
    from doorlab.hardware.identify.preset import summary_rows

    lines = [f"doorlab identify: {outcome.out_dir}", f"  {'status':<24}{outcome.status}"]
    if outcome.message:
        lines.append(f"  {'note':<24}{outcome.message}")
    if not outcome.fits:
        return "\n".join(lines)
    rows = summary_rows(outcome.fits)
    if outcome.identified is not None:  # the simulator's latency: the arm's + h/2
        arm = outcome.identified.station.arm
        rows.append(
            (
                "preset latency",
                f"{1e3 * arm.latency:.3g} ms, jitter {1e3 * arm.latency_jitter:.3g} ms "
                "(the measured + h/2: the simulator's semi-implicit step)",
            )
        )
    rows.append(("preset", f"{outcome.out_dir}/{IDENTIFIED_FILE} (--config)"))
    lines += [f"  {name:<24}{value}" for name, value in rows]
    lines += [f"  {'kept':<24}{line}" for line in outcome.kept]
    return "\n".join(lines)
