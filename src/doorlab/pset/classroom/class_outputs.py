"""What ``doorlab pset grade-all`` writes at the end of a run besides the sheet: the changes
and the sheet replaced (:mod:`doorlab.pset.classroom.regrade`), each submission's feedback page
(:mod:`doorlab.pset.classroom.feedback`), the class's statistics
(:mod:`doorlab.pset.classroom.class_statistics`: ``summary.json``, ``class.html``) and the gradebook
exports (:mod:`doorlab.pset.classroom.exports`: those asked for and those the folder has).

All of it is rebuilt from the class folder's results on every run (a figure is rendered once:
the feedback's cache), each file written atomically and recorded as doorlab's, so ``--force``
and ``--resume`` replace them and nothing else.
"""

from __future__ import annotations

import datetime
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from doorlab.pset.classroom import class_statistics, feedback, regrade


@dataclass(frozen=True)
class Outputs:
    """What a run writes at its end.

    Attributes:
        exports: Gradebook exports (:data:`doorlab.pset.classroom.gradebook.FORMATS`).
        pdf: Print each feedback page to PDF (headless Chromium).
        published: The course has published its grades: feedback pages show the
            ``after_published`` tests.
        now: The pages' time (default: now): ``after_due_date`` tests show after the due date.
        feedback: Write the feedback pages.
        only: Print only these submissions' pages (``--only``); empty: every page that is
            new, changed or without its PDF.
        roster: Canvas's gradebook export the ``canvas`` export is filled from (``--roster``).
    """

    exports: tuple[str, ...] = ()
    pdf: bool = False
    published: bool = False
    now: datetime.datetime | None = None
    feedback: bool = True
    only: tuple[str, ...] = ()
    roster: Path | None = None


Write = Callable[[Path, str, "str | bytes"], None]
"""Writes ``out/rel`` atomically and records it as doorlab's
(``doorlab.pset.classroom.class_folder``'s ``_write_text``)."""


def write_changes(out: Path, previous, changes: list[dict], write: Write) -> str | None:
    """``changes.csv``; the sheet this run replaces kept as ``history/grades-NNN.csv`` (when
    the run changed a row), with ``history/changes-NNN.csv``. ``previous.history``: the
    history's files as they were (``--force`` replaced the folder). Returns the kept sheet's
    name (None: nothing changed)."""
    for name, data in previous.history.items():
        if not (Path(out) / regrade.HISTORY / name).exists():
            write(out, f"{regrade.HISTORY}/{name}", data)
    text = regrade.changes_text(changes)
    write(out, regrade.CHANGES_CSV, text)
    if not changes:
        return None
    number = regrade.next_history_number(out)
    sheet = f"{regrade.HISTORY}/grades-{number:03d}.csv"
    write(out, sheet, previous.sheet)
    write(out, f"{regrade.HISTORY}/changes-{number:03d}.csv", text)
    return sheet


def changes_line(changes: list[dict]) -> str:
    """The summary's line on what a run over an existing sheet changed."""
    if not changes:
        return "changes: none (every submission kept as it was; changes.csv lists none)"
    actions: dict[str, int] = {}
    for row in changes:
        actions[row["action"]] = actions.get(row["action"], 0) + 1
    shown = {"grade": "graded again", "rescore": "re-scored", "rejudge": "re-judged"}
    parts = ", ".join(f"{n} {shown.get(a, a)}" for a, n in sorted(actions.items()))
    moved = sum(row["old_total"] != row["new_total"] for row in changes)
    return (
        f"changes: {len(changes)} submission{'s' if len(changes) != 1 else ''} regraded "
        f"({parts}), {moved} with a new total: "
        f"{regrade.CHANGES_CSV}; the sheet before: {regrade.HISTORY}/"
    )


def write_class_outputs(
    out: Path,
    submissions: list,
    rows: list[dict],
    results: dict[str, dict],
    assignment,
    outputs: Outputs | None,
    write: Write,
    exports=None,
) -> list[str]:
    """The feedback pages, ``summary.json``, ``class.html`` and the exports (``exports``: a
    :class:`doorlab.pset.classroom.exports.ExportPlan`; None: ``outputs.exports``); returns the
    summary's lines about them. (``write`` takes ``record=False``: the files are recorded in
    the folder's manifest together, once, not one rewrite of it per file.)"""
    from doorlab.runtime.folders import record_written

    outputs = outputs or Outputs()
    written: list[Path] = []

    def deferred(folder: Path, rel: str, data) -> None:
        write(folder, rel, data, record=False)
        written.append(Path(folder) / rel)

    if exports is None:
        from doorlab.pset.classroom.exports import ExportPlan

        exports = ExportPlan(tuple(outputs.exports))
    try:
        lines = _write_all(out, submissions, rows, results, assignment, outputs, deferred)
        from doorlab.pset.classroom.exports import write_exports

        return lines + write_exports(out, exports, submissions, rows, assignment, deferred)
    finally:
        record_written(out, written)


def _write_all(out, submissions, rows, results, assignment, outputs: Outputs, write) -> list[str]:
    from doorlab.pset.classroom.similarity import similar_groups

    lines = []
    stats = class_statistics.class_statistics(rows, results, similar_groups(submissions))
    write(out, class_statistics.SUMMARY_JSON, json.dumps(stats, indent=1) + "\n")
    write(out, class_statistics.CLASS_HTML, class_statistics.class_page(stats, assignment.title))
    lines.append(
        f"class statistics: {class_statistics.CLASS_HTML}, {class_statistics.SUMMARY_JSON}"
    )
    if outputs.feedback:
        now = outputs.now or datetime.datetime.now().astimezone()
        visibility = feedback.Visibility(now, outputs.published)
        by_id = {r["submission"]: r for r in rows}
        pages = [
            feedback.write_page(
                out, s, results.get(s.id), assignment, visibility, write, by_id.get(s.id)
            )
            for s in submissions
        ]
        chosen = [(p, w) for p, w in pages if not outputs.only or p.stem in outputs.only]
        pdfs = feedback.print_pages(out, chosen) if outputs.pdf and chosen else []
        changed = sum(written for _, written in pages)
        lines.append(
            f"feedback: {len(pages)} pages in {feedback.FEEDBACK}/ ({changed} new or changed)"
            + (f", {len(pdfs)} printed to PDF" if pdfs else "")
        )
    return lines
