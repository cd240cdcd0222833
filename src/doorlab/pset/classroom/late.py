"""The course's late policy, applied to a submission's results from its submission time.

The policy is the assignment's ``late`` (:class:`doorlab.pset.rules.assignment.LatePolicy`): a due
date with its UTC offset, a grace period, a penalty per day late (or part of a day) as a
percentage of the score earned, and a cap. The submission's time is Gradescope's: the
export's ``submission_metadata.yml`` (``:created_at:`` of each submission, for ``doorlab pset
grade-all``) or the container's ``/autograder/submission_metadata.json`` (``created_at``, for
``run_autograder``), both documented by Gradescope
(https://gradescope-autograders.readthedocs.io/en/latest/submission_metadata/).

:func:`apply_late` sets the results' top-level ``score`` (Gradescope takes it over the sum of
the tests' scores when both are given), records ``extra_data.late`` and says it in one line
of the top-level output; it is idempotent (the score before the penalty is the tests' sum), so
a regrade or a new policy re-applies it from the results alone.
"""

from __future__ import annotations

import datetime
import math
from dataclasses import dataclass

from doorlab.pset.rules.assignment import LatePolicy, parse_due

LINE_PREFIX = "Late policy: "
"""The start of the late policy's line in the results' top-level output."""
DAY_S = 86400.0


def submission_time(value: object) -> datetime.datetime | None:
    """A metadata's submission time (YAML's timestamp, or ISO 8601 text) as an aware
    datetime; None when there is none or it cannot be read (a naive one is taken as UTC)."""
    if isinstance(value, datetime.datetime):
        when = value
    elif isinstance(value, str) and value.strip():
        text = value.strip().replace(" ", "T", 1)
        # Gradescope writes nanoseconds and a space before the offset; Python reads 6 digits.
        head, _, rest = text.partition(".")
        if rest:
            digits = len(rest) - len(rest.lstrip("0123456789"))
            text = f"{head}.{rest[: min(digits, 6)]}{rest[digits:].strip()}"
        try:
            when = datetime.datetime.fromisoformat(text.replace(" ", ""))
        except ValueError:
            return None
    else:
        return None
    return when if when.tzinfo is not None else when.replace(tzinfo=datetime.timezone.utc)


@dataclass(frozen=True)
class Lateness:
    """How late a submission was and what it costs.

    Attributes:
        due: The due date. submitted: The submission's time.
        late_s: How late [s] (0 when on time).
        days: Days late counted (each started day; 0 within the grace period).
        percent: The penalty [% of the score earned], capped.
    """

    due: datetime.datetime
    submitted: datetime.datetime
    late_s: float
    days: int
    percent: float


def lateness(
    policy: LatePolicy, submitted: datetime.datetime | None, own_due=None
) -> Lateness | None:
    """The submission's lateness under ``policy`` (None: no due date, or no submission time);
    ``own_due``: its own due date (:class:`doorlab.pset.classroom.extensions.OwnDue`), which
    counts when it is later than the course's."""
    due = parse_due(policy.due)
    if due is None or submitted is None:
        return None
    if own_due is not None and own_due.due > due:
        due = own_due.due
    late_s = max(0.0, (submitted - due).total_seconds())
    days = math.ceil(late_s / DAY_S) if late_s > policy.grace_minutes * 60.0 else 0
    percent = float(min(policy.max_penalty_percent, days * policy.penalty_per_day_percent))
    return Lateness(due, submitted, late_s, days, percent)


def _duration(seconds: float) -> str:
    days, rest = divmod(int(round(seconds)), 86400)
    hours, rest = divmod(rest, 3600)
    minutes = rest // 60
    parts = [f"{days} d"] if days else []
    parts += [f"{hours} h", f"{minutes} min"] if days or hours else [f"{minutes} min"]
    return " ".join(parts)


def apply_late(
    results: dict, policy: LatePolicy, submitted: datetime.datetime | None, own_due=None
) -> dict:
    """Applies ``policy`` to ``results`` (in place; returned): the top-level score is the
    tests' sum less the penalty, ``extra_data.late`` says why, and so does one line of the
    top-level output (a line an earlier policy wrote is replaced). ``own_due``: the
    submission's own due date (an extension, :mod:`doorlab.pset.classroom.extensions`)."""
    tests = results.get("tests") or []
    raw = float(sum(t.get("score") or 0.0 for t in tests))
    extra = results.setdefault("extra_data", {})
    lines = [
        line
        for line in str(results.get("output") or "").split("\n")
        if not line.startswith(LINE_PREFIX)
    ]
    found = lateness(policy, submitted, own_due)
    extended = own_due is not None and found is not None and found.due == own_due.due
    extended = extended and own_due.due != parse_due(policy.due)
    extra.pop("late", None)
    results["score"] = raw
    if found is None:
        if parse_due(policy.due) is not None:
            extra["late"] = {"due": policy.due, "submitted": None, "penalty_points": 0.0}
            lines.append(f"{LINE_PREFIX}no submission time was given: no late penalty")
        results["output"] = "\n".join(lines)
        return results
    penalty = round(raw * found.percent / 100.0, 4)
    results["score"] = round(raw - penalty, 4)
    extra["late"] = {
        "due": found.due.isoformat(),
        "submitted": found.submitted.isoformat(),
        "late_by_s": round(found.late_s, 1),
        "days_late": found.days,
        "penalty_percent": found.percent,
        "penalty_points": penalty,
        "score_before": raw,
    }
    if extended:
        extra["late"]["extension"] = own_due.why
    due_text = f"the due date {found.due.isoformat()}" + (f", {own_due.why}" if extended else "")
    if found.late_s > 0:
        if found.days == 0:
            what = f"within the {policy.grace_minutes:g}-minute grace period: no penalty"
        else:
            what = (
                f"{found.days} day{'s' if found.days != 1 else ''} counted, -{found.percent:g} % "
                f"of the score ({penalty:g} points: {raw:g} -> {raw - penalty:g})"
            )
        lines.append(
            f"{LINE_PREFIX}submitted {found.submitted.isoformat()}, {_duration(found.late_s)} "
            f"after {due_text}; {what}"
        )
    elif extended:
        lines.append(
            f"{LINE_PREFIX}submitted {found.submitted.isoformat()}, before {due_text}: no penalty"
        )
    results["output"] = "\n".join(lines)
    return results
