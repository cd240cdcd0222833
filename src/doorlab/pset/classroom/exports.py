"""Which gradebook exports a run of ``grade-all`` writes, checked before it grades.

Nothing in a class's folder is left stale: every run that ends (not interrupted) rewrites
each export it finds in the folder (``canvas.csv``, ``gradescope.csv``) from the sheet it
writes, besides those ``--export`` asks for, so after ``--resume``, ``--only`` or a re-score
every export equals the sheet. A Canvas export filled from the course's roster
(``--roster``) keeps a copy of that roster in the folder (``canvas_roster.csv``) and is
filled from it again by later runs (a new ``--roster`` replaces it). An interrupted run
writes none of them (nor the sheet: :mod:`doorlab.pset.classroom.grade_all`).

Before anything is graded, :func:`doorlab.pset.classroom.gradebook.check_exports` refuses an
export that would give one row to two students (a shared SID or e-mail).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from doorlab.pset.classroom import canvas, gradebook


@dataclass
class ExportPlan:
    """The exports a run writes.

    Attributes:
        formats: The formats (:data:`doorlab.pset.classroom.gradebook.FORMATS`), in order.
        found: Those written because the folder had them (not asked for).
        roster: Canvas's roster the ``canvas`` export is filled from (None: none).
        roster_bytes: Its bytes, to keep in the folder (None: the folder's copy is kept).
        roster_source: Where the roster came from (for the summary).
    """

    formats: tuple[str, ...] = ()
    found: tuple[str, ...] = ()
    roster: canvas.Roster | None = None
    roster_bytes: bytes | None = field(default=None, repr=False)
    roster_source: str = ""


def plan_exports(out: Path, requested, roster_path: Path | None) -> ExportPlan:
    """The exports of a run over the folder ``out`` (``requested``: ``--export``'s;
    ``roster_path``: ``--roster``).

    Raises:
        ConfigError: The roster cannot be read or is not Canvas's gradebook export.
    """
    out = Path(out)
    found = tuple(
        f for f in gradebook.FORMATS if f not in requested and (out / gradebook.FILES[f]).is_file()
    )
    formats = tuple(f for f in gradebook.FORMATS if f in requested or f in found)
    plan = ExportPlan(formats, found)
    if roster_path is not None:
        plan.roster, plan.roster_bytes = canvas.read_roster(Path(roster_path))
        plan.roster_source = str(roster_path)
    elif (out / canvas.ROSTER_COPY).is_file():
        plan.roster, plan.roster_bytes = canvas.read_roster(out / canvas.ROSTER_COPY)
        plan.roster_source = f"{canvas.ROSTER_COPY} (the roster an earlier run was given)"
    return plan


def write_exports(out: Path, plan: ExportPlan, submissions, rows, assignment, write) -> list[str]:
    """Writes each export of ``plan`` (and the roster's copy); returns the summary's lines."""
    lines = []
    by_id = {r["submission"]: r for r in rows}
    if plan.roster_bytes is not None and "canvas" in plan.formats:
        write(out, canvas.ROSTER_COPY, plan.roster_bytes)
    for fmt in plan.formats:
        roster = plan.roster if fmt == "canvas" else None
        text, notes = gradebook.export_text(fmt, submissions, by_id, assignment, roster)
        write(out, gradebook.FILES[fmt], text)
        count = len(text.splitlines()) - (2 if fmt == "canvas" else 1)
        why = " (found in the folder: rewritten from this sheet)" if fmt in plan.found else ""
        source = f", filled from {plan.roster_source}" if roster is not None else ""
        lines.append(f"{fmt} export: {gradebook.FILES[fmt]} ({count} students{source}){why}")
        lines += [f"  {note}" for note in notes]
    return lines
