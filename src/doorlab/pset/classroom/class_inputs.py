"""What a run of ``grade-all`` reads before it grades, besides the submissions: the
assignment (the class's recorded one when a regrade names none), the instructor's files in
the class's folder (``adjustments.csv``, ``extensions.csv``), the exports it will write, and
what a different assignment will cost, said before anything is simulated.

Everything here is checked before the first grading: a bad row, an export that would give
one row to two students, a roster that is not Canvas's, is one line and nothing written.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class ClassInputs:
    """A run's inputs.

    Attributes:
        assignment: The assignment it grades with (None: doorlab's defaults).
        submissions: The submissions, their students' identities corrected
            (``adjustments.csv``).
        own_dues: Each submission's own due date (``extensions.csv``), by id.
        adjustments: ``adjustments.csv``
            (:class:`doorlab.pset.classroom.adjustments.Adjustments`).
        exports: The exports it writes (:class:`doorlab.pset.classroom.exports.ExportPlan`).
        notes: What the summary says of them.
    """

    assignment: object
    submissions: list
    own_dues: dict = field(default_factory=dict)
    adjustments: object = None
    exports: object = None
    notes: list[str] = field(default_factory=list)


def read_inputs(
    out: Path, submissions: list, assignment, previous, *, requested=(), roster=None
) -> ClassInputs:
    """The run's inputs (``previous``: the class graded before, None for a new class or
    ``--force``).

    Raises:
        ConfigError: A bad row of the instructor's files, a roster that is not Canvas's,
            an export that would give one row to two students.
    """
    from doorlab.pset.classroom.adjustments import apply_identities, read_adjustments
    from doorlab.pset.classroom.exports import plan_exports
    from doorlab.pset.classroom.extensions import read_extensions
    from doorlab.pset.classroom.gradebook import check_exports
    from doorlab.pset.rules.assignment import Assignment, assignment_from_dict

    notes = []
    if previous is not None and assignment is None:
        if previous.settings is not None:
            assignment = assignment_from_dict(previous.settings)
            notes.append("assignment: the class's (recorded in class.json; no --assignment given)")
        else:
            notes.append(
                "assignment: doorlab's defaults (no --assignment, and the class's class.json, "
                "written by an older doorlab, records none)"
            )
    adjustments = read_adjustments(out, submissions, assignment or Assignment())
    submissions = apply_identities(submissions, adjustments.identities)
    own_dues = read_extensions(out, submissions)
    exports = plan_exports(out, requested, roster)
    check_exports(exports.formats, submissions, exports.roster)
    count = sum(len(v) for v in adjustments.grades.values())
    if count or adjustments.identities or own_dues:
        notes.append(
            f"the instructor's files: adjustments.csv, {count} change(s) of a grade in "
            f"{len(adjustments.grades)} submission(s) and {len(adjustments.identities)} of an "
            f"identity; extensions.csv, {len(own_dues)} extension(s)"
        )
    return ClassInputs(assignment, submissions, own_dues, adjustments, exports, notes)


def assignment_changes(before: dict | None, after: dict) -> list[str]:
    """Each setting that differs between the class's recorded assignment and this run's
    (``key: old -> new``)."""
    from doorlab.pset.grading.rescore import _flat, _shown

    if before is None:
        return []
    old, new = dict(_flat(before)), dict(_flat(after))
    return [
        f"{key}: {_shown(old.get(key))} -> {_shown(new.get(key))}"
        for key in sorted(set(old) | set(new))
        if old.get(key) != new.get(key)
    ]


def cost_line(changes: list[str], ledger) -> str:
    """What a different assignment costs this run: the submissions re-scored (nothing
    simulated) and those graded again (simulated), with the worker time their last gradings
    took (measured, in their results)."""
    counts: dict[str, int] = {}
    seconds = 0.0
    for sid, step in ledger.steps.items():
        counts[step.action] = counts.get(step.action, 0) + 1
        if step.action == "grade":
            batch = (ledger.old.get(sid) or {}).get("extra_data", {}).get("batch") or {}
            seconds += float(batch.get("wall_time_s") or 0.0)
    shown = ", ".join(changes[:4]) + (f" and {len(changes) - 4} more" if len(changes) > 4 else "")
    graded = counts.get("grade", 0)
    cost = (
        f"{graded} graded again, simulated (their last gradings took {seconds:.0f} s of "
        "worker time)"
        if graded
        else "nothing simulated"
    )
    rescored = counts.get("rescore", 0) + counts.get("rejudge", 0) + counts.get("adjust", 0)
    return (
        f"the assignment differs from the class's ({shown}): {rescored} submission(s) "
        f"re-scored from their stored figures, {cost}"
    )
