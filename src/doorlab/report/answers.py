"""The problem set's six questions and their answers, GENERATED from the measured metrics and logs.

Each answer function takes the :class:`~doorlab.report.context.AnswerPage` and returns an
:class:`~doorlab.report.prose.Answer` (its figures and its paragraphs of facts and text); the
page template renders it under the quoted question.
"""

from __future__ import annotations

import math

from doorlab.report.closed_door import closed_sentence, contact_paragraph, damping_paragraph
from doorlab.report.context import (
    AnswerPage,
    door_lag_deg,
    knot_profile,
    order_phrase,
    ratio_phrase,
    side,
    signed_range_mm,
    tau_of_max,
)
from doorlab.report.experiments import IK_KNOTS
from doorlab.report.folders import LoadedRun
from doorlab.report.prose import D_Q, K_V, K_W, Answer, Paragraph, joined, number, para, strong, sup

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


class _Builder:
    """An answer being written: figures and paragraphs in page order (None paragraphs, the
    helpers' "nothing to say", are dropped)."""

    def __init__(self) -> None:
        self.figures: list = []
        self.paragraphs: list[Paragraph] = []

    def say(self, *paragraphs: Paragraph | None) -> None:
        self.paragraphs.extend(p for p in paragraphs if p is not None)

    def answer(self) -> Answer:
        return Answer(tuple(self.figures), tuple(self.paragraphs))


def _commanded_paragraph(page: AnswerPage, runs: list[LoadedRun], max_e: list) -> Paragraph:
    """The commanded q_ref's errors against the measured: whose error it is."""
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
    return para(
        "From the commanded q_ref alone (what the problem set plotted) the max radial errors are ",
        joined(page.num(r.name, "max_radial_error_cmd_m") for r in runs),
        ": the measured and commanded maxima differ by at most ",
        number(100 * share, "%"),
        ", so ",
        "the error is the plan's own: between knots the cubic spline interpolates joint "
        "angles, and the forward kinematics of interpolated joint angles is not a circle in "
        "the task space. The inner loop adds little."
        if share < 0.25
        else "a large part of the error comes from the inner loop's lag, not from the plan.",
    )


def _knot_power_paragraph(runs: list[LoadedRun], knots: list[int], max_e: list) -> Paragraph | None:
    """How the error scales with the segment length between knots."""
    if len(runs) < 2 or not all(m and m > 0 for m in max_e):
        return None
    sweep = math.degrees(runs[0].geometry.sweep)
    steps = [sweep / (k - 1) for k in knots]
    orders = [
        (i, math.log(max_e[i] / max_e[i + 1]) / math.log(steps[i] / steps[i + 1]))
        for i in range(len(runs) - 1)
        if steps[i] != steps[i + 1]
    ]
    return para(
        "More knots shorten each interpolated segment of the arc (",
        joined([number(s, "deg"), f" with {k} knots"] for s, k in zip(steps, knots, strict=True)),
        "): ",
        joined(
            (
                [
                    f"from {knots[i]} to {knots[i + 1]} knots the error scales like the "
                    "segment length to the power ",
                    number(o, digits=2),
                ]
                for i, o in orders
            ),
            "; ",
        ),
        ". A power near 2 is the chord-like bulge of the spline between knots (a sagitta "
        "scales with the square of the chord); a power near 0 means the error has reached "
        "a floor that more knots do not remove",
        "; a negative power means more knots made the error larger"
        if any(o < 0 for _, o in orders)
        else "",
        ".",
    )


def _answer_t1q1(page: AnswerPage) -> Answer:
    names = [f"ik_{k}_open" for k in IK_KNOTS]
    runs = page.logged(*names)
    out = _Builder()
    out.figures += page.tracking_figures("t1q1", runs, "IK, doors open, 2 / 5 / 10 knots")
    out.say(page.missing(*names))
    if not runs:
        return out.answer()
    knots = [r.scenario.ik.knots for r in runs]
    max_e = [page.value(r.name, "max_radial_error_m") for r in runs]
    phrase = (order_phrase(max_e) + " as knots are added") if len(runs) > 1 else "is"
    out.say(
        para(
            f"The max radial error of Q {phrase}: ",
            joined(
                [page.num(r.name, "max_radial_error_m"), f" with {k} knots"]
                for r, k in zip(runs, knots, strict=True)
            ),
            " (RMS ",
            joined(page.num(r.name, "rms_radial_error_m") for r in runs),
            "; max orientation error ",
            joined(page.num(r.name, "max_orientation_error_rad") for r in runs),
            ").",
        )
    )
    out.say(_commanded_paragraph(page, runs, max_e), _knot_power_paragraph(runs, knots, max_e))
    tol = runs[-1].scenario.ik.position_tolerance
    last = max_e[-1]
    if last is not None and tol and last < 3 * tol:
        out.say(
            para(
                f"With {knots[-1]} knots the max error (",
                page.num(runs[-1].name, "max_radial_error_m"),
                ") is within 3 times the IK position tolerance (",
                number(1000 * tol, "mm"),
                ", a box around each knot's arc point): more knots cannot push the error far "
                "below that tolerance.",
            )
        )
    out.say(page.status_note(*names))
    return out.answer()


def _knot_profile_paragraph(run: LoadedRun) -> tuple[Paragraph, bool] | None:
    """An IK run's error at its knots and between them; and whether it is consistent along the
    arc (the peaks between knots within 3 times the error at the knots)."""
    profile = knot_profile(run)
    if profile is None:
        return None
    at_knots, peaks = profile
    worst = max(peaks)
    k = run.scenario.ik.knots
    segments = "segment" if k == 2 else f"{k - 1} segments"
    ratio = worst / max(at_knots, 1e-9)
    consistent = ratio <= 3.0
    return (
        para(
            f"{run.label}: |error| is at most ",
            number(at_knots, "mm"),
            f" at the {k} knots and peaks at ",
            number(worst, "mm"),
            f" between them (largest excursion {side(run.tracking)} the arc). ",
            [
                f"The peaks of the {segments} range from ",
                number(min(peaks)),
                " to ",
                number(max(peaks), "mm"),
                ". ",
            ]
            if k > 2
            else "",
            [
                "The error is ",
                strong("not consistent"),
                " along the arc: small at the knots, a bulge between them (",
                number(ratio),
                " times larger).",
            ]
            if not consistent
            else [
                "The error is ",
                strong("roughly consistent"),
                " along the arc: the peaks between knots are within ",
                number(ratio),
                " times the error at the knots.",
            ],
        ),
        consistent,
    )


def _answer_t1q2(page: AnswerPage) -> Answer:
    names = [f"ik_{k}_open" for k in IK_KNOTS]
    runs = page.logged(*names)
    out = _Builder()
    out.figures += page.path_figure("t1q2", runs, "IK, doors open, 2 / 5 / 10 knots")
    pair = page.logged("ik_10_open", "ik_10_closed")
    if len(pair) == 2:
        out.figures += page.path_figure("t1q2_closed", pair, "IK 10 knots, doors open vs closed")
    closed = page.logged("ik_10_closed")
    if closed:
        out.figures += page.door_figure("t1q2", closed, "IK 10 knots, doors closed")
    out.say(page.missing(*names, "ik_10_closed"))
    bulging, floor = [], []
    for run in runs:
        profiled = _knot_profile_paragraph(run)
        if profiled is None:
            continue
        paragraph, consistent = profiled
        (floor if consistent else bulging).append(run)
        out.say(paragraph)
    if runs:
        tol = runs[0].scenario.ik.position_tolerance if runs[0].scenario else float("nan")
        out.say(
            para(
                "Why: IK puts Q on the arc only at the knots; between them the plan is a cubic "
                "spline in joint space, whose forward kinematics is not the circle, so the error "
                "bulges between knots, more for longer segments.",
                [
                    " With ",
                    ", ".join(r.label for r in bulging),
                    " this bulge dominates.",
                ]
                if bulging
                else "",
                [
                    " With ",
                    ", ".join(r.label for r in floor),
                    " the bulge has shrunk below the error the IK leaves at the knots themselves: "
                    "each knot may sit anywhere in a box of ±",
                    number(1000 * tol, "mm"),
                    " around its arc point (the IK position tolerance), so the error wanders from "
                    "knot to knot rather than growing between them.",
                ]
                if floor
                else "",
            )
        )
    if closed:
        out.say(closed_sentence(page, "ik_10_closed", "ik_10_open"))
        out.say(page.status_note("ik_10_closed"))
    return out.answer()


def _reference_ik(page: AnswerPage) -> LoadedRun | None:
    """The IK run the other controllers are compared with: the most knots, doors open."""
    runs = page.logged(*(f"ik_{k}_open" for k in reversed(IK_KNOTS)))
    return runs[0] if runs else None


def _answer_t2q1(page: AnswerPage) -> Answer:
    iks = page.logged(*(f"ik_{k}_open" for k in reversed(IK_KNOTS)))
    out = _Builder()
    out.figures += page.tracking_figures(
        "t2q1", page.logged("velocity_open") + iks[:2], "velocity plan vs IK, doors open"
    )
    out.say(page.missing("velocity_open", "ik_10_open"))
    ref = _reference_ik(page)
    if not (page.logged("velocity_open") and ref is not None):
        return out.answer()
    v = page.value("velocity_open", "max_radial_error_m")
    tau_max = tau_of_max(page.runs["velocity_open"].tracking)
    out.say(
        para(
            "The velocity plan's max radial error is ",
            page.num("velocity_open", "max_radial_error_m"),
            [
                " (reached at ",
                number(100 * tau_max, "%"),
                " of the arc: the start transient, while the arm picks up speed)",
            ]
            if tau_max < 0.1
            else "",
            ": ",
            joined(
                (
                    [
                        ratio_phrase(v, page.value(ik.name, "max_radial_error_m")),
                        " the ",
                        page.num(ik.name, "max_radial_error_m"),
                        f" of {ik.label}",
                    ]
                    for ik in iks
                ),
                "; ",
            ),
            ". RMS: ",
            page.num("velocity_open", "rms_radial_error_m"),
            " vs ",
            page.num(ref.name, "rms_radial_error_m"),
            f" ({ref.label}). Max orientation error: ",
            page.num("velocity_open", "max_orientation_error_rad"),
            " vs ",
            page.num(ref.name, "max_orientation_error_rad"),
            ".",
        )
    )
    larger = [
        ik
        for ik in iks
        if v is not None and v >= (page.value(ik.name, "max_radial_error_m") or math.inf)
    ]
    if v is not None and not larger:
        out.say(
            para(
                "This agrees with the problem set's hint (the error should be smaller): the "
                "velocity plan closes the loop on Q's task-space error at every control step, "
                "q̇ = J",
                sup("+"),
                " (",
                K_W,
                " θ n, ",
                K_V,
                " e), so it follows the arc itself rather than a joint-space interpolation of a "
                "few points on it.",
            )
        )
    elif larger:
        out.say(
            para(
                "This contradicts the problem set's hint: here the velocity plan's max radial "
                "error is not smaller than that of ",
                ", ".join(ik.label for ik in larger),
                ".",
                kind="contradiction",
            )
        )
    out.say(page.status_note("velocity_open", ref.name))
    return out.answer()


def _answer_t2q2(page: AnswerPage) -> Answer:
    ref = _reference_ik(page)
    out = _Builder()
    pair = page.logged("velocity_open") + ([ref] if ref else [])
    out.figures += page.path_figure(
        "t2q2", pair, "velocity plan vs " + (ref.label if ref else "IK")
    )
    oc = page.logged("velocity_open", "velocity_closed")
    if len(oc) == 2:
        out.figures += page.path_figure("t2q2_closed", oc, "velocity plan, doors open vs closed")
    if page.logged("velocity_closed"):
        out.figures += page.door_figure(
            "t2q2", page.logged("velocity_closed"), "velocity plan, doors closed"
        )
    out.say(page.missing("velocity_open", "ik_10_open", "velocity_closed"))
    if page.logged("velocity_open"):
        lo, hi = signed_range_mm(page.runs["velocity_open"].tracking)
        parts = [
            "Along the arc (after the first 5 % of it) the velocity plan's signed radial error "
            "stays between ",
            number(lo),
            " and ",
            number(hi, "mm"),
            ", a spread of ",
            number(hi - lo, "mm"),
        ]
        contradiction = None
        if ref is not None:
            ilo, ihi = signed_range_mm(ref.tracking)
            spread, ispread = hi - lo, ihi - ilo
            parts += [
                f"; for {ref.label} it spans ",
                number(ilo),
                " to ",
                number(ihi, "mm"),
                " (spread ",
                number(ispread, "mm"),
                "). ",
            ]
            if spread < ispread:
                parts.append(
                    "The velocity plan's error is smaller and more consistent along the arc, as "
                    "the problem set's hint says: there are no knots, the error is corrected "
                    "continuously, and what remains varies slowly (the inner loop's lag and the "
                    "arm's changing configuration)."
                )
            else:
                contradiction = para(
                    "This contradicts the problem set's hint: the velocity plan's error along "
                    f"the arc does not vary less than that of {ref.label} here.",
                    kind="contradiction",
                )
        else:
            parts.append(".")
        out.say(para(parts), contradiction)
    if page.logged("velocity_closed"):
        out.say(closed_sentence(page, "velocity_closed", "velocity_open"))
        out.say(page.status_note("velocity_closed"))
    return out.answer()


def _answer_t3q1(page: AnswerPage) -> Answer:
    ref = _reference_ik(page)
    names = ("impedance_open", "velocity_open", ref.name if ref else "ik_10_open")
    runs = page.logged(*names)
    out = _Builder()
    out.figures += page.tracking_figures("t3q1", runs, "the three controllers, doors open")
    out.say(page.missing(*names))
    if not (page.logged("impedance_open") and len(runs) >= 2):
        return out.answer()
    ranked = sorted(runs, key=lambda r: page.value(r.name, "max_radial_error_m") or math.inf)
    out.say(
        para(
            "Ranked by max radial error, doors open: ",
            joined(
                ([f"{r.label} (", page.num(r.name, "max_radial_error_m"), ")"] for r in ranked),
                " < ",
            ),
            ". By RMS: ",
            joined([f"{r.label} ", page.num(r.name, "rms_radial_error_m")] for r in runs),
            ". By max orientation error: ",
            joined([f"{r.label} ", page.num(r.name, "max_orientation_error_rad")] for r in runs),
            ".",
        )
    )
    imp = page.runs["impedance_open"]
    kv = imp.scenario.impedance.kv if imp.scenario else float("nan")
    e = page.value("impedance_open", "max_radial_error_m")
    if e is not None:
        out.say(
            para(
                "The impedance plan commands no joint positions along the path (q_ref = the "
                "measured q) and no feedforward for the motion: Q is pulled towards its moving "
                "reference only by a Cartesian spring of ",
                K_V,
                " = ",
                number(kv, "N/m"),
                ", which has to drag the arm against the inner loop's joint damping (",
                D_Q,
                " q̇, and the stiffness term acting on a q_ref one control period old). So Q "
                f"lags its reference and drifts {side(imp.tracking)} the arc: the max error of ",
                page.num("impedance_open", "max_radial_error_m"),
                " is a spring force of about ",
                number(kv * e, "N"),
                ". The position-commanding plans do not need a force to move, so their error "
                "does not scale with 1/",
                K_V,
                ".",
            )
        )
    out.say(page.status_note(*names))
    return out.answer()


def _answer_t3q2(page: AnswerPage) -> Answer:
    out = _Builder()
    pair = page.logged("impedance_open", "impedance_closed")
    out.figures += page.tracking_figures("t3q2", pair, "impedance plan, doors open vs closed")
    closed_all = page.logged("ik_10_closed", "velocity_closed", "impedance_closed")
    out.figures += page.door_figure("t3q2", closed_all, "doors closed, the three controllers")
    out.figures += page.torque_figure("t3q2", pair, "impedance plan, doors open vs closed")
    out.say(page.missing("impedance_open", "impedance_closed"))
    if not page.logged("impedance_closed"):
        return out.answer()
    out.say(closed_sentence(page, "impedance_closed", "impedance_open", explain=False))
    a = page.value("impedance_closed", "max_radial_error_m")
    b = page.value("impedance_open", "max_radial_error_m")
    if a is not None and b is not None:
        effect = "raises" if a > b else ("lowers" if a < b else "does not change")
        parts: list = [
            f"So closing the door {effect} the impedance plan's max radial error (",
            page.num("impedance_open", "max_radial_error_m"),
            " open, ",
            page.num("impedance_closed", "max_radial_error_m"),
            " closed). ",
        ]
        if page.value("impedance_closed", "slip_time_s") is not None:
            parts.append(
                "But the handle slipped out of the gripper during the closed-door run, so this "
                "comparison does not isolate the door's effect."
            )
        elif a < b:
            grows = (page.value("impedance_closed", "max_orientation_error_rad") or 0) > (
                page.value("impedance_open", "max_orientation_error_rad") or 0
            )
            parts += [
                "With the doors open the soft spring lets Q drift off the arc while it lags; "
                "with the door closed the hinge holds the handle, and so Q, on the circle, and "
                "the same lag appears along the arc instead: the door trails the plan by up to ",
                number(door_lag_deg(page.runs["impedance_closed"]), "deg"),
                " (door angle plot), while the orientation error ",
                "grows" if grows else "does not grow",
                ". The radial error measures only the distance from the circle.",
            ]
        else:
            parts += [
                "With a soft task-space spring, the force the door needs at the handle (its "
                "inertia and hinge damping) shows up as position error, force = ",
                K_V,
                " × error.",
            ]
        out.say(para(parts))
    if [r for r in closed_all if r.name != "impedance_closed"]:
        out.say(
            para(
                "Doors closed, all controllers: ",
                joined(
                    [
                        f"{r.label} ",
                        page.num(r.name, "max_radial_error_m"),
                        " max radial error, door at the arc's end ",
                        page.num(r.name, "door_opening_arc_end_rad"),
                    ]
                    for r in closed_all
                ),
                ".",
            )
        )
    out.say(contact_paragraph(page))
    out.say(damping_paragraph(page.runs["impedance_closed"]))
    out.say(page.status_note("impedance_closed", "impedance_open"))
    return out.answer()


ANSWERS = {
    "t1q1": _answer_t1q1,
    "t1q2": _answer_t1q2,
    "t2q1": _answer_t2q1,
    "t2q2": _answer_t2q2,
    "t3q1": _answer_t3q1,
    "t3q2": _answer_t3q2,
}
