"""The report's "On the arm" section: what each plan will do on the lab's iiwa.

Built from the section's run folders only (``metrics.json``; ``log.npz`` for the external
torques against kuka_driver's freeze limits and the door over time) and from the model (the
joint damping of both loops, seen at Q): every number on it is computed, none typed in. The
runs are :func:`doorlab.report.experiments.make_arm_cases`'.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from markupsafe import Markup

from doorlab.outputs.pages import Figures, format_number
from doorlab.report.experiments import (
    ARM_CONDITIONS,
    ARM_COST_YAW_DEG,
    ARM_TUNING,
    ArmCase,
    RunRecord,
)

CONDITION_TITLES = {
    "cell": "doorlab's cell",
    "timing": "the arm's timing",
    "arm": "the arm",
}
TUNING_TITLES = {
    "velocity": "q_ref = q + q_dot x the loop's lead",
    "impedance": "impedance.kv = 10000 N/m",
}


OUTCOMES = ("opens", "falls_short", "loses_the_handle", "stopped")
"""What a run on the arm did (:attr:`ArmRow.outcome`)."""


@dataclass(frozen=True)
class ArmRow:
    """One case's figures (SI units; nan where the run produced none)."""

    case: ArmCase
    folder: str
    status: str
    error: str
    door_arc_end_deg: float
    handle_held: bool | None
    slip_time_s: float | None
    max_radial_error_m: float
    peak_contact_torque_Nm: float
    freeze_ratio: float
    freeze_joint: int | None
    max_orientation_error_rad: float = math.nan

    @property
    def freeze_margin(self) -> float:
        """1 - the largest |external torque| over its freeze limit [-] (nan: not logged)."""
        return 1.0 - self.freeze_ratio

    @property
    def opened(self) -> bool:
        """The door opened: status ok, >= OPEN_THRESHOLD_DEG at the arc's end, held."""
        from doorlab.studies.robustness import OPEN_THRESHOLD_DEG

        return bool(
            self.status == "ok" and self.handle_held and self.door_arc_end_deg >= OPEN_THRESHOLD_DEG
        )

    @property
    def outcome(self) -> str:
        """What the run did (one of :data:`OUTCOMES`): opened the door; kept the handle
        but the door fell short of the threshold; lost the handle (slipped); or was stopped
        (a safety stop, the driver's freeze, a diverged simulation: its status)."""
        if self.opened:
            return "opens"
        if self.status not in ("ok", "slipped"):
            return "stopped"
        if self.handle_held is False or self.status == "slipped":
            return "loses_the_handle"
        return "falls_short"


def _freeze(folder: Path, limit: float) -> tuple[float, int | None]:
    """The largest |tau_external| / kuka_driver's limit over the run, and its joint: on each
    cycle's status (KUKA's estimate, what the driver judges) when the run kept the arm's
    timing, else on the logged contact torques."""
    from doorlab.episode.result import EpisodeResult
    from doorlab.kuka import external_torque_limits

    try:
        result = EpisodeResult.load(folder / "log.npz")
    except (OSError, ValueError, KeyError):
        return math.nan, None
    estimated = result.tau_external_estimated
    tau = np.abs(result.tau_external if estimated is None else estimated)
    ratio = tau / external_torque_limits(limit)
    if not ratio.size:
        return math.nan, None
    joint = int(np.argmax(ratio.max(axis=0)))
    return float(ratio.max()), joint


def arm_row(case: ArmCase, record: RunRecord, out_dir: Path, limit: float) -> ArmRow:
    """A case's row from its run folder."""
    folder = Path(record.run_dir)
    try:
        metrics = json.loads((folder / "metrics.json").read_text())
    except (OSError, ValueError):
        metrics = {"status": "missing"}

    def number(key: str) -> float:
        value = metrics.get(key)
        return math.nan if value is None else float(value)

    ratio, joint = _freeze(folder, limit)
    return ArmRow(
        case=case,
        folder=os.path.relpath(folder, out_dir),
        status=str(metrics.get("status", "missing")),
        error=str(metrics.get("error", "")),
        door_arc_end_deg=math.degrees(number("door_opening_arc_end_rad")),
        handle_held=metrics.get("handle_held"),
        slip_time_s=metrics.get("slip_time_s"),
        max_radial_error_m=number("max_radial_error_m"),
        peak_contact_torque_Nm=number("peak_external_torque_arc_Nm"),
        freeze_ratio=ratio,
        freeze_joint=joint,
        max_orientation_error_rad=number("max_orientation_error_rad"),
    )


@dataclass(frozen=True)
class DragModel:
    """Why a damped joint loop drags the impedance plan (numbers from the model).

    Attributes:
        damping_cell, damping_arm: The joints' damping in doorlab's cell and on the arm (7,)
            [N m s/rad]. delay_damping: What one 5 ms cycle of command delay adds with the
            arm's stiffness, K x 5 ms (7,) [N m s/rad]; ``delay_damping_cell``: with
            doorlab's Kq.
        drag_cell, drag_arm: The joints' damping seen at Q along the arc's tangent at the
            grasp, t^T (J D^-1 J^T)^-1 t [N s/m]. speed: Q's speed along the arc [m/s].
        kv: The impedance plan's task-space stiffness [N/m].
        grip: The gripper's squeeze on the handle, its PD's kp x (handle thickness - grasp
            width) [N].
    """

    damping_cell: np.ndarray
    damping_arm: np.ndarray
    delay_damping: np.ndarray
    delay_damping_cell: np.ndarray
    drag_cell: float
    drag_arm: float
    speed: float
    kv: float
    grip: float


def drag_model(cell, arm) -> DragModel:
    """:class:`DragModel` of the scenarios of doorlab's cell and of the arm."""
    from pydrake.multibody.tree import JacobianWrtVariable

    from doorlab.cell.frames import L7_FRAME, p_L7Q
    from doorlab.cell.geometry import scenario_door_geometry
    from doorlab.cell.station import joint_damping, loop_gains, make_controller_plant
    from doorlab.constants import Q_GRASP
    from doorlab.hardware.estimates import HANDLE_THICKNESS
    from doorlab.kuka import CYCLE_PERIOD

    plant = make_controller_plant()
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, Q_GRASP)
    W = plant.world_frame()
    J = plant.CalcJacobianSpatialVelocity(
        context, JacobianWrtVariable.kV, plant.GetFrameByName(L7_FRAME), p_L7Q, W, W
    )[3:]
    geometry = scenario_door_geometry(cell)
    tangent = geometry.p_WQ_ref(1e-3) - geometry.p_WQ_ref(0.0)
    tangent /= np.linalg.norm(tangent)

    def drag(damping: np.ndarray) -> float:
        C = np.linalg.inv(J @ np.diag(1.0 / damping) @ J.T)
        return float(tangent @ C @ tangent)

    d_cell, d_arm = joint_damping(cell.station), joint_damping(arm.station)
    gripper = arm.station.gripper
    return DragModel(
        damping_cell=d_cell,
        damping_arm=d_arm,
        delay_damping=loop_gains(arm.station.inner_loop)[0] * CYCLE_PERIOD,
        delay_damping_cell=loop_gains(cell.station.inner_loop)[0] * CYCLE_PERIOD,
        drag_cell=drag(d_cell),
        drag_arm=drag(d_arm),
        speed=geometry.r_handle * geometry.sweep / cell.timeline.arc_duration,
        kv=arm.impedance.kv,
        grip=gripper.kp * (HANDLE_THICKNESS - gripper.grasp_width),
    )


def _span(values: np.ndarray) -> str:
    low, high = format_number(float(np.min(values))), format_number(float(np.max(values)))
    return low if low == high else f"{low}-{high}"


def _deg(value: float) -> str:
    return f"{format_number(value)} deg"


def _mm(value: float) -> str:
    return f"{format_number(1e3 * value)} mm"


def _plan_findings(rows: Sequence[ArmRow]) -> list[str]:
    """One sentence per controller: the door under the three conditions, opened or not."""
    from doorlab.studies.robustness import OPEN_THRESHOLD_DEG

    findings = []
    plain = [r for r in rows if not r.case.tuned and not r.case.yaw_error_rad and not r.case.model]
    for controller in dict.fromkeys(r.case.controller for r in plain):
        by = {r.case.condition: r for r in plain if r.case.controller == controller}
        if set(by) != set(ARM_CONDITIONS):
            continue
        arm = by["arm"]
        verdict = "opens the door on the arm" if arm.opened else "does not open the door on the arm"
        how = (
            f"handle lost at t = {format_number(arm.slip_time_s)} s"
            if arm.slip_time_s is not None
            else ("handle held" if arm.handle_held else arm.status)
        )
        if arm.status not in ("ok", "slipped"):
            how = f"{arm.status}: {arm.error}"
        findings.append(
            f"The {controller} plan {verdict} as configured: the door at the arc's end "
            f"{_deg(by['cell'].door_arc_end_deg)} in doorlab's cell, "
            f"{_deg(by['timing'].door_arc_end_deg)} with the arm's timing, "
            f"{_deg(arm.door_arc_end_deg)} on the arm ({how}; opened means status ok, >= "
            f"{OPEN_THRESHOLD_DEG:g} deg and the handle held); Q's max radial error "
            f"{_mm(by['cell'].max_radial_error_m)}, {_mm(by['timing'].max_radial_error_m)}, "
            f"{_mm(arm.max_radial_error_m)}."
        )
    return findings


def _tuning_findings(rows: Sequence[ArmRow]) -> list[str]:
    """The tuned plans: on the arm, and what it costs in doorlab's cell."""

    def pick(controller: str, condition: str, tuned: bool, yaw: bool) -> ArmRow | None:
        found = [
            r
            for r in rows
            if r.case.controller == controller
            and r.case.condition == condition
            and r.case.tuned == tuned
            and bool(r.case.yaw_error_rad) == yaw
            and not r.case.model
        ]
        return found[0] if found else None

    findings = []
    for controller in ARM_TUNING:
        arm, cell = pick(controller, "arm", True, False), pick(controller, "cell", True, False)
        plain, turned, turned_tuned = (
            pick(controller, "cell", False, False),
            pick(controller, "cell", False, True),
            pick(controller, "cell", True, True),
        )
        if None in (arm, cell, plain, turned, turned_tuned):
            continue
        verdict = "opens the door" if arm.opened else "still does not open the door"
        findings.append(
            f"With {TUNING_TITLES[controller]} the {controller} plan {verdict} on the arm: "
            f"{_deg(arm.door_arc_end_deg)} at the arc's end, Q's max radial error "
            f"{_mm(arm.max_radial_error_m)}, handle {'held' if arm.handle_held else 'lost'}. "
            f"Its cost in doorlab's cell: door {_deg(cell.door_arc_end_deg)} (was "
            f"{_deg(plain.door_arc_end_deg)}), radial error {_mm(cell.max_radial_error_m)} "
            f"(was {_mm(plain.max_radial_error_m)}), peak contact torque "
            f"{format_number(cell.peak_contact_torque_Nm)} N m (was "
            f"{format_number(plain.peak_contact_torque_Nm)}); with the cupboard turned "
            f"{ARM_COST_YAW_DEG:g} deg, radial error {_mm(turned_tuned.max_radial_error_m)} "
            f"against {_mm(turned.max_radial_error_m)} and peak contact torque "
            f"{format_number(turned_tuned.peak_contact_torque_Nm)} against "
            f"{format_number(turned.peak_contact_torque_Nm)} N m."
        )
    return findings


def _freeze_finding(rows: Sequence[ArmRow], limit: float) -> str:
    from doorlab.cell.frames import ARM_JOINTS

    on_arm = [r for r in rows if r.case.condition == "arm" and math.isfinite(r.freeze_ratio)]
    if not on_arm:
        return "No run on the arm logged its external torques."
    worst = max(on_arm, key=lambda r: r.freeze_ratio)
    fires = [r.case.run for r in on_arm if r.freeze_ratio > 1.0 or "external_torque" in r.error]
    joint = ARM_JOINTS[worst.freeze_joint] if worst.freeze_joint is not None else "n/a"
    return (
        f"kuka_driver's external-torque freeze ({format_number(limit)} N m x 1, 1, 1, 0.5, 0.2, "
        f"0.2, 0.1 per joint) "
        + (f"fires in {', '.join(fires)}" if fires else "fires in none of the runs on the arm")
        + f": the largest |external torque| reached {format_number(100 * worst.freeze_ratio)} % "
        f"of its joint's limit ({worst.case.run}, {joint})."
    )


def _answer(rows: Sequence[ArmRow], model: DragModel) -> str:
    """Why does the impedance plan behave differently on the real robot? With numbers."""
    by = {
        r.case.condition: r
        for r in rows
        if r.case.controller == "impedance"
        and not r.case.tuned
        and not r.case.yaw_error_rad
        and not r.case.model
    }
    tuned = [
        r for r in rows if r.case.controller == "impedance" and r.case.tuned and not r.case.model
    ]
    tuned_arm = [r for r in tuned if r.case.condition == "arm"]
    if set(by) != set(ARM_CONDITIONS):
        return "The impedance plan's runs are missing: no answer."
    force_cell, force_arm = model.drag_cell * model.speed, model.drag_arm * model.speed
    ratio = model.damping_arm / model.damping_cell
    text = (
        "Why does the impedance plan behave differently on the real robot? It sends q_ref = q "
        "and tau_ff = J^T F, F = Kv e: nothing but the joint loop's damping resists the motion "
        "F asks for. KUKA's joint impedance with damping 1.0 damps the joints with "
        f"{_span(model.damping_arm)} N m s/rad, {_span(ratio)}x doorlab's "
        f"{_span(model.damping_cell)}; at Q, along the arc, that is "
        f"{format_number(model.drag_arm)} N s/m against {format_number(model.drag_cell)}. "
        f"Moving the handle at the arc's {format_number(1e3 * model.speed)} mm/s takes "
        f"{format_number(force_arm)} N on the arm ({format_number(force_cell)} N in doorlab's "
        f"cell), which F = Kv e with Kv = {format_number(model.kv)} N/m makes only once Q "
        f"trails by {format_number(1e3 * force_arm / model.kv)} mm "
        f"({format_number(1e3 * force_cell / model.kv)} mm); the fingers squeeze the handle "
        f"with {format_number(model.grip)} N (the gripper's PD), so the handle slips out"
    )
    arm = by["arm"]
    if arm.slip_time_s is not None:
        text += f" (measured: at t = {format_number(arm.slip_time_s)} s"
    else:
        text += f" (measured: status {arm.status}"
    text += (
        f", the door {_deg(arm.door_arc_end_deg)} at the arc's end against "
        f"{_deg(by['cell'].door_arc_end_deg)} in doorlab's cell). The arm's timing adds a "
        "cycle of delay, and a command 5 ms late is, to first order, more damping K x 5 ms: "
        f"{_span(model.delay_damping)} N m s/rad with KUKA's stiffness "
        f"({_span(100 * model.delay_damping / model.damping_arm)} % of its damping), "
        f"{_span(model.delay_damping_cell)} with doorlab's Kq "
        f"({_span(100 * model.delay_damping_cell / model.damping_cell)} % of doorlab's: the "
        f"door {_deg(by['timing'].door_arc_end_deg)} instead of "
        f"{_deg(by['cell'].door_arc_end_deg)})."
    )
    if tuned_arm:
        text += (
            f" A stiffer task spring makes the same force with less lag: with "
            f"{TUNING_TITLES['impedance']} the door reaches "
            f"{_deg(tuned_arm[0].door_arc_end_deg)} on the arm."
        )
    return text


def _door_figure(rows: Sequence[ArmRow], out_dir: Path):
    """The door over the arc for each controller under the three conditions (and tuned)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from doorlab.episode.metrics import door_opening
    from doorlab.episode.result import EpisodeResult

    controllers = list(dict.fromkeys(r.case.controller for r in rows))
    fig, axes = plt.subplots(1, len(controllers), figsize=(4 * len(controllers), 3.2), sharey=True)
    axes = np.atleast_1d(axes)
    styles = {"cell": "-", "timing": "--", "arm": "-"}
    colors = {"cell": "C0", "timing": "C1", "arm": "C3"}
    for ax, controller in zip(axes, controllers, strict=True):
        for row in rows:
            case = row.case
            if case.controller != controller or case.yaw_error_rad or case.model:
                continue
            if case.tuned and case.condition != "arm":
                continue
            try:
                result = EpisodeResult.load(Path(out_dir) / row.folder / "log.npz")
            except (OSError, ValueError, KeyError):
                continue
            if result.door_angles is None:
                continue
            t = result.t - result.arc_window[0]
            label = CONDITION_TITLES[case.condition] + (" (tuned)" if case.tuned else "")
            ax.plot(
                t,
                np.degrees(door_opening(result)),
                ls=":" if case.tuned else styles[case.condition],
                color="C2" if case.tuned else colors[case.condition],
                label=label,
            )
        ax.set(title=controller, xlabel="time since the arc's start [s]")
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    axes[0].set_ylabel("left door opened [deg]")
    fig.tight_layout()
    return fig


def arm_context(
    cases: Sequence[tuple[ArmCase, RunRecord]], out_dir: Path, figures: Figures, base
) -> dict:
    """What ``report.html.j2`` shows in its "On the arm" section.

    Args:
        cases: (case, its run) per case, in :func:`make_arm_cases` order.
        out_dir: The report folder (links to the runs are relative to it).
        figures: The page's figures. base: The report's base scenario.

    Returns:
        {"rows", "figures", "findings", "answer", "threshold"}.
    """
    from doorlab.cell.frames import ARM_JOINTS
    from doorlab.config import Scenario
    from doorlab.report.experiments import arm_condition
    from doorlab.studies.robustness import OPEN_THRESHOLD_DEG

    base = base if base is not None else Scenario()
    cell, arm = arm_condition(base, "cell"), arm_condition(base, "arm")
    limit = arm.station.driver.external_torque_limit
    rows = [arm_row(case, record, out_dir, limit) for case, record in cases]
    model = drag_model(cell, arm)
    table = []
    for row in rows:
        case = row.case
        if case.model:
            continue  # the band's models: their own table
        held = {True: "held", False: "lost"}.get(row.handle_held, "n/a")
        joint = ARM_JOINTS[row.freeze_joint][-1] if row.freeze_joint is not None else ""
        table.append(
            {
                "run": case.run,
                "folder": row.folder,
                "css": "" if row.opened else "warn",
                "cells": [
                    case.controller,
                    CONDITION_TITLES[case.condition],
                    TUNING_TITLES[case.controller] if case.tuned else "as shipped",
                    format_number(math.degrees(case.yaw_error_rad)),
                    row.status,
                    format_number(row.door_arc_end_deg),
                    held,
                    format_number(1e3 * row.max_radial_error_m),
                    format_number(math.degrees(row.max_orientation_error_rad)),
                    format_number(row.peak_contact_torque_Nm),
                    f"{format_number(100 * row.freeze_ratio)} ({joint})" if joint else "n/a",
                    "yes" if row.opened else "no",
                ],
            }
        )
    embedded = figures.embed(
        "on_the_arm",
        _door_figure(rows, out_dir),
        "The left door over the arc, each controller in doorlab's cell, with the arm's timing, "
        "on the arm, and (dotted) tuned on the arm.",
    )
    findings = [
        *_plan_findings(rows),
        *_tuning_findings(rows),
        _freeze_finding(rows, limit),
    ]
    from doorlab.report.arm_band import (
        band_figure,
        band_summary,
        band_table,
        plan_bands,
        verdict_sentence,
    )

    bands = plan_bands(rows)
    band_embedded = ""
    if any(len(band.rows) > 1 for band in bands):
        band_embedded = figures.embed(
            "arm_band",
            band_figure(bands, out_dir),
            "The left door over the arc on the arm, each plan under each plausible model of "
            "the arm (the nominal black; dashed: the door not opened; grey: the band).",
        )
    return {
        "rows": table,
        "figures": Markup(embedded),
        "band_rows": band_table(bands),
        "band_figure": Markup(band_embedded),
        "verdicts": [verdict_sentence(band) for band in bands],
        "findings": findings,
        "answer": _answer(rows, model),
        "threshold": f"{OPEN_THRESHOLD_DEG:g}",
        "summary": [
            {
                "run": r.case.run,
                "controller": r.case.controller,
                "condition": r.case.condition,
                "tuned": r.case.tuned,
                "yaw_error_rad": r.case.yaw_error_rad,
                "model": r.case.model,
                "opened": r.opened,
                "external_torque_over_freeze_limit": r.freeze_ratio
                if math.isfinite(r.freeze_ratio)
                else None,
            }
            for r in rows
        ],
        "verdicts_summary": band_summary(bands),
    }
