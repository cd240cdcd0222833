"""What closing the doors does, as paragraphs generated from the logs: the door's progress and
lag, the grip, the contact torques and the inner loop's damping behind the impedance plan's lag.
"""

from __future__ import annotations

import math

import numpy as np

from doorlab.report.context import AnswerPage, door_lag_deg, ratio_phrase
from doorlab.report.folders import LoadedRun
from doorlab.report.prose import (
    D_Q,
    K_V,
    K_W,
    Paragraph,
    Part,
    code,
    em,
    joined,
    number,
    para,
    strong,
    sup,
)


def closed_sentence(
    page: AnswerPage, closed: str, opened: str, *, explain: bool = True
) -> Paragraph:
    """What closing the doors did for one controller: door, error, torques, grip."""
    c = page.runs[closed]
    geometry = c.geometry
    planned = math.degrees(geometry.sweep) if geometry else float("nan")
    opening = page.value(closed, "door_opening_arc_end_rad")
    parts: list[Part | list] = [
        f"With the doors closed ({c.label}) the door had opened by ",
        page.num(closed, "door_opening_arc_end_rad"),
        " at the arc's end, of the ",
        number(planned, "deg"),
        " the arc asks for (",
        page.num(closed, "door_opening_rad"),
        " at the episode's end, after the hold)",
    ]
    if opening is not None and math.isfinite(planned):
        parts += [", i.e. ", number(100.0 * math.degrees(opening) / planned, "%"), " of the sweep."]
    else:
        parts.append(".")
    held = c.metrics.get("handle_held")
    slip = page.value(closed, "slip_time_s")
    if slip is not None:
        parts += [
            " The handle slipped out of the gripper at t = ",
            page.num(closed, "slip_time_s"),
            " (the metrics' status is ",
            strong("slipped"),
            ").",
        ]
    elif held is not None:
        parts.append(
            " The gripper kept the handle to the end."
            if held
            else " The gripper did not hold the handle at the end."
        )
    lag = door_lag_deg(c)
    if lag is not None:
        parts += [
            " Over the arc the door trails the plan's hinge angle by up to ",
            number(lag, "deg"),
            ".",
        ]
    if opened in page.runs and page.runs[opened].has_logs:
        a = page.value(closed, "max_radial_error_m")
        b = page.value(opened, "max_radial_error_m")
        parts += [
            " Its max radial error is ",
            page.num(closed, "max_radial_error_m"),
            ", ",
            ratio_phrase(a, b),
            " the ",
            page.num(opened, "max_radial_error_m"),
            " with the doors open (RMS ",
            page.num(closed, "rms_radial_error_m"),
            " vs ",
            page.num(opened, "rms_radial_error_m"),
            "); max orientation error ",
            page.num(closed, "max_orientation_error_rad"),
            " vs ",
            page.num(opened, "max_orientation_error_rad"),
            ".",
        ]
        if explain:
            parts.append(_why_closed(a, b, slip, lag))
        parts += [
            " The peak external joint torque is ",
            page.num(closed, "peak_external_torque_Nm"),
            " vs ",
            page.num(opened, "peak_external_torque_Nm"),
            " with the doors open: the door pushes back on the arm through the handle.",
        ]
    return para(parts)


def _why_closed(a: float | None, b: float | None, slip: float | None, lag: float | None) -> str:
    """Why the closed door's radial error is what it is: the grip, the circle, the load."""
    if slip is not None:
        return (
            " Once the handle has slipped, Q no longer moves with the door, so the errors "
            "after the slip say little about the controller."
        )
    if a is not None and b is not None and a < b:
        return (
            " Holding the handle, the gripper is carried by the door on the handle's circle: "
            "Q can leave the arc only as far as the grasp gives, so the radial error cannot "
            "grow as in free space"
            + (
                "; the lag shows up along the arc instead (the door angle)."
                if lag is not None and lag > 1.0
                else "."
            )
        )
    if a is not None and b is not None and a > b:
        return (
            " The door's inertia and hinge damping load the arm through the handle, and the "
            "arm yields to that load."
        )
    return ""


def damping_paragraph(run: LoadedRun) -> Paragraph | None:
    """The inner loop's damping behind the impedance plan's lag (issue 12's trade-off)."""
    from doorlab.episode.metrics import joint_damping_ratios

    if run.result is None or run.scenario is None:
        return None
    i0 = int(np.argmin(np.abs(run.result.t - run.result.arc_window[0])))
    zeta = joint_damping_ratios(run.scenario, run.result.q_measured[i0])
    if zeta is None:
        return para(
            "This run used the original station's inverse-dynamics PID: with q_ref = q its "
            "derivative term damps almost nothing, so the impedance plan's J",
            sup("T"),
            " F meets only the arm's inertia.",
        )
    return para(
        "Why the door trails: with q_ref = q the stiffness loop's damping ",
        D_Q,
        " q̇ is all that resists the plan's J",
        sup("T"),
        " F. This run's joint damping ratios at the grasp are ",
        number(float(zeta.min())),
        "-",
        number(float(zeta.max())),
        " (motors' reflected inertia included); more damping leaves the door further behind "
        "at the arc's end, less lets the position plans ring. The measured trade-off over ",
        D_Q,
        " is in doorlab's documentation (",
        em("The model of the cell"),
        ", ",
        em("Inner loop gains"),
        "; ",
        code("benchmarks/inner_loop_sweep.py"),
        ", ",
        code("station.inner_loop.dq_scale"),
        ").",
    )


def contact_paragraph(page: AnswerPage) -> Paragraph | None:
    """Why the three controllers press on the closed door as hard as they do (from the logs)."""
    runs = page.logged("ik_10_closed", "velocity_closed", "impedance_closed")
    key = "peak_external_torque_arc_Nm"
    values = [(r, page.value(r.name, key)) for r in runs]
    values = [(r, v) for r, v in values if v is not None]
    if len(values) < 2:
        return None
    ranked = sorted(values, key=lambda rv: rv[1])
    parts: list = [
        strong("Contact torques."),
        " Peak |external joint torque| during the arc, doors closed (the grasp before the "
        "arc, the same for all, is left out): ",
        joined([[f"{r.label} ", page.num(r.name, key)] for r, _ in ranked], " < "),
        ". ",
    ]
    imp = page.runs.get("impedance_closed")
    if imp is None or imp.result is None or imp.tracking is None or imp.geometry is None:
        return para(parts)
    lowest = ranked[0][0].name == "impedance_closed"
    parts.append(
        "The impedance plan is the softest controller, and it does press the lightest. "
        if lowest
        else "The impedance plan is the softest controller, yet it does not press the lightest. "
    )
    # Where the impedance plan pressed hardest: its spring's stretch and twist.
    result, tracking = imp.result, imp.tracking
    norms = np.linalg.norm(result.tau_external[result.window(*result.arc_window)], axis=1)
    i = min(int(np.argmax(norms)), len(tracking.t) - 1)
    p_ref = np.array([imp.geometry.p_WQ_ref(s) for s in tracking.tau])
    stretch = float(np.linalg.norm(tracking.p_WQ[i] - p_ref[i]))
    kv = imp.scenario.impedance.kv if imp.scenario is not None else float("nan")
    kw = imp.scenario.impedance.kw if imp.scenario is not None else float("nan")
    theta = float(tracking.orientation_error[i])
    parts += [
        "At its peak (t = ",
        number(float(tracking.t[i]), "s"),
        ") it trails its reference by ",
        number(1e3 * stretch, "mm"),
        " and ",
        number(float(np.degrees(theta)), "deg"),
        ", so its task-space spring pulls with ",
        K_V,
        "\u00a0|e| = ",
        number(kv * stretch, "N"),
        " and twists with ",
        K_W,
        "\u00a0θ = ",
        number(kw * theta, "N m"),
        ". That lag comes from the inner loop's joint damping ",
        D_Q,
        ", which is all the spring works against when q_ref = q. ",
    ]
    if page.value("impedance_open", "max_radial_error_m") is not None:
        parts += [
            "Dragged that way in free space, the soft arm drifts ",
            page.num("impedance_open", "max_radial_error_m"),
            " off the handle's circle (impedance, open); with the door closed the hinge holds "
            "Q on the circle instead, and that holding force is the contact torque. ",
        ]
    parts.append(
        "The position-controlled plans (IK, velocity) stay within about a millimetre of the "
        "circle in free space, so the door carries little more than its own inertia and hinge "
        "damping, plus the plan's own mismatch: IK's knots may sit up to 1 mm off the arc, and "
        "the stiff arm pushes that mismatch into the door."
    )
    return para(parts)
