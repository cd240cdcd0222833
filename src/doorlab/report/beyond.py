"""The report's comparison beyond the problem set: differential IK with limits (``diffik``) and
operational-space control (``osc``) against the problem set's three, doors open and closed.

:func:`comparison_context` builds the section's table (each cell a fact tied to its run and
metrics key), its figures and its answer (:class:`~doorlab.report.prose.Answer`): what each of
the two changes, and why, from the runs and from the controllers' model of the arm (its mass
matrix, Jacobian and the inner loop's joint damping at a measured configuration).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from doorlab.outputs.pages import EmbeddedFigure
from doorlab.report.context import AnswerPage, ratio_phrase
from doorlab.report.experiments import BEYOND
from doorlab.report.folders import LoadedRun
from doorlab.report.prose import (
    K_D,
    K_P,
    K_V,
    K_W,
    V_DES,
    Answer,
    Num,
    Paragraph,
    code,
    count,
    joined,
    number,
    para,
    strong,
    sup,
)

COMPARED = ("ik", "velocity", "impedance", *BEYOND)
"""The controllers of the comparison, in table order (IK with 10 knots)."""
COLUMNS = (
    ("max_radial_error_m", "max radial error [mm]"),
    ("rms_radial_error_m", "RMS radial error [mm]"),
    ("max_orientation_error_rad", "L7's max orientation error [deg]"),
    ("door_opening_arc_end_rad", "door at the arc's end [deg]"),
    ("door_lag_max_rad", "door lag [deg]"),
    ("peak_external_torque_arc_Nm", "peak contact torque in the arc [N m]"),
)
"""The table's metrics (metrics.json keys) and headers."""
SCALED_BELOW = 0.999
"""diffik's QP counts as having scaled V_des down at a tick when |J v| / |V_des| is below this."""


def run_name(controller: str, doors: str) -> str:
    """The experiment holding ``controller`` with ``doors`` (IK: 10 knots)."""
    return f"ik_10_{doors}" if controller == "ik" else f"{controller}_{doors}"


@dataclass(frozen=True)
class ComparisonRow:
    """One run of the comparison table.

    Attributes:
        run: The run's name. folder: Its folder, relative to the page. label: What it is.
        cells: One fact per :data:`COLUMNS` entry (n/a where not measured). held: "yes", "no"
            or "n/a" (doors open: no handle to hold). css: The row's class ("" when ok).
    """

    run: str
    folder: str
    label: str
    cells: tuple[Num, ...]
    held: str
    css: str


@dataclass(frozen=True)
class Comparison:
    """The section: table rows, figures and the generated answer."""

    headers: tuple[str, ...]
    rows: tuple[ComparisonRow, ...]
    figures: tuple[EmbeddedFigure, ...]
    answer: Answer


def comparison_context(page: AnswerPage, out_dir: Path) -> Comparison | None:
    """The comparison section from the page's runs; None when no diffik or osc run is there."""
    names = [run_name(c, d) for c in COMPARED for d in ("open", "closed")]
    if not any(run_name(c, d) in page.runs for c in BEYOND for d in ("open", "closed")):
        return None
    rows = []
    for name in names:
        run = page.runs.get(name)
        if run is None:
            continue
        held = run.metrics.get("handle_held")
        rows.append(
            ComparisonRow(
                name,
                os.path.relpath(run.record.run_dir, out_dir),
                run.label,
                tuple(page.num(name, key) for key, _ in COLUMNS),
                "n/a" if held is None else ("yes" if held else "no"),
                "" if run.status == "ok" else ("warn" if run.has_logs else "failed"),
            )
        )
    figures: list[EmbeddedFigure] = []
    for doors in ("open", "closed"):
        runs = page.logged(*(run_name(c, doors) for c in COMPARED))
        what = f"the five controllers, doors {doors}"
        figures += page.tracking_figures(f"beyond_{doors}", runs, what)
        if doors == "closed":
            figures += page.door_figure("beyond_closed", runs, what)
            figures += page.torque_figure("beyond_closed", runs, what)
    paragraphs = [
        page.missing(*(run_name(c, d) for c in BEYOND for d in ("open", "closed"))),
        *_diffik_paragraphs(page),
        *_osc_paragraphs(page),
        _contact_paragraph(page),
        page.status_note(*(run_name(c, d) for c in BEYOND for d in ("open", "closed"))),
    ]
    answer = Answer(tuple(figures), tuple(p for p in paragraphs if p is not None))
    return Comparison(tuple(h for _, h in COLUMNS), tuple(rows), tuple(figures), answer)


# diffik against the velocity plan ----------------------------------------------------------


def _qp_scale(run: LoadedRun) -> tuple[int, int, float] | None:
    """(ticks in the arc where the QP scaled V_des down, ticks in the arc, the least scale)."""
    log = run.result.plan_log if run.result is not None else {}
    if "scale" not in log:
        return None
    t0, t1 = run.result.arc_window
    in_arc = (log["t"] >= t0) & (log["t"] <= t1)
    scale = log["scale"][in_arc]
    scale = scale[np.isfinite(scale)]
    if not len(scale):
        return None
    return int(np.sum(scale < SCALED_BELOW)), len(scale), float(np.min(scale))


def _diffik_paragraphs(page: AnswerPage) -> list[Paragraph | None]:
    """diffik against the velocity plan: errors, the QP's limits, q_ref, the closed door."""
    if not page.logged("diffik_open", "velocity_open"):
        return []
    pair = len(page.logged("diffik_open", "velocity_open")) == 2
    return [
        _diffik_errors(page) if pair else None,
        _diffik_qp(page) if page.logged("diffik_open") else None,
        _diffik_q_ref(page) if pair else None,
        _diffik_closed(page) if len(page.logged("diffik_closed", "velocity_closed")) == 2 else None,
    ]


def _diffik_errors(page: AnswerPage) -> Paragraph:
    a = page.value("diffik_open", "max_radial_error_m")
    b = page.value("velocity_open", "max_radial_error_m")
    return para(
        strong("diffik against the velocity plan."),
        " Both ask for the same task velocity ",
        V_DES,
        " = (",
        K_W,
        " θ n, ",
        K_V,
        " e) at every tick. Doors open, diffik's max radial error is ",
        page.num("diffik_open", "max_radial_error_m"),
        ", ",
        ratio_phrase(a, b),
        " the velocity plan's ",
        page.num("velocity_open", "max_radial_error_m"),
        " (RMS ",
        page.num("diffik_open", "rms_radial_error_m"),
        " vs ",
        page.num("velocity_open", "rms_radial_error_m"),
        "); L7's max orientation error ",
        page.num("diffik_open", "max_orientation_error_rad"),
        " vs ",
        page.num("velocity_open", "max_orientation_error_rad"),
        ".",
    )


def _diffik_qp(page: AnswerPage) -> Paragraph | None:
    """Whether the QP's limits bound along the arc (diffik's plan log)."""
    scale = _qp_scale(page.runs["diffik_open"])
    if scale is None:
        return None
    scaled, ticks, least = scale
    if scaled:
        return para(
            "The QP scaled ",
            V_DES,
            " down at ",
            count(scaled),
            " of its ",
            count(ticks),
            " ticks along the arc (least |J v| / |",
            V_DES,
            "| ",
            number(least, digits=3),
            "), keeping the task velocity's direction where the velocity plan's clip turns it.",
        )
    limit = page.runs["diffik_open"].scenario.diffik.joint_speed_limit
    return para(
        "The QP's joint limits never bound along this arc: at none of its ",
        count(ticks),
        " ticks did it scale ",
        V_DES,
        " down (the least |J v| / |",
        V_DES,
        "| was ",
        number(least, digits=4),
        "), so its velocities are J",
        sup("+"),
        " ",
        V_DES,
        "'s, and the velocity plan's clip at ",
        number(limit, "rad/s"),
        " never acted either. What diffik changes here is where q_ref comes from.",
    )


def _diffik_q_ref(page: AnswerPage) -> Paragraph:
    """Where q_ref comes from: diffik's own integrated state, against q + q_dot dt."""
    cmd = page.value("diffik_open", "max_radial_error_cmd_m")
    measured = page.value("diffik_open", "max_radial_error_m")
    parts: list = [
        "diffik integrates its solution into q_ref, q_ref ← q_ref + v dt, and linearizes at "
        "that integrated state (Drake's ",
        code("DifferentialInverseKinematicsIntegrator"),
        "); the velocity plan sets q_ref = q + q̇ dt from the measured q. So diffik's "
        "q_ref stays on the arc whatever the arm does: its forward kinematics is ",
        page.num("diffik_open", "max_radial_error_cmd_m"),
        " off the arc at most (the velocity plan's q_ref: ",
        page.num("velocity_open", "max_radial_error_cmd_m"),
        "), ",
    ]
    if cmd is not None and measured is not None and cmd < 0.25 * measured:
        parts += [
            "and what the arm shows is the inner loop's lag of q behind q_ref: diffik is a "
            "position plan with a knot at every tick. The velocity plan instead needs a "
            "standing task error to keep its q_ref ahead of q (q_ref - q = J",
            sup("+"),
            " ",
            V_DES,
            " dt), which is part of its error.",
        ]
    else:
        parts.append("yet the arm's measured error is of the same order as q_ref's own.")
    return para(parts)


def _diffik_closed(page: AnswerPage) -> Paragraph:
    """The closed door: diffik's lag and contact torque against the velocity plan's."""
    lag_d = page.value("diffik_closed", "door_lag_max_rad")
    lag_v = page.value("velocity_closed", "door_lag_max_rad")
    torque_d = page.value("diffik_closed", "peak_external_torque_arc_Nm")
    torque_v = page.value("velocity_closed", "peak_external_torque_arc_Nm")
    harder = torque_d is not None and torque_v is not None and torque_d > torque_v
    return para(
        "Doors closed, the door trails diffik's plan by up to ",
        page.num("diffik_closed", "door_lag_max_rad"),
        ", ",
        "less than" if (lag_d or 0) < (lag_v or 0) else "no less than",
        " the velocity plan's ",
        page.num("velocity_closed", "door_lag_max_rad"),
        ", and is open ",
        page.num("diffik_closed", "door_opening_arc_end_rad"),
        " at the arc's end (velocity plan: ",
        page.num("velocity_closed", "door_opening_arc_end_rad"),
        "). The peak contact torque in the arc is ",
        page.num("diffik_closed", "peak_external_torque_arc_Nm"),
        " against ",
        page.num("velocity_closed", "peak_external_torque_arc_Nm"),
        ": diffik presses harder. Like IK's spline, its q_ref does not yield to what the door "
        "does (it is integrated from its own state, not from the measured q), so whatever the "
        "door pushes back meets the joints' full stiffness; the velocity plan starts its q_ref "
        "from the measured q at every tick."
        if harder
        else ".",
    )


# osc against the impedance plan -----------------------------------------------------------


@dataclass(frozen=True)
class _ArmAtQ:
    """The controllers' model of the arm at a run's measured configuration halfway along the arc
    (model values, computed from the measured q), and how far Q trailed its reference there
    (measured)."""

    tangent_mass: float  # [kg] 1 / (u^T Lambda^-1 u), u: the arc's tangent
    osc_stiffness: float  # [N/m] u^T Lambda u wn^2: osc's spring along the tangent
    drag: float  # [N] the joints' damping seen at Q, against the arc's speed
    speed: float  # [m/s] the arc's speed at Q
    impedance_lag: float  # [m] the lag at which the impedance plan's spring gives that drag
    osc_lag: float  # [m] ... osc's, without its damping term
    measured_lag: float  # [m] |p_WQ - p_WQ_ref| there, from the run's log


def _arm_at_q(run: LoadedRun) -> _ArmAtQ | None:
    """The model at ``run``'s measured configuration halfway along the arc."""
    from pydrake.multibody.tree import JacobianWrtVariable

    from doorlab.cell.frames import L7_FRAME, p_L7Q
    from doorlab.cell.station import STIFFNESS_LOOPS, joint_damping, make_controller_plant

    result, scenario, tracking = run.result, run.scenario, run.tracking
    if result is None or scenario is None or run.geometry is None or tracking is None:
        return None
    if scenario.station.inner_loop.kind not in STIFFNESS_LOOPS:
        return None
    k = int(np.argmin(np.abs(tracking.tau - 0.5)))
    i = int(np.argmin(np.abs(result.t - tracking.t[k])))
    plant = make_controller_plant()
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, result.q_measured[i])
    L7, W = plant.GetFrameByName(L7_FRAME), plant.world_frame()
    J = plant.CalcJacobianSpatialVelocity(context, JacobianWrtVariable.kV, L7, p_L7Q, W, W)
    M = plant.CalcMassMatrix(context)
    D = joint_damping(scenario.station)
    V = run.geometry.V_WQ_ref(0.5, scenario.timeline.arc_duration)
    speed = float(np.linalg.norm(V[3:]))
    u = np.concatenate((np.zeros(3), V[3:] / speed))
    mobility = J @ np.linalg.solve(M, J.T)  # Lambda^-1
    Lambda = np.linalg.inv(mobility)
    wn = scenario.osc.wn_translation
    # Moving Q with the arc's spatial velocity V against the joints' damping alone (no
    # acceleration) takes the task force (J D^-1 J^T)^-1 V.
    drag_force = np.linalg.solve(J @ np.diag(1.0 / D) @ J.T, V)
    stiffness = np.diag([scenario.impedance.kw] * 3 + [scenario.impedance.kv] * 3)
    return _ArmAtQ(
        tangent_mass=float(1.0 / (u @ mobility @ u)),
        osc_stiffness=float(u @ Lambda @ u) * wn**2,
        drag=float(np.linalg.norm(drag_force[3:])),
        speed=speed,
        impedance_lag=float(np.linalg.norm(np.linalg.solve(stiffness, drag_force)[3:])),
        osc_lag=float(np.linalg.norm(np.linalg.solve(wn**2 * Lambda, drag_force)[3:])),
        measured_lag=float(
            np.linalg.norm(tracking.p_WQ[k] - run.geometry.p_WQ_ref(float(tracking.tau[k])))
        ),
    )


def _osc_paragraphs(page: AnswerPage) -> list[Paragraph | None]:
    """osc against the impedance plan: the law and the errors, why (the model), the door."""
    if len(page.logged("osc_open", "impedance_open")) < 2:
        return []
    closed = len(page.logged("osc_closed", "impedance_closed")) == 2
    return [_osc_law(page), _osc_why(page), _osc_closed(page) if closed else None]


def _osc_law(page: AnswerPage) -> Paragraph:
    osc, imp = page.runs["osc_open"], page.runs["impedance_open"]
    a = page.value("osc_open", "max_radial_error_m")
    b = page.value("impedance_open", "max_radial_error_m")
    config = osc.scenario.osc
    return para(
        strong("osc against the impedance plan."),
        " Both send q_ref = q and a torque; the impedance plan's is J",
        sup("T"),
        " (K e) with fixed springs (",
        K_V,
        " = ",
        number(imp.scenario.impedance.kv, "N/m"),
        "), osc's is J",
        sup("T"),
        " Λ (a_ref + ",
        K_P,
        " e + ",
        K_D,
        " ė) with Λ = (J M",
        sup("-1"),
        " J",
        sup("T"),
        ")",
        sup("-1"),
        " from the controller plant's M(q), plus the Coriolis terms and the inner loop's "
        "joint damping in the task's directions (",
        number(100 * config.damping_compensation, "%"),
        " of it), ",
        K_P,
        " = ω",
        sup("2"),
        ", ",
        K_D,
        " = 2ζω with ω = ",
        number(config.wn_translation, "rad/s"),
        " (rotation ",
        number(config.wn_rotation, "rad/s"),
        "), ζ = ",
        number(config.zeta),
        ": the error obeys ë + ",
        K_D,
        " ė + ",
        K_P,
        " e = 0 in every direction and configuration (by design, with the model exact). "
        "Doors open, osc's max radial error is ",
        page.num("osc_open", "max_radial_error_m"),
        ", ",
        ratio_phrase(a, b),
        " the impedance plan's ",
        page.num("impedance_open", "max_radial_error_m"),
        "; L7's max orientation error ",
        page.num("osc_open", "max_orientation_error_rad"),
        " vs ",
        page.num("impedance_open", "max_orientation_error_rad"),
        ".",
    )


def _osc_why(page: AnswerPage) -> Paragraph | None:
    """The joints' damping seen at Q against each spring, from the model at each run's q."""
    imp = page.runs["impedance_open"]
    at_imp, at_osc = _arm_at_q(imp), _arm_at_q(page.runs["osc_open"])
    if at_imp is None or at_osc is None:
        return None
    kv = imp.scenario.impedance.kv
    return para(
        "Why, from the controllers' model at each run's measured configuration halfway "
        "along the arc: the inner loop's joint damping, seen at Q, resists the arc's ",
        number(1e3 * at_imp.speed, "mm/s"),
        " with ",
        number(at_imp.drag, "N"),
        "; the impedance plan's ",
        number(kv, "N/m"),
        " spring gives that force only ",
        number(1e3 * at_imp.impedance_lag, "mm"),
        " behind its reference (the steady state), and the run trails it by ",
        number(1e3 * at_imp.measured_lag, "mm"),
        " there. Along the arc's tangent the arm shows an effective mass of ",
        number(at_osc.tangent_mass, "kg"),
        ", and osc's Λ ω",
        sup("2"),
        " is a spring of ",
        number(at_osc.osc_stiffness, "N/m"),
        " there, ",
        number(at_osc.osc_stiffness / kv),
        " times the impedance plan's: against the same damping it would trail by ",
        number(1e3 * at_osc.osc_lag, "mm"),
        "; with the damping put back in the task's directions, the run trails its reference by ",
        number(1e3 * at_osc.measured_lag, "mm"),
        " there.",
    )


def _osc_closed(page: AnswerPage) -> Paragraph:
    return para(
        "Doors closed, the door trails osc's plan by up to ",
        page.num("osc_closed", "door_lag_max_rad"),
        " (impedance: ",
        page.num("impedance_closed", "door_lag_max_rad"),
        ") and is open ",
        page.num("osc_closed", "door_opening_arc_end_rad"),
        " at the arc's end (impedance: ",
        page.num("impedance_closed", "door_opening_arc_end_rad"),
        ").",
    )


def _contact_paragraph(page: AnswerPage) -> Paragraph | None:
    """The five controllers' peak contact torque in the arc, doors closed, ranked, against their
    free-space radial errors."""
    key = "peak_external_torque_arc_Nm"
    runs = [
        r
        for r in page.logged(*(run_name(c, "closed") for c in COMPARED))
        if page.value(r.name, key) is not None
    ]
    if len(runs) < 2:
        return None
    ranked = sorted(runs, key=lambda r: page.value(r.name, key))
    free = {
        r.name: page.value(r.name.replace("_closed", "_open"), "max_radial_error_m")
        if r.name.replace("_closed", "_open") in page.runs
        else None
        for r in ranked
    }
    parts: list = [
        strong("Contact torques, doors closed."),
        " Peak |external joint torque| in the arc: ",
        joined(([f"{r.label} ", page.num(r.name, key)] for r in ranked), " < "),
        ". ",
    ]
    known = [free[r.name] for r in ranked if free[r.name] is not None]
    if len(known) == len(ranked):
        swapped = [
            (a, b) for a, b in zip(ranked, ranked[1:], strict=False) if free[a.name] > free[b.name]
        ]
        parts += [
            "Their free-space max radial errors, in the same order: ",
            joined(
                page.num(r.name.replace("_closed", "_open"), "max_radial_error_m") for r in ranked
            ),
            ". The ranking follows how far each plan leaves the handle's circle when nothing "
            "holds it",
            [
                ", but for ",
                joined(
                    (f"{a.label.split(',')[0]} before {b.label.split(',')[0]}" for a, b in swapped),
                    "; ",
                ),
            ]
            if swapped
            else "",
            ": the hinge holds Q on the circle against the plan's own mismatch with it, and "
            "what is left is the door's inertia and hinge damping.",
        ]
    return para(parts)


def comparison_summary(page: AnswerPage, comparison: Comparison) -> dict:
    """The section for summary.json: per run, the columns' metrics as metrics.json has them (SI),
    and the answer's paragraphs as Markdown."""
    rows = [
        {
            "run": row.run,
            "controller": page.runs[row.run].metrics.get("controller"),
            "doors": page.runs[row.run].metrics.get("doors"),
            "handle_held": page.runs[row.run].metrics.get("handle_held"),
            **{key: page.value(row.run, key) for key, _ in COLUMNS},
        }
        for row in comparison.rows
    ]
    return {"rows": rows, "answer_markdown": [p.markdown for p in comparison.answer.paragraphs]}
