"""The course's settings in the students' handout, and the self-check that grades with them.

``doorlab pset handout OUT.zip --assignment FILE`` writes ``pset5/course.yaml``
(:data:`COURSE_FILE`): the assignment as students may see it. Every test but the hidden ones
is there with its points, visibility and margins, and the course's random seed, title and
late policy; a hidden test's settings stay with the instructor (its entry is left out, and
the self-check neither runs nor names it). The folder's ``test_pset_5a.py`` (the notebook's
last cell) grades with this file (:func:`load_course`): the course's points and total, the
course's margins, the tests the course lets students run (``self_check``), and it says which
tests Gradescope shows only after the due date or once grades are published. The students'
doorlab holds no answer key: it judges against the handout's practice table, whose draws come
from the course's random seed (:mod:`doorlab.pset.handout.edition`); the course's grading draws its
own from each submission's files.

The random seed is no secret worth keeping: the course's grading draws the unit tests' inputs
from it and the SHA-256 of the student's own files, and those inputs are handed to the
student's code anyway; a change to a file changes them all.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from doorlab.errors import ConfigError
from doorlab.pset.rules import verdicts
from doorlab.pset.rules.assignment import (
    Assignment,
    _test_lines,
    _top_lines,
    parse_assignment,
)
from doorlab.runtime.inputs import load_yaml, read_text_file

COURSE_FILE = "course.yaml"
"""The course's settings in the handout's folder (read by its ``test_pset_5a.py``)."""

LATER = {
    "after_due_date": "Gradescope shows this test after the due date",
    "after_published": "Gradescope shows this test once the course publishes its grades",
}
"""What the self-check says of a test whose result Gradescope shows later."""


def shown_tests(assignment: Assignment) -> list[str]:
    """The keys of the tests students may see the settings of: every test but the hidden ones."""
    return [
        t.key for t in verdicts.TESTS if getattr(assignment.tests, t.key).visibility != "hidden"
    ]


HIDDEN_POINTS = "hidden_points"
"""``course.yaml``'s key for the points of the course's hidden tests (their number only: the
self-check's total is the course's)."""


def hidden_points(assignment: Assignment) -> float:
    """The points of the assignment's hidden tests."""
    keys = shown_tests(assignment)
    return sum(
        float(getattr(assignment.tests, t.key).points) for t in verdicts.TESTS if t.key not in keys
    )


def course_yaml(assignment: Assignment) -> str:
    """``course.yaml``'s text: the assignment without its hidden tests' settings (but how
    many points they carry: :data:`HIDDEN_POINTS`)."""
    keys = shown_tests(assignment)
    header = [
        "# Your course's grading settings, for this folder's self-check (test_pset_5a.py).",
        "# Written by doorlab pset handout from the course's assignment file. Changing this",
        "# copy changes only your own check, not how the course grades.",
    ]
    lines = header + _top_lines(assignment) + _test_lines(assignment, keys)
    hidden = hidden_points(assignment)
    if hidden:
        lines.append(
            f"{HIDDEN_POINTS}: {hidden!r}  # [points] in tests the course grades but does not "
            "list here (hidden)"
        )
    return "\n".join(lines) + "\n"


@dataclass
class SelfCheck:
    """What the folder's self-check grades with.

    Attributes:
        assignment: The settings (tests not in the file keep the defaults and are not run).
        run: The names of the tests it runs.
        not_run: The course's tests it does not run: ``{"name", "points", "why"}``.
        notes: Test name -> what to know about its result (shown by Gradescope later).
        course_points: The points of every test in the file (the course's total, hidden
            tests aside).
        source: Where the settings came from (for the summary's first line).
        hidden_points: The points of the course's hidden tests (in its total, never run
            or shown here).
    """

    assignment: Assignment
    run: tuple[str, ...]
    not_run: list[dict] = field(default_factory=list)
    notes: dict[str, str] = field(default_factory=dict)
    course_points: float = 0.0
    source: str = ""
    hidden_points: float = 0.0

    def to_dict(self) -> dict:
        """The results' ``extra_data.self_check``."""
        return {
            "source": self.source,
            "course_points": self.course_points,
            "hidden_points": self.hidden_points,
            "not_run": self.not_run,
            "notes": self.notes,
        }


def self_check(assignment: Assignment, keys: list[str], source: str) -> SelfCheck:
    """The self-check of the tests ``keys`` (those in the course's file) under ``assignment``."""
    run, not_run, notes, total = [], [], {}, 0.0
    for spec in verdicts.TESTS:
        if spec.key not in keys:
            continue
        settings = getattr(assignment.tests, spec.key)
        total += settings.points
        if settings.self_check:
            run.append(spec.name)
            if settings.visibility in LATER:
                notes[spec.name] = LATER[settings.visibility]
        else:
            why = LATER.get(settings.visibility, "the course does not run it in this check")
            not_run.append({"name": spec.name, "points": settings.points, "why": why})
    return SelfCheck(assignment, tuple(run), not_run, notes, total, source)


def load_course(path: str | Path) -> SelfCheck:
    """The self-check of a folder's ``course.yaml``.

    Raises:
        ConfigError: The file cannot be read or is not a course's settings (one line).
    """
    text = read_text_file(path, what="course settings")
    try:
        data = load_yaml(text) or {}
        hidden = data.pop(HIDDEN_POINTS, 0.0) if isinstance(data, dict) else 0.0
        if not isinstance(hidden, (int, float)) or isinstance(hidden, bool) or hidden < 0:
            raise ConfigError(f"{HIDDEN_POINTS} must be a number >= 0, got {hidden!r}")
        # JSON is YAML: the settings without the key the assignment does not have.
        assignment = parse_assignment(json.dumps(data, default=str) if data else text)
    except ConfigError as e:
        raise ConfigError(f"course settings {str(path)!r}: {e}") from None
    tests = data.get("tests") if isinstance(data, dict) else None
    keys = list(tests) if isinstance(tests, dict) else [t.key for t in verdicts.TESTS]
    check = self_check(assignment, keys, f"your course's settings ({Path(path).name})")
    check.hidden_points = float(hidden)
    return check


def default_check() -> SelfCheck:
    """The self-check of a folder without the course's file: the grader's defaults."""
    keys = [t.key for t in verdicts.TESTS]
    return self_check(Assignment(), keys, "the grader's defaults (no course.yaml here)")
