"""The problem set's six questions and their answers, GENERATED from the measured metrics and logs.

Each answer function takes the :class:`~doorlab.report.context.AnswerPage` and returns
(figures HTML, answer HTML); the page template places them under the quoted question.
"""

from __future__ import annotations

import html
import math

from doorlab.outputs.pages import format_number
from doorlab.report.closed_door import closed_sentence, contact_paragraph, damping_paragraph
from doorlab.report.context import (
    AnswerPage,
    door_lag_deg,
    knot_profile,
    order_phrase,
    ratio_phrase,
    side,
    signed_range_mm,
    span,
    tau_of_max,
)
from doorlab.report.experiments import IK_KNOTS
from doorlab.report.folders import LoadedRun

QUESTIONS: tuple[tuple[str, int, str], ...] = (
    (
        "t1q1",
        1,
        "With the doors open, generate tracking error plots for trajectories with 2, 5 and 10 "
        "knot points. How does the number of knot points affect tracking error?",
    ),
    (
        "t1q2",
        1,
        "Zoom in to the xy position plot of Q. Is the magnitude of tracking error consistent "
        "along the arc with the doors open? Why do you think the error is (in)consistent? What "
        "happens if the doors are closed?",
    ),
    (
        "t2q1",
        2,
        "Generate tracking error plots with the doors open. How does the tracking error compare "
        "with the trajectory generated from IK? (Hint: tracking error should be smaller)",
    ),
    (
        "t2q2",
        2,
        "Zoom in to the xy position plot of Q. Is the magnitude of tracking error consistent "
        "along the arc with the doors open? Why do you think the error is (in)consistent? What "
        "happens if the doors are closed? (Hint: error along the arc should be smaller and more "
        "consistent).",
    ),
    (
        "t3q1",
        3,
        "Generate tracking error plots with the doors open. How does the tracking error compare "
        "with the other approaches?",
    ),
    (
        "t3q2",
        3,
        "Generate tracking error plots with the doors closed. How does closing the door affect "
        "tracking error?",
    ),
)
"""The problem set's six questions, quoted: (id, task, text)."""

TASK_TITLES = {
    1: "Task 1: pointwise IK and a cubic joint spline",
    2: "Task 2: Jacobian pseudo-inverse velocity mapping",
    3: "Task 3: Jacobian-transpose impedance",
}


def _answer_t1q1(page: AnswerPage) -> tuple[str, str]:
    names = [f"ik_{k}_open" for k in IK_KNOTS]
    runs = page.logged(*names)
    figs = page.tracking_figures("t1q1", runs, "IK, doors open, 2 / 5 / 10 knots")
    text = page.missing(*names)
    if runs:
        knots = [r.scenario.ik.knots for r in runs]
        max_e = [page.value(r.name, "max_radial_error_m") for r in runs]
        phrase = (order_phrase(max_e) + " as knots are added") if len(runs) > 1 else "is"
        listing = ", ".join(
            f"{page.num(r.name, 'max_radial_error_m')} with {k} knots"
            for r, k in zip(runs, knots, strict=True)
        )
        rms = ", ".join(page.num(r.name, "rms_radial_error_m") for r in runs)
        ori = ", ".join(page.num(r.name, "max_orientation_error_rad") for r in runs)
        text += (
            f"<p>The max radial error of Q {phrase}: {listing} "
            f"(RMS {rms}; max orientation error {ori}).</p>"
        )
        cmd = ", ".join(page.num(r.name, "max_radial_error_cmd_m") for r in runs)
        gaps = [
            abs(
                (page.value(r.name, "max_radial_error_m") or 0)
                - (page.value(r.name, "max_radial_error_cmd_m") or 0)
            )
            for r in runs
        ]
        share = (
            max(g / m for g, m in zip(gaps, max_e, strict=True) if m and m > 0)
            if any(m for m in max_e)
            else float("nan")
        )
        text += (
            "<p>From the commanded q_ref alone (what the problem set plotted) the max radial "
            f"errors are {cmd}: the measured and commanded maxima differ by at most "
            f"{span(format_number(100 * share))} %, so "
            + (
                "the error is the plan's own: between knots the cubic spline interpolates joint "
                "angles, and the forward kinematics of interpolated joint angles is not a circle "
                "in the task space. The inner loop adds little."
                if share < 0.25
                else "a large part of the error comes from the inner loop's lag, not from the plan."
            )
            + "</p>"
        )
        if len(runs) >= 2 and all(m and m > 0 for m in max_e):
            sweep = math.degrees(runs[0].geometry.sweep)
            steps = [sweep / (k - 1) for k in knots]
            orders = [
                (i, math.log(max_e[i] / max_e[i + 1]) / math.log(steps[i] / steps[i + 1]))
                for i in range(len(runs) - 1)
                if steps[i] != steps[i + 1]
            ]
            spacing = ", ".join(
                f"{span(format_number(s))} deg with {k} knots"
                for s, k in zip(steps, knots, strict=True)
            )
            steps_text = "; ".join(
                f"from {knots[i]} to {knots[i + 1]} knots the error scales like the segment "
                f"length to the power {span(format_number(o, 2))}"
                for i, o in orders
            )
            text += (
                f"<p>More knots shorten each interpolated segment of the arc ({spacing}): "
                f"{steps_text}. A power near 2 is the chord-like bulge of the spline between "
                "knots (a sagitta scales with the square of the chord); a power near 0 means the "
                "error has reached a floor that more knots do not remove"
                + (
                    "; a negative power means more knots made the error larger"
                    if any(o < 0 for _, o in orders)
                    else ""
                )
                + ".</p>"
            )
        tol = runs[-1].scenario.ik.position_tolerance
        last = max_e[-1]
        if last is not None and tol and last < 3 * tol:
            text += (
                f"<p>With {knots[-1]} knots the max error "
                f"({page.num(runs[-1].name, 'max_radial_error_m')}) is within 3 times the IK "
                f"position tolerance ({span(format_number(1000 * tol))} mm, a box around each "
                "knot's arc point): more knots cannot push the error far below that tolerance."
                "</p>"
            )
        text += page.status_note(*names)
    return figs, text


def _answer_t1q2(page: AnswerPage) -> tuple[str, str]:
    names = [f"ik_{k}_open" for k in IK_KNOTS]
    runs = page.logged(*names)
    figs = page.path_figure("t1q2", runs, "IK, doors open, 2 / 5 / 10 knots")
    pair = page.logged("ik_10_open", "ik_10_closed")
    if len(pair) == 2:
        figs += page.path_figure("t1q2_closed", pair, "IK 10 knots, doors open vs closed")
    closed = page.logged("ik_10_closed")
    if closed:
        figs += page.door_figure("t1q2", closed, "IK 10 knots, doors closed")
    text = page.missing(*names, "ik_10_closed")
    bulging, floor = [], []
    for run in runs:
        profile = knot_profile(run)
        if profile is None:
            continue
        at_knots, peaks = profile
        worst = max(peaks)
        sign = side(run.tracking)
        k = run.scenario.ik.knots
        segments = "segment" if k == 2 else f"{k - 1} segments"
        ratio = worst / max(at_knots, 1e-9)
        consistent = ratio <= 3.0
        (floor if consistent else bulging).append(run)
        text += (
            f"<p>{html.escape(run.label)}: |error| is at most "
            f"{span(format_number(at_knots))} mm at the {k} knots and peaks at "
            f"{span(format_number(worst))} mm between them (largest excursion {sign} the arc). "
            + (
                f"The peaks of the {segments} range from {span(format_number(min(peaks)))} to "
                f"{span(format_number(max(peaks)))} mm. "
                if k > 2
                else ""
            )
            + (
                "The error is <b>not consistent</b> along the arc: small at the knots, a bulge "
                f"between them ({span(format_number(ratio))} times larger)."
                if not consistent
                else "The error is <b>roughly consistent</b> along the arc: the peaks between "
                f"knots are within {span(format_number(ratio))} times the error at the knots."
            )
            + "</p>"
        )
    if runs:
        tol = runs[0].scenario.ik.position_tolerance if runs[0].scenario else float("nan")
        why = (
            "<p>Why: IK puts Q on the arc only at the knots; between them the plan is a cubic "
            "spline in joint space, whose forward kinematics is not the circle, so the error "
            "bulges between knots, more for longer segments."
        )
        if bulging:
            why += (
                " With "
                + ", ".join(html.escape(r.label) for r in bulging)
                + " this bulge dominates."
            )
        if floor:
            why += (
                " With "
                + ", ".join(html.escape(r.label) for r in floor)
                + " the bulge has shrunk below the error the IK leaves at the knots themselves: "
                f"each knot may sit anywhere in a box of &plusmn;{span(format_number(1000 * tol))}"
                " mm around its arc point (the IK position tolerance), so the error wanders "
                "from knot to knot rather than growing between them."
            )
        text += why + "</p>"
    if closed:
        text += closed_sentence(page, "ik_10_closed", "ik_10_open")
        text += page.status_note("ik_10_closed")
    return figs, text


def _reference_ik(page: AnswerPage) -> LoadedRun | None:
    """The IK run the other controllers are compared with: the most knots, doors open."""
    runs = page.logged(*(f"ik_{k}_open" for k in reversed(IK_KNOTS)))
    return runs[0] if runs else None


def _answer_t2q1(page: AnswerPage) -> tuple[str, str]:
    iks = page.logged(*(f"ik_{k}_open" for k in reversed(IK_KNOTS)))
    figs = page.tracking_figures(
        "t2q1", page.logged("velocity_open") + iks[:2], "velocity plan vs IK, doors open"
    )
    text = page.missing("velocity_open", "ik_10_open")
    ref = _reference_ik(page)
    if page.logged("velocity_open") and ref is not None:
        v = page.value("velocity_open", "max_radial_error_m")
        sentences = [
            f"{ratio_phrase(v, page.value(ik.name, 'max_radial_error_m'))} the "
            f"{page.num(ik.name, 'max_radial_error_m')} of {html.escape(ik.label)}"
            for ik in iks
        ]
        tau_max = tau_of_max(page.runs["velocity_open"].tracking)
        where = (
            f" (reached at {span(format_number(100 * tau_max))} % of the arc: the start "
            "transient, while the arm picks up speed)"
            if tau_max < 0.1
            else ""
        )
        text += (
            "<p>The velocity plan's max radial error is "
            f"{page.num('velocity_open', 'max_radial_error_m')}{where}: "
            + "; ".join(sentences)
            + ". "
            f"RMS: {page.num('velocity_open', 'rms_radial_error_m')} vs "
            f"{page.num(ref.name, 'rms_radial_error_m')} ({html.escape(ref.label)}). Max "
            f"orientation error: {page.num('velocity_open', 'max_orientation_error_rad')} vs "
            f"{page.num(ref.name, 'max_orientation_error_rad')}.</p>"
        )
        larger = [
            ik
            for ik in iks
            if v is not None and v >= (page.value(ik.name, "max_radial_error_m") or math.inf)
        ]
        if v is not None and not larger:
            text += (
                "<p>This agrees with the problem set's hint (the error should be smaller): the "
                "velocity plan closes the loop on Q's task-space error at every control "
                "step, q_dot = J<sup>+</sup> (K<sub>w</sub> &theta; n, K<sub>v</sub> e), "
                "so it follows the arc itself rather than a joint-space interpolation of "
                "a few points on it.</p>"
            )
        elif larger:
            text += (
                '<p class="contradiction">This contradicts the problem set\'s hint: here the '
                "velocity plan's max radial error is not smaller than that of "
                + ", ".join(html.escape(ik.label) for ik in larger)
                + ".</p>"
            )
        text += page.status_note("velocity_open", ref.name)
    return figs, text


def _answer_t2q2(page: AnswerPage) -> tuple[str, str]:
    ref = _reference_ik(page)
    pair = page.logged("velocity_open") + ([ref] if ref else [])
    figs = page.path_figure("t2q2", pair, "velocity plan vs " + (ref.label if ref else "IK"))
    oc = page.logged("velocity_open", "velocity_closed")
    if len(oc) == 2:
        figs += page.path_figure("t2q2_closed", oc, "velocity plan, doors open vs closed")
    if page.logged("velocity_closed"):
        figs += page.door_figure(
            "t2q2", page.logged("velocity_closed"), "velocity plan, doors closed"
        )
    text = page.missing("velocity_open", "ik_10_open", "velocity_closed")
    if page.logged("velocity_open"):
        run = page.runs["velocity_open"]
        lo, hi = signed_range_mm(run.tracking)
        text += (
            f"<p>Along the arc (after the first 5 % of it) the velocity plan's signed radial "
            f"error stays between {span(format_number(lo))} and {span(format_number(hi))} mm, "
            f"a spread of {span(format_number(hi - lo))} mm"
        )
        if ref is not None:
            ilo, ihi = signed_range_mm(ref.tracking)
            spread, ispread = hi - lo, ihi - ilo
            text += (
                f"; for {html.escape(ref.label)} it spans {span(format_number(ilo))} to "
                f"{span(format_number(ihi))} mm (spread {span(format_number(ispread))} mm). "
            )
            if spread < ispread:
                text += (
                    "The velocity plan's error is smaller and more consistent along the arc, as "
                    "the problem set's hint says: there are no knots, the error is corrected "
                    "continuously, and what remains varies slowly (the inner loop's lag and the "
                    "arm's changing configuration).</p>"
                )
            else:
                text += (
                    '</p><p class="contradiction">This contradicts the problem set\'s hint: the '
                    "velocity plan's error along the arc does not vary less than that of "
                    f"{html.escape(ref.label)} here.</p>"
                )
        else:
            text += ".</p>"
    if page.logged("velocity_closed"):
        text += closed_sentence(page, "velocity_closed", "velocity_open")
        text += page.status_note("velocity_closed")
    return figs, text


def _answer_t3q1(page: AnswerPage) -> tuple[str, str]:
    ref = _reference_ik(page)
    names = ("impedance_open", "velocity_open", ref.name if ref else "ik_10_open")
    runs = page.logged(*names)
    figs = page.tracking_figures("t3q1", runs, "the three controllers, doors open")
    text = page.missing(*names)
    if page.logged("impedance_open") and len(runs) >= 2:
        ranked = sorted(runs, key=lambda r: page.value(r.name, "max_radial_error_m") or math.inf)
        text += (
            "<p>Ranked by max radial error, doors open: "
            + " &lt; ".join(
                f"{html.escape(r.label)} ({page.num(r.name, 'max_radial_error_m')})" for r in ranked
            )
            + ". By RMS: "
            + ", ".join(
                f"{html.escape(r.label)} {page.num(r.name, 'rms_radial_error_m')}" for r in runs
            )
            + ". By max orientation error: "
            + ", ".join(
                f"{html.escape(r.label)} {page.num(r.name, 'max_orientation_error_rad')}"
                for r in runs
            )
            + ".</p>"
        )
        imp = page.runs["impedance_open"]
        kv = imp.scenario.impedance.kv if imp.scenario else float("nan")
        e = page.value("impedance_open", "max_radial_error_m")
        if e is not None:
            text += (
                "<p>The impedance plan commands no joint positions along the path (q_ref = the "
                "measured q) and no feedforward for the motion: Q is pulled towards its moving "
                "reference only by a Cartesian spring of K<sub>v</sub> = "
                f"{span(format_number(kv))} N/m, which has to drag the arm against the inner "
                "loop's joint damping (D<sub>q</sub> q&#775;, and the stiffness term acting on a "
                "q_ref one control period old). So Q lags its reference and drifts "
                f"{side(imp.tracking)} the arc: the max error of "
                f"{page.num('impedance_open', 'max_radial_error_m')} is a spring force of about "
                f"{span(format_number(kv * e))} N. The position-commanding plans do not need a "
                "force to move, so their error does not scale with 1/K<sub>v</sub>.</p>"
            )
        text += page.status_note(*names)
    return figs, text


def _answer_t3q2(page: AnswerPage) -> tuple[str, str]:
    pair = page.logged("impedance_open", "impedance_closed")
    figs = page.tracking_figures("t3q2", pair, "impedance plan, doors open vs closed")
    closed_all = page.logged("ik_10_closed", "velocity_closed", "impedance_closed")
    figs += page.door_figure("t3q2", closed_all, "doors closed, the three controllers")
    figs += page.torque_figure("t3q2", pair, "impedance plan, doors open vs closed")
    text = page.missing("impedance_open", "impedance_closed")
    if page.logged("impedance_closed"):
        text += closed_sentence(page, "impedance_closed", "impedance_open", explain=False)
        a = page.value("impedance_closed", "max_radial_error_m")
        b = page.value("impedance_open", "max_radial_error_m")
        if a is not None and b is not None:
            effect = "raises" if a > b else ("lowers" if a < b else "does not change")
            text += (
                f"<p>So closing the door {effect} the impedance plan's max radial error "
                f"({page.num('impedance_open', 'max_radial_error_m')} open, "
                f"{page.num('impedance_closed', 'max_radial_error_m')} closed). "
            )
            if page.value("impedance_closed", "slip_time_s") is not None:
                text += (
                    "But the handle slipped out of the gripper during the closed-door run, so "
                    "this comparison does not isolate the door's effect.</p>"
                )
            elif a < b:
                lag = door_lag_deg(page.runs["impedance_closed"])
                text += (
                    "With the doors open the soft spring lets Q drift off the arc while it "
                    "lags; with the door closed the hinge holds the handle, and so Q, on the "
                    "circle, and the same lag appears along the arc instead: the door trails the "
                    f"plan by up to {span(format_number(lag))} deg (door angle plot), while the "
                    "orientation error "
                    + (
                        "grows"
                        if (page.value("impedance_closed", "max_orientation_error_rad") or 0)
                        > (page.value("impedance_open", "max_orientation_error_rad") or 0)
                        else "does not grow"
                    )
                    + ". The radial error measures only the distance from the circle.</p>"
                )
            else:
                text += (
                    "With a soft task-space spring, the force the door needs at the handle "
                    "(its inertia and hinge damping) shows up as position error, force = "
                    "K<sub>v</sub> &times; error.</p>"
                )
        others = [r for r in closed_all if r.name != "impedance_closed"]
        if others:
            text += (
                "<p>Doors closed, all controllers: "
                + ", ".join(
                    f"{html.escape(r.label)} {page.num(r.name, 'max_radial_error_m')} max radial "
                    f"error, door at the arc's end {page.num(r.name, 'door_opening_arc_end_rad')}"
                    for r in closed_all
                )
                + ".</p>"
            )
        text += contact_paragraph(page)
        text += damping_paragraph(page.runs["impedance_closed"])
        text += page.status_note("impedance_closed", "impedance_open")
    return figs, text


ANSWERS = {
    "t1q1": _answer_t1q1,
    "t1q2": _answer_t1q2,
    "t2q1": _answer_t2q1,
    "t2q2": _answer_t2q2,
    "t3q1": _answer_t3q1,
    "t3q2": _answer_t3q2,
}
