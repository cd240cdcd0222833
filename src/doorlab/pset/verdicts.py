"""The graded tests and their verdicts: what each test needs, how it is judged, and the
Gradescope results from the jobs' figures (in the grader's supervisor, the trusted side:
:mod:`doorlab.pset.jobs`).

Thresholds of the episodes are relative to doorlab's reference solution simulated in the same
grading; each margin says why it is what it is.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from doorlab.pset.safe_text import clean_text

IK_POSITION_TOLERANCE = 0.001
"""The task cell's position_tolerance [m]."""
IK_RADIAL_MARGIN = 2 * math.sqrt(2) * IK_POSITION_TOLERANCE
"""How much more Q's radial error may be with the student's IK than with the reference's [m]:
each knot may sit anywhere in a +-1 mm box, so two valid IKs can put a knot up to
2 sqrt(2) mm apart horizontally."""
ARC_END_MARGIN = math.radians(2.0)
"""Q's angle about the hinge at the arc's end vs the reference's [rad]: a correct plan ends
within a fraction of a degree of it; a plan that does not follow the whole arc misses by tens."""
VELOCITY_ORIENTATION_MARGIN = 0.01
"""How much larger L7's orientation error may be than the reference velocity plan's [rad]
(0.6 deg: a correct plan matches the reference to a small fraction of that; a wrong rotational
term is off by tenths of a radian)."""
DOOR_OPENING_MARGIN = math.radians(5.0)
"""Door opening by the arc's end vs the reference impedance plan's [rad]: a correct J^T F
lands within a degree; a wrong gain, sign or frame leaves the door far behind or loses the
handle."""
MAX_OUTPUT_CHARS = 4000
"""Longest output of one test in the results (the student's printed output is capped
before that, see :mod:`doorlab.pset.sandbox`)."""


@dataclass(frozen=True)
class TestSpec:
    """One graded test: its Gradescope name, points, the jobs it needs and how it is judged."""

    name: str
    max_score: float
    jobs: tuple[str, ...]
    judge: Callable[[dict[str, dict]], tuple[bool, str]]


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


def _judge_unit(job: str) -> Callable[[dict[str, dict]], tuple[bool, str]]:
    def judge(results: dict[str, dict]) -> tuple[bool, str]:
        r = results.get(job)
        r = r if isinstance(r, dict) else {}
        text = str(r.get("output") or "")
        if "error" in r:
            text = f"{r['error']}\n{text}".rstrip()
        return r.get("passed") is True and "error" not in r, text

    return judge


def _judge_ik(results: dict[str, dict]) -> tuple[bool, str]:
    jobs = ("student:ik", "reference:ik")
    if failed := _failed_job(results, jobs):
        return False, failed
    s, r = _figures(results, "student:ik"), _figures(results, "reference:ik")
    bound = r["max_radial_error_m"] + IK_RADIAL_MARGIN
    checks = [
        (
            s["max_radial_error_m"] <= bound,
            f"max radial error of Q {_mm(s['max_radial_error_m'])} (bound {_mm(bound)} = the "
            f"reference's {_mm(r['max_radial_error_m'])} + {_mm(IK_RADIAL_MARGIN)})",
        ),
        _arc_end_check(s, r),
    ]
    passed, text = _combine(checks)
    return passed, f"{text}\n({_angle_zero(s, r)})"


def _arc_end_check(s: dict, r: dict) -> tuple[bool, str]:
    """Q's angle about the hinge at the arc's end, the student's (s) against the reference's (r)."""
    return (
        abs(s["q_end_angle_rad"] - r["q_end_angle_rad"]) <= ARC_END_MARGIN,
        f"Q's angle about the hinge at the arc's end {_deg(s['q_end_angle_rad'])} "
        f"(reference {_deg(r['q_end_angle_rad'])}, margin {_deg(ARC_END_MARGIN)})",
    )


def _judge_velocity(results: dict[str, dict]) -> tuple[bool, str]:
    jobs = ("student:velocity", "reference:velocity", "reference:ik")
    if failed := _failed_job(results, jobs):
        return False, failed
    s = _figures(results, "student:velocity")
    r = _figures(results, "reference:velocity")
    ik = _figures(results, "reference:ik")
    o_bound = r["max_orientation_error_rad"] + VELOCITY_ORIENTATION_MARGIN
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
            f"{VELOCITY_ORIENTATION_MARGIN})",
        ),
        _arc_end_check(s, r),
    ]
    passed, text = _combine(checks)
    return passed, f"{text}\n({_angle_zero(s, r)})"


_DOOR = "door_opening_at_arc_end_rad"


def _judge_impedance(results: dict[str, dict]) -> tuple[bool, str]:
    jobs = ("student:impedance", "reference:impedance")
    if failed := _failed_job(results, jobs):
        return False, failed
    s, r = _figures(results, "student:impedance"), _figures(results, "reference:impedance")
    checks = [
        (s["handle_held"] is True, f"handle held at the end: {s['handle_held']}"),
        (
            abs(s[_DOOR] - r[_DOOR]) <= DOOR_OPENING_MARGIN,
            f"door opened {_deg(s[_DOOR])} by the arc's end (from the closed door; "
            f"reference {_deg(r[_DOOR])}, margin {_deg(DOOR_OPENING_MARGIN)})",
        ),
    ]
    return _combine(checks)


def _combine(checks: list[tuple[bool, str]]) -> tuple[bool, str]:
    lines = [("ok     " if ok else "FAILED ") + text for ok, text in checks]
    return all(ok for ok, _ in checks), "\n".join(lines)


TESTS: tuple[TestSpec, ...] = (
    TestSpec("Task 1 unit test: InverseKinPointwise", 2.0, ("unit:ik",), _judge_unit("unit:ik")),
    TestSpec("Task 2 unit test: calc_p_Q", 1.0, ("unit:calc_p_Q",), _judge_unit("unit:calc_p_Q")),
    TestSpec(
        "Task 2 unit test: calc_R_WL7_ref",
        1.0,
        ("unit:calc_R_WL7_ref",),
        _judge_unit("unit:calc_R_WL7_ref"),
    ),
    TestSpec(
        "Task 2 unit test: IiwaTaskSpaceVelocityPlan.CalcPositionCommand",
        2.0,
        ("unit:velocity",),
        _judge_unit("unit:velocity"),
    ),
    TestSpec(
        "Task 3 unit test: IiwaTaskSpaceImpedancePlan.CalcTorqueCommand",
        2.0,
        ("unit:impedance",),
        _judge_unit("unit:impedance"),
    ),
    TestSpec(
        "Task 1 episode: IK with 10 knots, doors open",
        2.0,
        ("student:ik", "reference:ik"),
        _judge_ik,
    ),
    TestSpec(
        "Task 2 episode: velocity plan, doors open",
        2.0,
        ("student:velocity", "reference:velocity", "reference:ik"),
        _judge_velocity,
    ),
    TestSpec(
        "Task 3 episode: impedance plan, doors closed",
        2.0,
        ("student:impedance", "reference:impedance"),
        _judge_impedance,
    ),
)
"""Every graded test, in report order."""

# What the student's process must not see -------------------------------------------------

_ARC = "doorlab's handle arc and L7's orientation along it (the reference of calc_p_Q and "
_ARC += "calc_R_WL7_ref)"
_LAWS = "doorlab's control laws (the reference solution of tasks 2 and 3)"
_PLANS = "doorlab's task-space plans (the reference solution of tasks 2 and 3)"
REFERENCE_SOLUTIONS: dict[str, dict[str, str]] = {
    "ik_utils.InverseKinPointwise": {
        "doorlab.ik_pointwise": "doorlab's pointwise IK (the reference solution of task 1)",
    },
    "open_left_door.calc_p_Q": {"doorlab.geometry": _ARC},
    "open_left_door.calc_R_WL7_ref": {"doorlab.geometry": _ARC},
    "IiwaTaskSpaceVelocityPlan.CalcPositionCommand": {
        "doorlab.laws": _LAWS,
        "doorlab.plans": _PLANS,
    },
    "IiwaTaskSpaceImpedancePlan.CalcTorqueCommand": {
        "doorlab.laws": _LAWS,
        "doorlab.plans": _PLANS,
    },
}
"""Per graded function (``doorlab.pset.folder.STUDENT_FUNCTIONS``), the modules that hold
doorlab's reference solution of it, and what they hold."""
BUILT_ON_REFERENCES = {
    "doorlab.controllers": "doorlab's controllers (the reference solutions of tasks 1-3)",
    "doorlab.adaptive": "doorlab's adaptive plan (built on the reference control laws)",
    "doorlab.legacy": "doorlab's former episode design (runs the reference controllers)",
    "doorlab.simulation": "doorlab's episodes (they run the reference plans)",
}
"""Modules that run or re-export the reference solutions."""
_GRADER = "the grader (its expected answers)"
GRADER_MODULES = {
    "doorlab.pset.folder": "the problem set's solution files (doorlab pset init --solutions)",
    "doorlab.pset.notebook": "the problem set's notebook writer",
    "doorlab.pset.autograder": "the grader's Gradescope autograder (its wheel)",
    **{
        f"doorlab.pset.{name}": _GRADER
        for name in (
            "grader",
            "verdicts",
            "checks",
            "episodes",
            "jobs",
            "student",
            "sandbox",
            "view",
            "isolation",
            "safe_text",
        )
    },
}
"""The grader's own modules."""
TEMPLATES = ("doorlab.pset", "templates")
"""The folder of the problem set's templates (the solutions' text)."""


def hidden_modules() -> dict[str, str]:
    """Every module the student's process must not see (each graded function's reference,
    what is built on them, the grader), and what it holds: the one table the student's view
    (:mod:`doorlab.pset.view`), the honesty guard and the Gradescope fallback derive from."""
    out: dict[str, str] = {}
    for modules in REFERENCE_SOLUTIONS.values():
        out.update(modules)
    out.update(BUILT_ON_REFERENCES)
    out.update(GRADER_MODULES)
    return out


def _cap(text: str) -> str:
    if len(text) <= MAX_OUTPUT_CHARS:
        return text
    return text[:MAX_OUTPUT_CHARS] + f"\n[... {len(text) - MAX_OUTPUT_CHARS} characters left out]"


ISOLATION_HELD = {
    "bwrap": "a minimal read-only root (bubblewrap): the student's code sees only its own "
    "scratch copy, the interpreter and the libraries it needs; no network; its own processes",
    "uid": "WITHOUT the minimal root: another user, no namespaces; it can read what that user "
    "may read on this machine",
    "none": "WITHOUT the minimal root: the grader's own user, no namespaces; it can read and "
    "write what that user may",
}
"""What each isolation mode means, for ``extra_data.sandbox.held``."""


def _sandbox_facts(results: dict[str, dict], isolation) -> dict:
    """How the student's processes ran: the grading's isolation and what each process
    observed of itself before its code loaded (judged here)."""
    from doorlab.pset import sandbox

    facts = [r["sandbox"] for r in results.values() if isinstance(r.get("sandbox"), dict)]
    uids = sorted({f.get("uid") for f in facts if isinstance(f.get("uid"), int)})

    def every(key: str) -> bool:
        return bool(facts) and all(f.get(key) is True for f in facts)

    sizes = [f.get("tmpfs_bytes") for f in facts if isinstance(f.get("tmpfs_bytes"), dict)]
    mode = getattr(isolation, "mode", None)
    out = {
        "mode": mode,
        "isolated": mode == "bwrap",
        "held": ISOLATION_HELD.get(mode, "no student process ran"),
        "student_uids": uids,
        "grader_uid": os.geteuid(),
        "network_isolated": every("network_isolated"),
        "reference_hidden": every("reference_hidden"),
        "pid_namespace": every("pid_namespace"),
        "python_path_read_only": bool(facts)
        and not any(f.get("python_path_writable") for f in facts),
        "seen": {
            key: sorted({str(p) for f in facts for p in f.get(key) or []})[:5]
            for key in ("reference_readable", "python_path_writable")
        },
        "tmpfs_bytes": max(
            (v for s in sizes for v in s.values() if isinstance(v, int)), default=None
        ),
        "memory_limit_bytes": sandbox.MEMORY_LIMIT_BYTES,
        "file_size_limit_bytes": sandbox.FILE_SIZE_LIMIT_BYTES,
        "output_limit_bytes": sandbox.OUTPUT_LIMIT_BYTES,
        "process_limit": sandbox.PROCESS_LIMIT,
    }
    if isolation is not None and isolation.mode != "bwrap":
        out["why_no_minimal_root"] = clean_text(isolation.reason, 300)
        out["policy"] = isolation.policy
        out["made_unreadable"] = list(isolation.hardened)
    return out


def results_from_jobs(
    specs: Sequence[TestSpec], results: dict[str, dict], execution_time: float, isolation=None
) -> dict:
    """The Gradescope results of ``specs`` judged on the jobs' ``results`` (in the
    supervisor; see :func:`grade` for the format); ``isolation``: the grading's
    :class:`~doorlab.pset.isolation.Isolation` (None: no student process ran). Every
    test's output is cleaned (:func:`~doorlab.pset.safe_text.clean_text`)."""
    tests = []
    for spec in specs:
        passed, output = spec.judge(results)
        tests.append(
            {
                "name": spec.name,
                "score": spec.max_score if passed else 0.0,
                "max_score": spec.max_score,
                "output": _cap(clean_text(output)),
            }
        )
    return {
        "score": sum(t["score"] for t in tests),
        "tests": tests,
        "execution_time": round(execution_time, 2),
        "extra_data": {
            "max_score": sum(t["max_score"] for t in tests),
            "reference": {k: v for k, v in results.items() if k.startswith("reference:")},
            "sandbox": _sandbox_facts(results, isolation),
        },
    }
