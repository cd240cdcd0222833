"""A class's statistics: ``summary.json`` and the page ``class.html``, from the sheet and the
results (nothing is graded here).

:func:`class_statistics` gives the figures both show: the submissions by status, the score
distribution (mean, median, spread, a histogram of the totals), each test's pass rate and
mean score and its most common messages (the first failing check of each failed test, its
numbers replaced by ``#``, so that the same mistake counts as one: what a lecture should
address), the time per submission, and the groups of submissions whose graded files are
identical. The page draws the histogram, the pass rates and the times (matplotlib) and lists
the rest; it is self-contained (Jinja2 template ``pset_class.html.j2``).
"""

from __future__ import annotations

import math
import re
import statistics
from collections import Counter

from doorlab.pset.rules import verdicts

SUMMARY_JSON = "summary.json"
CLASS_HTML = "class.html"
SHOWN_SCORES = 12
"""Distinct total scores listed in the summary's distribution (the rest summed up)."""
MESSAGE_CHARS = 300
"""Longest message listed [characters] (shortened at a word)."""
NOT_ATTEMPTED = "NotImplementedError"
"""What a test left as its stub says (the stubs raise it)."""
_DIAGNOSIS = re.compile(r"^on \d+ of \d+ draws your answer is (.+)$")
"""A unit test's diagnosis line (:mod:`doorlab.pset.grading.checks`)."""
_NUMBER = re.compile(r"(?<![\w.])[-+]?(\d+\.\d*|\.\d+|\d+)([eE][-+]?\d+)?(?![\w])")
"""A number that is not part of a name (``calc_R_WL7_ref`` keeps its 7)."""


def _message(output: str) -> tuple[str, str]:
    """A failed test's mistake as a class-wide key, and its kind: the catalogue's diagnosis
    (``diagnosis``), else its first failing line (an episode's ``FAILED`` check, else the
    first line) with its numbers as ``#`` (``message``)."""
    import textwrap

    lines = [line.strip() for line in str(output).splitlines() if line.strip()]
    lines = [line for line in lines if not line.startswith("grading seed ")]  # a unit's header
    for line in lines:
        if match := _DIAGNOSIS.match(line):
            return "your answer is " + match.group(1), "diagnosis"
    failing = [line for line in lines if line.startswith("FAILED")]
    line = (failing or lines or ["(no message)"])[0].removeprefix("FAILED").strip()
    text = " ".join(_NUMBER.sub("#", line).split())
    return textwrap.shorten(text, MESSAGE_CHARS, placeholder=" ..."), "message"


def _quantiles(values: list[float]) -> dict:
    if not values:
        return {}
    return {
        "n": len(values),
        "mean": round(statistics.fmean(values), 3),
        "median": round(statistics.median(values), 3),
        "stdev": round(statistics.pstdev(values), 3),
        "min": min(values),
        "max": max(values),
    }


def _test_figures(spec, entries: list[dict]) -> dict:
    """One test's figures over the graded submissions' ``entries`` (its results entries)."""
    failed = [t for t in entries if t.get("status") != "passed"]
    stubs = [t for t in failed if NOT_ATTEMPTED in str(t.get("text_output", t.get("output")))]
    mistakes = Counter(
        _message(str(t.get("output", ""))) for t in failed if not any(t is x for x in stubs)
    )
    return {
        "key": spec.key,
        "number": spec.number,
        "name": spec.name,
        "max_score": max(float(t.get("max_score") or 0) for t in entries),
        "pass_rate": round(1 - len(failed) / len(entries), 4),
        "mean_score": round(statistics.fmean(float(t["score"]) for t in entries), 3),
        "graded": len(entries),
        "not_attempted": len(stubs),
        "messages": [
            {"message": m, "kind": kind, "count": n}
            for (m, kind), n in sorted(mistakes.items(), key=lambda x: (-x[1], x[0]))
        ],
    }


def class_statistics(
    rows: list[dict], results: dict[str, dict], similar: list[dict] | None = None
) -> dict:
    """The class's figures (``summary.json``): ``rows`` the sheet's, ``results`` by id,
    ``similar`` the groups of :func:`doorlab.pset.classroom.similarity.similar_groups`."""
    scored = [r for r in rows if r.get("status") in ("graded", "not_graded")]
    graded = [r["submission"] for r in rows if r.get("status") == "graded"]
    totals = [float(r["total"]) for r in scored if r.get("total") is not None]
    best = max((float(r.get("max_total") or 0) for r in scored), default=0.0)
    histogram = sorted(Counter(totals).items())
    from doorlab.pset.classroom.final_grade import restore

    judged = {sid: restore(results[sid]) for sid in graded if sid in results}  # no adjustment
    tests = []
    for spec in verdicts.TESTS:
        entries = [
            t
            for sid in graded
            for t in (judged.get(sid) or {}).get("tests", [])
            if t.get("name") == spec.name
        ]
        if entries:
            tests.append(_test_figures(spec, entries))
    times = [float(r["wall_time_s"]) for r in scored if _positive(r.get("wall_time_s"))]
    times_by_id = {
        r["submission"]: float(r["wall_time_s"]) for r in scored if _positive(r.get("wall_time_s"))
    }
    groups: dict[str, list[str]] = {}
    stubs = _stubs_digest()
    for r in rows:
        original = r.get("same_files_as")
        batch = ((results.get(original) or {}).get("extra_data") or {}).get("batch") or {}
        if original and batch.get("files_sha256") != stubs:  # the untouched stubs left out
            groups.setdefault(original, [original]).append(r["submission"])
    late = [r for r in scored if _positive(r.get("late_penalty"))]
    return {
        "submissions": len(rows),
        "by_status": dict(sorted(Counter(r.get("status") for r in rows).items())),
        "max_total": best,
        "scores": _quantiles(totals),
        "histogram": [{"total": total, "submissions": n} for total, n in histogram],
        "tests": tests,
        "time_per_submission_s": _quantiles(times),
        "times_s": times_by_id,
        "late": {"submissions": len(late), "points": sum(float(r["late_penalty"]) for r in late)},
        "identical_files": sorted(groups.values()),
        "similar_code": similar or [],
        "rows": [_student_row(r) for r in rows],
    }


def _stubs_digest() -> str:
    """The graded files' SHA-256 of the untouched stubs (as a grading records it)."""
    from doorlab.pset.classroom.regrade import _stubs
    from doorlab.pset.rules.assignment import bytes_digest

    return bytes_digest(dict(_stubs()))


def _student_row(row: dict) -> dict:
    """A submission's row of the page's table (its feedback page's link)."""
    keep = ("submission", "names", "total", "max_total", "status", "late_penalty", "adjustment")
    out = {k: row.get(k) for k in keep}
    out["page"] = f"feedback/{row['submission']}.html"
    out["note"] = row.get("error") or row.get("missing_files") or ""
    return out


def _positive(value: object) -> bool:
    try:
        return math.isfinite(float(value)) and float(value) > 0
    except (TypeError, ValueError):
        return False


def _figures(stats: dict) -> list[dict]:
    """The page's figures (PNG data): the score histogram, the pass rates, the times (margins
    set by hand: constrained layout cost a third of the drawing)."""
    import base64
    import io

    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    def png(fig) -> str:
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=90, pil_kwargs={"compress_level": 4})
        return base64.b64encode(buffer.getvalue()).decode("ascii")

    out = []
    if stats["histogram"]:
        fig = Figure(figsize=(6.4, 3.0))
        fig.subplots_adjust(left=0.1, right=0.98, bottom=0.16, top=0.96)
        ax = fig.subplots()
        xs = [h["total"] for h in stats["histogram"]]
        ax.bar(xs, [h["submissions"] for h in stats["histogram"]], width=0.8, color="#6a8fbf")
        ax.set_xlabel(f"total score (of {stats['max_total']:g})")
        ax.set_ylabel("submissions")
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlim(-1, stats["max_total"] + 1)
        ax.grid(True, axis="y", alpha=0.4)
        out.append({"id": "histogram", "data": png(fig), "caption": "The score histogram"})
    if stats["tests"]:
        fig = Figure(figsize=(6.4, 3.2))
        fig.subplots_adjust(left=0.3, right=0.97, bottom=0.15, top=0.97)
        ax = fig.subplots()
        labels = [f"{t['number']} {t['key']}" for t in stats["tests"]]
        ax.barh(labels[::-1], [100 * t["pass_rate"] for t in stats["tests"]][::-1], color="#5b9a68")
        ax.set_xlim(0, 100)
        ax.set_xlabel("submissions that passed [%]")
        ax.grid(True, axis="x", alpha=0.4)
        out.append({"id": "pass-rates", "data": png(fig), "caption": "Each test's pass rate"})
    if stats["times_s"]:
        fig = Figure(figsize=(6.4, 3.0))
        fig.subplots_adjust(left=0.1, right=0.98, bottom=0.16, top=0.96)
        ax = fig.subplots()
        ax.hist(
            list(stats["times_s"].values()), bins=min(20, len(stats["times_s"])), color="#b07d48"
        )
        ax.set_xlabel("wall time of a grading [s] (its worker's, the queue aside)")
        ax.set_ylabel("submissions")
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(True, axis="y", alpha=0.4)
        out.append({"id": "times", "data": png(fig), "caption": "The time per submission"})
    return out


def class_page(stats: dict, title: str) -> str:
    """``class.html``'s text."""
    from doorlab.outputs.pages import render

    return render(
        "pset_class.html.j2", title=f"{title}: the class", stats=stats, figures=_figures(stats)
    )


def summarize(rows: list[dict], keys: list[str], total: int) -> list[str]:
    """The summary: counts by status, the score distribution, the most often failed tests."""
    from doorlab.pset.rules.verdicts import TESTS

    counts = Counter(r.get("status") for r in rows)
    parts = [f"{n} {status.replace('_', ' ')}" for status, n in sorted(counts.items())]
    lines = [f"{len(rows)} of {total} submissions in the sheet: " + ", ".join(parts)]
    scored = [r for r in rows if r.get("status") in ("graded", "not_graded")]
    if scored:
        totals = [float(r["total"]) for r in scored]
        best = max(float(r.get("max_total") or 0) for r in scored)
        lines.append(
            f"scores (of {best:g}): mean {statistics.fmean(totals):.2f}, median "
            f"{statistics.median(totals):g}, min {min(totals):g}, max {max(totals):g}"
        )
        by_score = sorted(Counter(totals).items(), reverse=True)
        shown = [f"{score:g}: {n}" for score, n in by_score[:SHOWN_SCORES]]
        if len(by_score) > SHOWN_SCORES:
            shown.append(f"others: {sum(n for _, n in by_score[SHOWN_SCORES:])}")
        lines.append("distribution (total: submissions): " + ", ".join(shown))
        names = {t.key: t.name for t in TESTS}
        failed = Counter(k for r in scored for k in keys if r.get(k) is not None and r[k] <= 0)
        if failed:
            top = failed.most_common(3)
            lines.append(
                "most often failed: "
                + "; ".join(f"{names.get(k, k)} ({n} of {len(scored)})" for k, n in top)
            )
    errors = [r for r in rows if r.get("status") == "error"]
    if errors:
        lines.append(
            f"{len(errors)} grading errors (the grader's, not the students'; --resume grades "
            f"them again), first: {errors[0]['submission']}: {errors[0].get('error', '')}"
        )
    return lines
