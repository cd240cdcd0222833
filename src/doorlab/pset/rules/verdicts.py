"""The graded tests and their verdicts: what each test needs and how it is judged, and what
the student's process must not see (the Gradescope results from the jobs' figures:
:mod:`doorlab.pset.grading.scoring`).

Thresholds of the episodes are relative to doorlab's reference solution simulated in the same
grading; each margin says why it is what it is.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

IK_POSITION_TOLERANCE = 0.001
"""The task cell's position_tolerance [m]."""
IK_RADIAL_MARGIN = 2 * math.sqrt(2) * IK_POSITION_TOLERANCE
"""How much more Q's radial error may be with the student's IK than with the reference's [m]:
each knot may sit anywhere in a +-1 mm box, so two valid IKs can put a knot up to
2 sqrt(2) mm apart horizontally."""
ARC_END_MARGIN_DEG = 2.0
ARC_END_MARGIN = math.radians(ARC_END_MARGIN_DEG)
"""Q's angle about the hinge at the arc's end vs the reference's [rad]: a correct plan ends
within a fraction of a degree of it; a plan that does not follow the whole arc misses by tens."""
VELOCITY_ORIENTATION_MARGIN = 0.01
"""How much larger L7's orientation error may be than the reference velocity plan's [rad]
(0.6 deg: a correct plan matches the reference to a small fraction of that; a wrong rotational
term is off by tenths of a radian)."""
DOOR_OPENING_MARGIN_DEG = 5.0
DOOR_OPENING_MARGIN = math.radians(DOOR_OPENING_MARGIN_DEG)
"""Door opening by the arc's end vs the reference impedance plan's [rad]: a correct J^T F
lands within a degree; a wrong gain, sign or frame leaves the door far behind or loses the
handle."""
STUDENT_FILES = ("ik_utils.py", "open_left_door.py", "manip_station_sim/robot_plans.py")
"""The files a student edits (they hold every stub of the graded functions): the only files
of a submission that a grading takes (:mod:`doorlab.pset.isolation.intake`); the rest of the folder
is doorlab's. Their SHA-256 seeds the grading's random inputs."""


@dataclass(frozen=True)
class TestSpec:
    """One graded test: its Gradescope name, default points, the jobs it needs and how it
    is judged.

    Attributes:
        name: Its name in the results.
        max_score: Its points unless the assignment file says otherwise.
        jobs: The jobs whose results it is judged on.
        judge: ``judge(results, settings) -> (passed, output)``: ``results`` by job,
            ``settings`` its entry of the assignment (:mod:`doorlab.pset.rules.assignment`: its
            margins).
        key: Its entry in the assignment file's ``tests``.
        number: Its Gradescope ``number`` (task.test).
        helpers: The helper functions (graded by their own unit tests) an episode runs when
            the assignment gives it the student's helpers: {function: its unit test's job}.
    """

    name: str
    max_score: float
    jobs: tuple[str, ...]
    judge: Callable[[dict[str, dict], object], tuple[bool, str]]
    key: str = ""
    number: str = ""
    helpers: tuple[tuple[str, str], ...] = ()

    def uses_student_helpers(self, settings: object) -> bool:
        """Whether this test's episode runs the student's helpers (the assignment's choice)."""
        return bool(self.helpers) and getattr(settings, "helpers", "reference") == "student"

    def needed_jobs(self, settings: object) -> tuple[str, ...]:
        """The jobs this test is judged on under ``settings`` (with the student's helpers,
        their unit tests too: the episode's message says when one failed)."""
        if not self.uses_student_helpers(settings):
            return self.jobs
        return self.jobs + tuple(job for _, job in self.helpers if job not in self.jobs)


FIGURES = (
    "max_radial_error_m",
    "max_orientation_error_rad",
    "q_end_angle_rad",
    "door_opening_at_arc_end_rad",
)
"""The episode figures the judges read (finite numbers), besides ``handle_held``."""


def _figures(results: dict[str, dict], job: str) -> dict | None:
    """The job's figures if they are all there and numbers (None otherwise)."""
    r = results.get(job)
    figures = r.get("figures") if isinstance(r, dict) else None
    if not isinstance(figures, dict) or figures.get("handle_held") not in (True, False, None):
        return None
    for key in FIGURES:
        x = figures.get(key)
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            return None
    return figures


def _failed_job(results: dict[str, dict], jobs: Sequence[str]) -> str | None:
    for job in jobs:
        if _figures(results, job) is not None:
            continue
        r = results.get(job)
        r = r if isinstance(r, dict) else {}
        who = "doorlab's reference" if job.startswith("reference") else "your code"
        text = str(r.get("error") or "no result")
        detail = str(r.get("output") or "")
        return f"{who} ({job}) did not finish: {text}" + (f"\n{detail}" if detail else "")
    return None


def _angle_zero(*figures: dict) -> str:
    """What Q's angle about the hinge is measured from (it is not the door's opening)."""
    theta0 = next((f["theta0_rad"] for f in figures if "theta0_rad" in f), None)
    at = f" ({_deg(theta0)} at the closed door's handle)" if theta0 is not None else ""
    return (
        f"Q's angle about the hinge is the notebook's theta, measured from W's y axis{at}; the "
        "door's opening is measured from the closed door"
    )


def _mm(x: float) -> str:
    return f"{x * 1e3:.2f} mm"


def _deg(x: float) -> str:
    return f"{math.degrees(x):.2f} deg"


def _judge_unit(job: str) -> Callable[[dict[str, dict], object], tuple[bool, str]]:
    def judge(results: dict[str, dict], settings: object = None) -> tuple[bool, str]:
        r = results.get(job)
        r = r if isinstance(r, dict) else {}
        text = str(r.get("output") or "")
        if "error" in r:
            text = f"{r['error']}\n{text}".rstrip()
        return r.get("passed") is True and "error" not in r, text

    return judge


def _margin(settings: object, name: str, default: float) -> float:
    """A margin of the test's assignment entry (``*_deg`` ones in degrees), in SI units."""
    value = getattr(settings, name, None)
    if value is None:
        return default
    return math.radians(value) if name.endswith("_deg") else float(value)


def _judge_ik(results: dict[str, dict], settings: object = None) -> tuple[bool, str]:
    jobs = ("student:ik", "reference:ik")
    if failed := _failed_job(results, jobs):
        return False, failed
    s, r = _figures(results, "student:ik"), _figures(results, "reference:ik")
    margin = _margin(settings, "radial_margin", IK_RADIAL_MARGIN)
    bound = r["max_radial_error_m"] + margin
    checks = [
        (
            s["max_radial_error_m"] <= bound,
            f"max radial error of Q {_mm(s['max_radial_error_m'])} (bound {_mm(bound)} = the "
            f"reference's {_mm(r['max_radial_error_m'])} + {_mm(margin)})",
        ),
        _arc_end_check(s, r, _margin(settings, "arc_end_margin_deg", ARC_END_MARGIN)),
    ]
    passed, text = _combine(checks)
    return passed, f"{text}\n({_angle_zero(s, r)})"


def _arc_end_check(s: dict, r: dict, margin: float = ARC_END_MARGIN) -> tuple[bool, str]:
    """Q's angle about the hinge at the arc's end, the student's (s) against the reference's
    (r), within ``margin`` [rad]."""
    return (
        abs(s["q_end_angle_rad"] - r["q_end_angle_rad"]) <= margin,
        f"Q's angle about the hinge at the arc's end {_deg(s['q_end_angle_rad'])} "
        f"(reference {_deg(r['q_end_angle_rad'])}, margin {_deg(margin)})",
    )


def _judge_velocity(results: dict[str, dict], settings: object = None) -> tuple[bool, str]:
    jobs = ("student:velocity", "reference:velocity", "reference:ik")
    if failed := _failed_job(results, jobs):
        return False, failed
    s = _figures(results, "student:velocity")
    r = _figures(results, "reference:velocity")
    ik = _figures(results, "reference:ik")
    o_margin = _margin(settings, "orientation_margin", VELOCITY_ORIENTATION_MARGIN)
    o_bound = r["max_orientation_error_rad"] + o_margin
    checks = [
        (
            s["max_radial_error_m"] <= ik["max_radial_error_m"],
            f"max radial error of Q {_mm(s['max_radial_error_m'])} (must be below pointwise "
            f"IK's {_mm(ik['max_radial_error_m'])}; the reference velocity plan: "
            f"{_mm(r['max_radial_error_m'])})",
        ),
        (
            s["max_orientation_error_rad"] <= o_bound,
            f"max orientation error of L7 {s['max_orientation_error_rad']:.4f} rad (bound "
            f"{o_bound:.4f} = the reference's {r['max_orientation_error_rad']:.4f} + "
            f"{o_margin:g})",
        ),
        _arc_end_check(s, r, _margin(settings, "arc_end_margin_deg", ARC_END_MARGIN)),
    ]
    passed, text = _combine(checks)
    return passed, f"{text}\n({_angle_zero(s, r)})"


_DOOR = "door_opening_at_arc_end_rad"


def _judge_impedance(results: dict[str, dict], settings: object = None) -> tuple[bool, str]:
    jobs = ("student:impedance", "reference:impedance")
    if failed := _failed_job(results, jobs):
        return False, failed
    s, r = _figures(results, "student:impedance"), _figures(results, "reference:impedance")
    margin = _margin(settings, "door_opening_margin_deg", DOOR_OPENING_MARGIN)
    checks = [
        (s["handle_held"] is True, f"handle held at the end: {s['handle_held']}"),
        (
            abs(s[_DOOR] - r[_DOOR]) <= margin,
            f"door opened {_deg(s[_DOOR])} by the arc's end (from the closed door; "
            f"reference {_deg(r[_DOOR])}, margin {_deg(margin)})",
        ),
    ]
    return _combine(checks)


def _combine(checks: list[tuple[bool, str]]) -> tuple[bool, str]:
    lines = [("ok     " if ok else "FAILED ") + text for ok, text in checks]
    return all(ok for ok, _ in checks), "\n".join(lines)


_HELPERS = (("calc_p_Q", "unit:calc_p_Q"), ("calc_R_WL7_ref", "unit:calc_R_WL7_ref"))
"""The helpers the task 2 and 3 episodes' plans call, and their unit tests' jobs."""

TESTS: tuple[TestSpec, ...] = (
    TestSpec(
        "Task 1 unit test: InverseKinPointwise",
        2.0,
        ("unit:ik",),
        _judge_unit("unit:ik"),
        key="ik_unit",
        number="1.1",
    ),
    TestSpec(
        "Task 1 episode: IK with 10 knots, doors open",
        2.0,
        ("student:ik", "reference:ik"),
        _judge_ik,
        key="ik_episode",
        number="1.2",
    ),
    TestSpec(
        "Task 2 unit test: calc_p_Q",
        1.0,
        ("unit:calc_p_Q",),
        _judge_unit("unit:calc_p_Q"),
        key="calc_p_Q_unit",
        number="2.1",
    ),
    TestSpec(
        "Task 2 unit test: calc_R_WL7_ref",
        1.0,
        ("unit:calc_R_WL7_ref",),
        _judge_unit("unit:calc_R_WL7_ref"),
        key="calc_R_WL7_ref_unit",
        number="2.2",
    ),
    TestSpec(
        "Task 2 unit test: IiwaTaskSpaceVelocityPlan.CalcPositionCommand",
        2.0,
        ("unit:velocity",),
        _judge_unit("unit:velocity"),
        key="velocity_unit",
        number="2.3",
    ),
    TestSpec(
        "Task 2 episode: velocity plan, doors open",
        2.0,
        ("student:velocity", "reference:velocity", "reference:ik"),
        _judge_velocity,
        key="velocity_episode",
        number="2.4",
        helpers=_HELPERS,
    ),
    TestSpec(
        "Task 3 unit test: IiwaTaskSpaceImpedancePlan.CalcTorqueCommand",
        2.0,
        ("unit:impedance",),
        _judge_unit("unit:impedance"),
        key="impedance_unit",
        number="3.1",
    ),
    TestSpec(
        "Task 3 episode: impedance plan, doors closed",
        2.0,
        ("student:impedance", "reference:impedance"),
        _judge_impedance,
        key="impedance_episode",
        number="3.2",
        helpers=_HELPERS,
    ),
)
"""Every graded test, in number order (task.test: the order of the results and the sheet)."""

# What the student's process must not see -------------------------------------------------

_ARC = "doorlab's handle arc and L7's orientation along it (the reference of calc_p_Q and "
_ARC += "calc_R_WL7_ref)"
_LAWS = "doorlab's control laws (the reference solution of tasks 2 and 3)"
_PLANS = "doorlab's task-space plans (the reference solution of tasks 2 and 3)"
REFERENCE_SOLUTIONS: dict[str, dict[str, str]] = {
    "ik_utils.InverseKinPointwise": {
        "doorlab.control.ik_pointwise": "doorlab's pointwise IK (the reference solution of task 1)",
    },
    "open_left_door.calc_p_Q": {"doorlab.cell.geometry": _ARC},
    "open_left_door.calc_R_WL7_ref": {"doorlab.cell.geometry": _ARC},
    "IiwaTaskSpaceVelocityPlan.CalcPositionCommand": {
        "doorlab.control.laws": _LAWS,
        "doorlab.control.plans": _PLANS,
    },
    "IiwaTaskSpaceImpedancePlan.CalcTorqueCommand": {
        "doorlab.control.laws": _LAWS,
        "doorlab.control.plans": _PLANS,
    },
}
"""Per graded function (``doorlab.pset.handout.folder.STUDENT_FUNCTIONS``), the modules that hold
doorlab's reference solution of it, and what they hold."""
BUILT_ON_REFERENCES = {
    "doorlab.episode.controllers": "doorlab's controllers (the reference solutions of tasks 1-3)",
    "doorlab.control.adaptive": "doorlab's adaptive plan (built on the reference control laws)",
    "doorlab.control.diffik": "doorlab's diffik plan (built on the reference control laws)",
    "doorlab.control.osc": "doorlab's osc plan (built on the reference control laws and plans)",
    "doorlab.studies.legacy": "doorlab's former episode design (runs the reference controllers)",
    "doorlab.episode.simulation": "doorlab's episodes (they run the reference plans)",
}
"""Modules that run or re-export the reference solutions."""
_GRADER = "the grader (its expected answers)"
GRADER_MODULES = {
    "doorlab.pset.handout.folder": (
        "the problem set's solution files (doorlab pset init --solutions)"
    ),
    "doorlab.pset.handout.notebook": "the problem set's notebook writer",
    "doorlab.pset.classroom.gradescope": "the grader's Gradescope autograder (its wheel)",
    "doorlab.pset.grading.answer_key": "the grader's answer key (the unit tests' expected answers)",
    **{
        f"doorlab.pset.{name}": _GRADER
        for name in (
            "grading.grader",
            "rules.verdicts",
            "grading.scoring",
            "grading.checks",
            "grading.episodes",
            "grading.jobs",
            "grading.supervisor",
            "isolation.handle",
            "isolation.sandbox",
            "isolation.bwrap_root",
            "isolation.student_view",
            "isolation.choice",
            "isolation.safe_text",
            "isolation.cgroups",
            "rules.clock",
            "isolation.seccomp",
            "classroom.cluster",
        )
    },
}
"""The grader's own modules."""
TEMPLATES = ("doorlab.pset.handout", "templates")
"""The folder of the problem set's templates (the solutions' text)."""


def hidden_modules() -> dict[str, str]:
    """Every module the student's process must not see (each graded function's reference,
    what is built on them, the grader), and what it holds: the one table the student's view
    (:mod:`doorlab.pset.isolation.bwrap_root`), the honesty guard and the Gradescope fallback derive
    from."""
    out: dict[str, str] = {}
    for modules in REFERENCE_SOLUTIONS.values():
        out.update(modules)
    out.update(BUILT_ON_REFERENCES)
    out.update(GRADER_MODULES)
    return out


def test_settings(assignment: object, spec: TestSpec) -> object:
    """``spec``'s entry of the assignment (None without one: the defaults)."""
    tests = getattr(assignment, "tests", None)
    return getattr(tests, spec.key, None) if tests is not None else None
