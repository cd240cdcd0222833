"""A submission's final grade: its judged tests, the instructor's adjustments, the late
penalty (with the submission's own due date) and the line that says the total.

:func:`finalize` is what every results file goes through before it is written, in
``grade-all`` (:class:`doorlab.pset.classroom.regrade.Ledger`) and in ``run_autograder``
(:mod:`doorlab.pset.classroom.gradescope`). It is idempotent and starts from the judged
results (:func:`restore` undoes an earlier finalization), so a kept, re-scored or regraded
result gets the adjustments and extensions of the run that writes it, never twice:

1. each adjustment of a test (:mod:`doorlab.pset.classroom.adjustments`) sets or changes
   that test's score (within 0 and its points) and its status;
2. the late policy (:func:`doorlab.pset.classroom.late.apply_late`) from the tests' sum,
   with the submission's own due date when it is later (an extension);
3. each adjustment of the total adds its points (the total stays >= 0);
4. the top-level output's ``Total:`` line: the grade with the course's points, how many of
   them are in tests students do not see (hidden, or shown only later), the late penalty and
   the adjustments (what every student-facing total says: results.json, the feedback page).

``extra_data.adjusted`` records what was changed (each test's judged score, each
adjustment's line, the points the adjustments moved the total by).
"""

from __future__ import annotations

import copy
import datetime

from doorlab.pset.classroom.late import apply_late

ADJUSTMENT_PREFIX = "Adjustment: "
"""The start of an adjustment's line in the results' top-level output."""
TOTAL_PREFIX = "Total: "
"""The start of the total's line in the results' top-level output."""


def restore(results: dict) -> dict:
    """A copy of ``results`` as judged: every test's judged score and status back, the
    adjustments' and the total's lines out of the top-level output."""
    out = copy.deepcopy(results)
    extra = out.setdefault("extra_data", {})
    adjusted = extra.pop("adjusted", None)
    judged = adjusted.get("tests") if isinstance(adjusted, dict) else None
    if isinstance(judged, dict):
        for test in out.get("tests") or []:
            before = judged.get(test.get("name"))
            if isinstance(before, dict):
                test["score"], test["status"] = before.get("score"), before.get("status")
    lines = str(out.get("output") or "").split("\n")
    out["output"] = "\n".join(
        line for line in lines if not line.startswith((ADJUSTMENT_PREFIX, TOTAL_PREFIX))
    )
    return out


def _adjust_tests(results: dict, adjustments) -> tuple[dict, list[str]]:
    """Applies the adjustments of tests (in place); returns each test's judged score and
    status, and the lines."""
    from doorlab.pset.rules import verdicts

    names = {t.key: t.name for t in verdicts.TESTS}
    by_name = {t.get("name"): t for t in results.get("tests") or []}
    judged, lines = {}, []
    for adjustment in adjustments:
        test = by_name.get(names.get(adjustment.test))
        if not adjustment.test or test is None:
            continue
        judged.setdefault(test["name"], {"score": test["score"], "status": test["status"]})
        most = float(test.get("max_score") or 0.0)
        old = float(test.get("score") or 0.0)
        if adjustment.score is not None:
            new = min(max(adjustment.score, 0.0), most)
        else:
            new = min(max(old + adjustment.points, 0.0), most)
        test["score"] = new
        test["status"] = "passed" if new >= most else "failed"
        capped = (
            " (kept within 0 and its points)"
            if adjustment.points is not None and (new != old + adjustment.points)
            else ""
        )
        lines.append(
            f"{ADJUSTMENT_PREFIX}{test['number']} {test['name']}: {old:g} -> {new:g} by the "
            f"instructor{capped} ({adjustment.reason})"
        )
    return judged, lines


def finalize(
    results: dict,
    assignment,
    submitted: datetime.datetime | None,
    *,
    own_due=None,
    adjustments=(),
) -> dict:
    """``results`` (not changed) as written: adjusted, the late policy applied, the total
    said (see the module docstring); a new dict.

    Args:
        results: A grading's (or an earlier finalization's) results.
        assignment: The course's settings (its late policy).
        submitted: The submission's time (None: none known, no penalty).
        own_due: Its own due date (:class:`doorlab.pset.classroom.extensions.OwnDue`).
        adjustments: Its adjustments (:class:`doorlab.pset.classroom.adjustments.Adjustment`).
    """
    base = apply_late(restore(results), assignment.late, submitted, own_due)
    if not adjustments:
        _total_line(base)
        return base
    out = restore(results)
    judged, lines = _adjust_tests(out, adjustments)
    apply_late(out, assignment.late, submitted, own_due)
    for adjustment in adjustments:
        if adjustment.test:
            continue
        before = float(out["score"])
        out["score"] = round(max(0.0, before + adjustment.points), 4)
        lines.append(
            f"{ADJUSTMENT_PREFIX}{adjustment.points:+g} point"
            f"{'s' if abs(adjustment.points) != 1 else ''} on the total by the instructor "
            f"({before:g} -> {float(out['score']):g}; {adjustment.reason})"
        )
    out["extra_data"]["adjusted"] = {
        "tests": judged,
        "lines": [line.removeprefix(ADJUSTMENT_PREFIX) for line in lines],
        "points": round(float(out["score"]) - float(base["score"]), 4),
        "reasons": [a.describe() for a in adjustments],
    }
    out["output"] = "\n".join([*str(out.get("output") or "").split("\n"), *lines]).strip("\n")
    _total_line(out)
    return out


_LATER = {
    "hidden": "a hidden test, never shown",
    "after_due_date": "tests shown after the due date",
    "after_published": "tests shown once grades are published",
}


def unseen_points(results: dict) -> dict[str, float]:
    """The points of the tests students do not see now, by visibility (hidden, shown later)."""
    out: dict[str, float] = {}
    for test in results.get("tests") or []:
        visibility = test.get("visibility", "visible")
        if visibility in _LATER:
            out[visibility] = out.get(visibility, 0.0) + float(test.get("max_score") or 0.0)
    return out


def total_text(results: dict) -> str:
    """What the total's line says after ``Total: `` (the feedback page's score says it too)."""
    extra = results.get("extra_data") or {}
    score = float(results.get("score") or 0.0)
    most = float(extra.get("max_score") or sum(t.get("max_score") or 0 for t in results["tests"]))
    parts = []
    for visibility, points in unseen_points(results).items():
        if points:
            what = _LATER[visibility]
            if visibility == "hidden":
                count = sum(t.get("visibility") == "hidden" for t in results["tests"])
                what = what if count == 1 else f"{count} hidden tests, never shown"
            parts.append(f"{points:g} point{'s' if points != 1 else ''} in {what}")
    late = extra.get("late") if isinstance(extra.get("late"), dict) else {}
    if late.get("penalty_points"):
        parts.append(
            f"late penalty -{float(late['penalty_points']):g} ({float(late['penalty_percent']):g}"
            f" %, {late.get('days_late')} day{'s' if late.get('days_late') != 1 else ''} late)"
        )
    adjusted = extra.get("adjusted") if isinstance(extra.get("adjusted"), dict) else {}
    if adjusted.get("points"):
        parts.append(f"the instructor's adjustments {float(adjusted['points']):+g}")
    return f"{score:g} / {most:g} points" + (f" ({'; '.join(parts)})" if parts else "")


def _total_line(results: dict) -> None:
    text = str(results.get("output") or "").rstrip("\n")
    results["output"] = (f"{text}\n" if text else "") + TOTAL_PREFIX + total_text(results)
