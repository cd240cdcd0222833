"""A student's feedback page: ``feedback/<submission>.html`` (and, on request, its PDF).

One self-contained page per submission (Jinja2 template ``pset_feedback.html.j2``: the
figures are PNG data URIs, the CSS inline, no script, nothing fetched): the score, the late
penalty, each test's verdict and message, and for each episode that ran a figure of the
student's own episode against doorlab's reference (the door's opening, Q's radial error, L7's
orientation error along the 10 s arc), drawn from the series the grading stored in the
results (:func:`doorlab.pset.grading.episodes.episode_series`): nothing is simulated here.

What the page shows follows the tests' Gradescope visibility: a ``hidden`` test is never on
it, an ``after_due_date`` test once the due date (the assignment's late policy) has passed, an
``after_published`` test once the course says its grades are published (``published``). The
score is always the grade with the course's points, and says how many of them are in tests
the page does not show, the late penalty (and an extension) and the instructor's adjustments
(:mod:`doorlab.pset.classroom.final_grade`). A figure depends only on the two series it draws, so it
is rendered once and kept (``feedback/figures/<sha256>.png``): a regrade that changes points
or margins re-renders the pages, not the figures.
"""

from __future__ import annotations

import base64
import datetime
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from doorlab.pset.rules import verdicts

FEEDBACK = "feedback"
"""The folder of the pages in a class's folder."""
FIGURES = "figures"
"""The figures' cache under :data:`FEEDBACK`."""
FIGURE_STYLE = 2
"""Bumped when the figures' drawing changes (it is part of each figure's cache key)."""
EPISODES = {
    "student:ik": "Task 1: your IK (10 knots), doors open",
    "student:velocity": "Task 2: your velocity plan, doors open",
    "student:impedance": "Task 3: your impedance plan, doors closed",
}
"""The student's episodes, as the figures title them."""
PANELS = (
    ("door_opening_deg", "door opening [deg]"),
    ("radial_error_mm", "Q's radial error [mm]"),
    ("orientation_error_deg", "L7's orientation error [deg]"),
)


@dataclass(frozen=True)
class Visibility:
    """When the page is written: what the course lets students see.

    Attributes:
        now: The page's time (after_due_date tests are shown after the due date).
        published: The course has published its grades (after_published tests are shown).
    """

    now: datetime.datetime
    published: bool = False

    def shows(self, visibility: str, due: datetime.datetime | None) -> bool:
        """Whether a test of this Gradescope visibility is shown."""
        if visibility == "hidden":
            return False
        if visibility == "after_due_date":
            return self.published or (due is not None and self.now >= due)
        if visibility == "after_published":
            return self.published
        return True

    @staticmethod
    def later(visibility: str, due: datetime.datetime | None) -> str:
        """What the page says of a test it does not show yet."""
        if visibility == "after_due_date":
            when = f" ({due.isoformat()})" if due is not None else ""
            return f"shown after the due date{when}"
        return "shown once the course publishes its grades"


def _series(entry: object) -> dict | None:
    figures = entry.get("figures") if isinstance(entry, dict) else None
    series = figures.get("series") if isinstance(figures, dict) else None
    ok = isinstance(series, dict) and isinstance(series.get("t_s"), list) and series["t_s"]
    return series if ok else None


def _figure_png(title: str, yours: dict, reference: dict | None) -> bytes:
    """The three panels of one episode, the student's against the reference's, as PNG."""
    import io

    from matplotlib.figure import Figure

    fig = Figure(figsize=(10.5, 2.9))
    axes = fig.subplots(1, len(PANELS))
    # Margins set by hand: matplotlib's constrained layout measures every label and took a
    # third of the figure's time (0.16 against 0.11 CPU-s), for the same look here.
    fig.subplots_adjust(left=0.075, right=0.99, bottom=0.17, top=0.88, wspace=0.36)
    for ax, (key, label) in zip(axes, PANELS, strict=True):
        if reference is not None and key in reference:
            ax.plot(reference["t_s"], reference[key], color="0.45", lw=2.2, label="reference")
        if key in yours:
            ax.plot(yours["t_s"], yours[key], color="#c0392b", lw=1.3, label="yours")
        ax.set_xlabel("time from the arc's start [s]")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.4)
    axes[0].legend(loc="best", fontsize="small")
    fig.suptitle(title, fontsize="medium", y=0.98)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=90, pil_kwargs={"compress_level": 4})
    return buffer.getvalue()


def figure_key(yours: dict, reference: dict | None, title: str) -> str:
    """The cache key of a figure: SHA-256 of what it draws."""
    text = json.dumps([FIGURE_STYLE, title, yours, reference], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def episode_figures(results: dict, out: Path, shown: set[str], write) -> list[dict]:
    """The figures of the episodes of the tests ``shown`` (by job), rendered or taken from
    ``out/feedback/figures`` (``write(out, rel, data)`` writes a file doorlab owns)."""
    extra = results.get("extra_data") or {}
    episodes = extra.get("episodes") or {}
    reference = extra.get("reference") or {}
    figures = []
    for job, title in EPISODES.items():
        yours = _series(episodes.get(job))
        if job not in shown or yours is None:
            continue
        ref = _series(reference.get(job.replace("student:", "reference:")))
        rel = f"{FEEDBACK}/{FIGURES}/{figure_key(yours, ref, title)}.png"
        path = Path(out) / rel
        if path.is_file() and not path.is_symlink():
            data = path.read_bytes()
        else:
            data = _figure_png(title, yours, ref)
            write(out, rel, data)
        caption = f"{title}: yours (red) against doorlab's reference (grey)" + (
            "" if ref is not None else " (the reference's series is not in this grading)"
        )
        figures.append(
            {"job": job, "data": base64.b64encode(data).decode("ascii"), "caption": caption}
        )
    return figures


def page_context(submission, results: dict, assignment, visibility: Visibility) -> dict:
    """What the page shows of ``results`` (the figures come later: :func:`write_page`)."""
    from doorlab import __version__
    from doorlab.pset.rules.assignment import parse_due

    due = parse_due(assignment.late.due)
    extra = results.get("extra_data") or {}
    by_name = {t["name"]: t for t in results.get("tests", [])}
    tests, later, shown_jobs = [], [], set()
    for spec in verdicts.TESTS:
        t = by_name.get(spec.name)
        if t is None:
            continue
        vis = t.get("visibility", "visible")
        if not visibility.shows(vis, due):
            if vis != "hidden":
                later.append({"name": spec.name, "when": Visibility.later(vis, due)})
            continue
        shown_jobs.update(j for j in spec.jobs if j.startswith("student:"))
        tests.append(
            {
                "number": spec.number,
                "name": spec.name,
                "score": t.get("score", 0.0),
                "max_score": t.get("max_score", 0.0),
                "passed": t.get("status") == "passed",
                "output": str(t.get("output") or ""),
            }
        )
    late = extra.get("late") if isinstance(extra.get("late"), dict) else None
    people = ", ".join(p.get("name", "") for p in submission.submitters if p.get("name"))
    seed = extra.get("seed") if isinstance(extra.get("seed"), dict) else {}
    adjusted = extra.get("adjusted") if isinstance(extra.get("adjusted"), dict) else {}
    return {
        "title": f"{assignment.title}: feedback for {submission.id}",
        "meta": [
            ("submission", submission.id),
            ("students", people or "(not named in the export)"),
            ("submitted", submission.created_at or "(no time in the export)"),
            ("graded by", f"doorlab {__version__}"),
            ("grading seed", str(seed.get("grading", "")) if seed else "not graded"),
        ],
        "tests": tests,
        "later": later,
        "shown_jobs": shown_jobs,
        "score": sum(t["score"] for t in tests),
        "max_score": float(extra.get("max_score") or sum(t["max_score"] for t in tests)),
        "final": float(results.get("score") or 0.0),
        "notes": _score_notes(by_name, tests, late, adjusted),
        "late": late if late and late.get("penalty_points") else None,
        "adjustments": list(adjusted.get("lines") or []),
        "output": str(results.get("output") or ""),
    }


def _score_notes(by_name: dict, shown: list[dict], late: dict | None, adjusted: dict) -> list:
    """What the page's score says besides the grade: the points in tests not shown (hidden,
    or shown later), the late penalty (and an extension), the instructor's adjustments."""
    names = {t["name"] for t in shown}
    unseen: dict[str, list[float]] = {}
    for name, t in by_name.items():
        if name not in names:
            kind = "hidden" if t.get("visibility") == "hidden" else "later"
            unseen.setdefault(kind, []).append(float(t["max_score"]))
    notes = []
    for kind, points in sorted(unseen.items()):
        plural = "s" if len(points) != 1 else ""
        what = f"hidden test{plural}" if kind == "hidden" else f"test{plural} not shown yet"
        total = sum(points)
        notes.append(
            f"{total:g} point{'s' if total != 1 else ''} in {len(points)} {what} (not on this page)"
        )
    if late and late.get("penalty_points"):
        days = late.get("days_late")
        notes.append(
            f"after the late penalty: {float(late['penalty_points']):g} points, "
            f"{float(late['penalty_percent']):g} %, {days} day{'s' if days != 1 else ''} late"
        )
    if late and late.get("extension"):
        notes.append(f"due {late.get('due')}: {late['extension']}")
    if adjusted.get("points"):
        notes.append(f"the instructor's adjustments: {float(adjusted['points']):+g}")
    return notes


def ungraded_context(submission, assignment, row: dict | None) -> dict:
    """The page of a submission without results: absent (named in the export, nothing
    uploaded) or its grading failed (the course grades it again)."""
    status = (row or {}).get("status", "absent")
    why = (
        "No submission was received: the course's export names you, with no files."
        if status == "absent"
        else "Your submission could not be graded yet (the grader failed, not your code); "
        "the course grades it again."
    )
    people = ", ".join(p.get("name", "") for p in submission.submitters if p.get("name"))
    return {
        "title": f"{assignment.title}: feedback for {submission.id}",
        "meta": [("submission", submission.id), ("students", people or "(not named)")],
        "tests": [],
        "later": [],
        "final": None,
        "why": why,
        "adjustments": [],
        "figures": [],
        "output": "",
    }


def write_page(
    out: Path, submission, results: dict | None, assignment, visibility, write, row=None
) -> tuple[Path, bool]:
    """Writes ``out/feedback/<submission>.html`` unless it holds this page already (a page
    depends only on the results and what is shown, not on when it is written); returns it
    and whether it was written. Without ``results`` (absent, or its grading failed: ``row``
    says which), a page that says so."""
    from doorlab.outputs.pages import render

    if results is None:
        context = ungraded_context(submission, assignment, row)
    else:
        context = page_context(submission, results, assignment, visibility)
        context["figures"] = episode_figures(results, out, context.pop("shown_jobs"), write)
    rel = f"{FEEDBACK}/{submission.id}.html"
    path = Path(out) / rel
    text = render("pset_feedback.html.j2", **context)
    try:
        same = path.is_file() and not path.is_symlink() and path.read_text() == text
    except (OSError, UnicodeDecodeError):
        same = False
    if not same:
        write(out, rel, text)
    return path, not same


def print_pages(out: Path, pages: list[tuple[Path, bool]]) -> list[Path]:
    """Prints to a PDF beside it (headless Chromium, :mod:`doorlab.runtime.pdf`) each page
    written this run or without its PDF; returns the PDFs printed.

    Raises:
        OutputError: No Chromium, or it failed.
    """
    from doorlab.runtime.folders import record_written
    from doorlab.runtime.pdf import find_chromium, print_pdf

    todo = [page for page, written in pages if written or not page.with_suffix(".pdf").is_file()]
    if not todo:
        return []
    chromium = find_chromium()
    printed = [print_pdf(page, page.with_suffix(".pdf"), chromium=chromium) for page in todo]
    record_written(out, printed)
    return printed
