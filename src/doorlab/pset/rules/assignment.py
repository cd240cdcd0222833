"""The assignment file: a course's grading settings, typed and validated like a scenario.

``doorlab pset assignment FILE`` writes the defaults (with a fresh random seed);
``doorlab pset grade --assignment FILE`` and ``doorlab pset autograder OUT.zip --assignment
FILE`` grade with it (the zip carries it, inside its digest). Every key is optional (the
defaults below); unknown keys, wrong types and values out of range are one-line errors naming
the dotted field::

    seed: 1234567                 # the course's; with each submission's files, its random inputs
    visibility: visible           # the results' top-level Gradescope visibility
    stdout_visibility: hidden     # Gradescope's: whether students see the autograder's stdout
    title: Problem set 5          # the gradebook column (doorlab pset grade-all --export canvas)
    late:
      due: '2024-03-01T23:59:00-05:00'  # ISO 8601 with its UTC offset ('' = no due date)
      grace_minutes: 15           # [min] this late costs nothing
      penalty_per_day_percent: 10  # [%] of the score, per day late or part of one
      max_penalty_percent: 50     # [%] the cap
    tests:
      calc_p_Q_unit: {points: 1, visibility: visible}
      velocity_episode:
        points: 2
        visibility: after_due_date
        orientation_margin: 0.01  # [rad]
        arc_end_margin_deg: 2.0   # [deg]
        helpers: reference        # calc_p_Q and calc_R_WL7_ref: doorlab's, or the student's
        self_check: true          # run by the handout's self-check (test_pset_5a.py)

The handout carries what students may see of it (:mod:`doorlab.pset.handout.course`: every test but
the hidden ones); the rest stays with the instructor. The defaults are the grader's
(:data:`doorlab.pset.rules.verdicts.TESTS` and its margins), so a grading without a file is a
grading with the default file (random seed 0).

(No ``from __future__ import annotations`` here: ``yaml_load_typed`` reads the dataclasses'
field types, which must be classes, not strings.)
"""

import dataclasses
import datetime
import hashlib
import json
import math
import secrets
import typing
from dataclasses import dataclass, field
from pathlib import Path

from doorlab.errors import ConfigError, OutputError
from doorlab.pset.rules import verdicts
from doorlab.runtime.inputs import load_yaml, quote, read_text_file

VISIBILITIES = ("visible", "hidden", "after_due_date", "after_published")
"""Gradescope's visibility settings (its Autograder Specifications)."""
HELPERS = ("reference", "student")
"""Whose calc_p_Q and calc_R_WL7_ref the task 2 and 3 episodes run."""
MAX_SEED = 2**63 - 1
MAX_POINTS = 1000.0
"""Most points one test may carry (a typo guard)."""
SEED_BITS = 32
"""Bits of the random seed ``doorlab pset assignment`` draws, and of a grading seed."""
TITLE_CHARS = 100
"""Longest assignment title (a gradebook column's name)."""
MAX_GRACE_MINUTES = 7 * 24 * 60.0
"""Longest grace period [min] (a week)."""


def _points(key: str) -> float:
    return next(t.max_score for t in verdicts.TESTS if t.key == key)


@dataclass
class UnitTestSettings:
    """A unit test."""

    points: float = 1.0  # [points]
    visibility: str = "visible"  # one of VISIBILITIES
    self_check: bool = True  # run by the handout's self-check (never for a hidden test)


@dataclass
class IkEpisodeSettings:
    """Task 1's episode: the student's IK with 10 knots, doors open."""

    points: float = 2.0  # [points]
    visibility: str = "visible"  # one of VISIBILITIES
    # [m] how much more Q's max radial error may be than the reference IK's (2 sqrt(2) mm:
    # each knot may sit anywhere in the +-1 mm box)
    radial_margin: float = verdicts.IK_RADIAL_MARGIN
    # [deg] Q's angle about the hinge at the arc's end vs the reference's
    arc_end_margin_deg: float = verdicts.ARC_END_MARGIN_DEG
    self_check: bool = True  # run by the handout's self-check (never for a hidden test)


@dataclass
class VelocityEpisodeSettings:
    """Task 2's episode: the student's velocity plan, doors open."""

    points: float = 2.0  # [points]
    visibility: str = "visible"  # one of VISIBILITIES
    # [rad] how much larger L7's max orientation error may be than the reference plan's
    orientation_margin: float = verdicts.VELOCITY_ORIENTATION_MARGIN
    arc_end_margin_deg: float = verdicts.ARC_END_MARGIN_DEG  # [deg]
    helpers: str = "reference"  # one of HELPERS: whose calc_p_Q and calc_R_WL7_ref it runs
    self_check: bool = True  # run by the handout's self-check (never for a hidden test)


@dataclass
class ImpedanceEpisodeSettings:
    """Task 3's episode: the student's impedance plan, doors closed."""

    points: float = 2.0  # [points]
    visibility: str = "visible"  # one of VISIBILITIES
    # [deg] the door's opening by the arc's end vs the reference plan's
    door_opening_margin_deg: float = verdicts.DOOR_OPENING_MARGIN_DEG
    helpers: str = "reference"  # one of HELPERS
    self_check: bool = True  # run by the handout's self-check (never for a hidden test)


def _unit(key: str):
    return field(default_factory=lambda: UnitTestSettings(points=_points(key)))


@dataclass
class TestsSettings:
    """Every graded test's settings (keys: :attr:`doorlab.pset.rules.verdicts.TestSpec.key`)."""

    ik_unit: UnitTestSettings = _unit("ik_unit")
    calc_p_Q_unit: UnitTestSettings = _unit("calc_p_Q_unit")
    calc_R_WL7_ref_unit: UnitTestSettings = _unit("calc_R_WL7_ref_unit")
    velocity_unit: UnitTestSettings = _unit("velocity_unit")
    impedance_unit: UnitTestSettings = _unit("impedance_unit")
    ik_episode: IkEpisodeSettings = field(
        default_factory=lambda: IkEpisodeSettings(points=_points("ik_episode"))
    )
    velocity_episode: VelocityEpisodeSettings = field(
        default_factory=lambda: VelocityEpisodeSettings(points=_points("velocity_episode"))
    )
    impedance_episode: ImpedanceEpisodeSettings = field(
        default_factory=lambda: ImpedanceEpisodeSettings(points=_points("impedance_episode"))
    )


@dataclass
class LatePolicy:
    """When the assignment is due and what lateness costs, applied from each submission's
    time (:mod:`doorlab.pset.classroom.late`: Gradescope's ``submission_metadata``)."""

    # ISO 8601 with its UTC offset, e.g. 2024-03-01T23:59:00-05:00 ('' = no due date, no penalty)
    due: str = ""
    grace_minutes: float = 0.0  # [min] a submission at most this late costs nothing
    # [%] of the score earned, per day late or part of a day (after the grace)
    penalty_per_day_percent: float = 0.0
    max_penalty_percent: float = 100.0  # [%] the penalty's cap


@dataclass
class Assignment:
    """A course's grading settings."""

    # [-] the course's seed (0 <= seed < 2^63): with each submission's graded files (their
    # SHA-256) it draws the unit tests' random inputs, so a regrade draws the same ones
    seed: int = 0
    visibility: str = "visible"  # one of VISIBILITIES: the results' top level
    stdout_visibility: str = "hidden"  # one of VISIBILITIES: the autograder's stdout
    title: str = "Problem set 5"  # the assignment's gradebook column (Canvas's export)
    late: LatePolicy = field(default_factory=LatePolicy)
    tests: TestsSettings = field(default_factory=TestsSettings)

    def to_dict(self) -> dict:
        """The settings as plain data (what the grader's supervisor receives)."""
        return dataclasses.asdict(self)

    def digest(self) -> str:
        """SHA-256 (hex) of the settings (not of a file's spelling of them)."""
        text = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()


def _check(condition: bool, message: str) -> None:
    if not condition:
        raise ConfigError(message)


def _number(name: str, value: object, low: float, high: float) -> None:
    _check(
        isinstance(value, (int, float))
        and not isinstance(value, bool)
        and math.isfinite(value)
        and low <= value <= high,
        f"{name} must be a number in [{low:g}, {high:g}], got {quote(value)}",
    )


def _choice(name: str, value: object, choices: tuple[str, ...]) -> None:
    _check(value in choices, f"{name} must be one of {', '.join(choices)}; got {quote(value)}")


_MARGINS = {
    "radial_margin": 0.1,  # [m] a tenth of a metre: the whole handle's arc is ~0.3 m long
    "orientation_margin": 1.0,  # [rad]
    "arc_end_margin_deg": 90.0,  # [deg]
    "door_opening_margin_deg": 90.0,  # [deg]
}
"""Each margin's largest value (a margin beyond it would pass anything)."""


def validate_assignment(assignment: Assignment) -> Assignment:
    """Checks every field's type and range; returns the assignment.

    Raises:
        ConfigError: Naming the first offending dotted field and its valid range.
    """
    _check(isinstance(assignment, Assignment), "expected an Assignment")
    seed = assignment.seed
    _check(
        isinstance(seed, int) and not isinstance(seed, bool) and 0 <= seed <= MAX_SEED,
        f"seed must be an integer in [0, 2^63 - 1], got {quote(seed)}",
    )
    _choice("visibility", assignment.visibility, VISIBILITIES)
    _choice("stdout_visibility", assignment.stdout_visibility, VISIBILITIES)
    _check_title(assignment.title)
    _check_late(assignment.late)
    for f in dataclasses.fields(TestsSettings):
        settings = getattr(assignment.tests, f.name)
        name = f"tests.{f.name}"
        _number(f"{name}.points", settings.points, 0.0, MAX_POINTS)
        settings.points = float(settings.points)  # 2 and 2.0 are the same settings
        _choice(f"{name}.visibility", settings.visibility, VISIBILITIES)
        for margin, high in _MARGINS.items():
            if hasattr(settings, margin):
                _number(f"{name}.{margin}", getattr(settings, margin), 0.0, high)
                setattr(settings, margin, float(getattr(settings, margin)))
        if hasattr(settings, "helpers"):
            _choice(f"{name}.helpers", settings.helpers, HELPERS)
        _check(
            isinstance(settings.self_check, bool),
            f"{name}.self_check must be true or false, got {quote(settings.self_check)}",
        )
    return assignment


def _check_title(title: object) -> None:
    _check(
        isinstance(title, str)
        and title.strip() == title
        and 0 < len(title) <= TITLE_CHARS
        and title.isprintable()
        and not title.startswith(("=", "+", "-", "@")),
        f"title must be 1 to {TITLE_CHARS} printable characters, not starting with a space, "
        f"=, +, - or @ (it names a gradebook column), got {quote(title)}",
    )


def parse_due(text: str) -> datetime.datetime | None:
    """A due date (ISO 8601 with its UTC offset) as an aware datetime; None for ''.

    Raises:
        ConfigError: Not such a date, or no UTC offset.
    """
    if text == "":
        return None
    message = (
        f"late.due must be a date and time in ISO 8601 with its UTC offset, e.g. "
        f"2024-03-01T23:59:00-05:00 (or '' for none), got {quote(text)}"
    )
    try:
        due = datetime.datetime.fromisoformat(text)
    except (TypeError, ValueError):
        raise ConfigError(message) from None
    _check(due.tzinfo is not None and due.utcoffset() is not None, message)
    return due


def _check_late(late: LatePolicy) -> None:
    _check(isinstance(late, LatePolicy), "late must be a mapping of fields")
    _check(isinstance(late.due, str), f"late.due must be text, got {quote(late.due)}")
    parse_due(late.due)
    _number("late.grace_minutes", late.grace_minutes, 0.0, MAX_GRACE_MINUTES)
    _number("late.penalty_per_day_percent", late.penalty_per_day_percent, 0.0, 100.0)
    _number("late.max_penalty_percent", late.max_penalty_percent, 0.0, 100.0)
    for name in ("grace_minutes", "penalty_per_day_percent", "max_penalty_percent"):
        setattr(late, name, float(getattr(late, name)))


def parse_assignment(document: str) -> Assignment:
    """An assignment from a YAML document (keys left out keep the defaults), validated.

    Raises:
        ConfigError: Invalid YAML, unknown keys, wrong types or out-of-range values.
    """
    data = load_yaml(document)  # within doorlab.runtime.inputs' budget (no aliases, bounded)
    if data is None:
        return validate_assignment(Assignment())
    # The scenario's checker (any dataclass schema) and Drake's loader, imported here: the
    # grader's supervisor builds its assignment from data (assignment_from_dict), not YAML.
    from pydrake.common.yaml import yaml_load_typed

    from doorlab.config import _check_shape

    _check(isinstance(data, dict), f"the assignment must be a mapping of fields, got {quote(data)}")
    late = data.get("late")
    if isinstance(late, dict) and isinstance(late.get("due"), datetime.datetime):
        # YAML reads an unquoted date as a timestamp: the same date, as text.
        late["due"] = late["due"].isoformat()
        document = json.dumps(data, default=str)  # JSON is YAML
    _check_shape(data, Assignment, "")
    try:
        loaded = yaml_load_typed(schema=Assignment, data=document, defaults=Assignment())
    except (RuntimeError, ValueError, TypeError) as e:  # not expected after _check_shape
        raise ConfigError(str(e).splitlines()[0] if str(e) else type(e).__name__) from None
    return validate_assignment(loaded)


def load_assignment(path: str | Path) -> Assignment:
    """Loads and validates an assignment file.

    Raises:
        ConfigError: The file is missing, unreadable or invalid (one line naming the file and
            the dotted field).
    """
    text = read_text_file(path, what="assignment file")
    try:
        return parse_assignment(text)
    except ConfigError as e:
        raise ConfigError(f"assignment file {str(path)!r}: {e}") from None


def assignment_from_dict(data: dict) -> Assignment:
    """An assignment from :meth:`Assignment.to_dict`'s data (the supervisor's request),
    validated.

    Raises:
        ConfigError: The data is not an assignment's.
    """
    try:
        hints = typing.get_type_hints(TestsSettings)
        tests = TestsSettings(
            **{name: hints[name](**value) for name, value in data["tests"].items()}
        )
        top = {k: v for k, v in data.items() if k not in ("tests", "late")}
        late = LatePolicy(**data.get("late", {}))
        assignment = Assignment(**top, late=late, tests=tests)
    except (KeyError, TypeError, AttributeError) as e:
        raise ConfigError(f"not an assignment's settings ({e})") from None
    return validate_assignment(assignment)


def _yaml_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(float(value))
    if isinstance(value, str) and (value == "" or not value.replace(" ", "").isalnum()):
        return json.dumps(value)  # quoted: a date, a title with punctuation
    return str(value)


_COMMENTS = {
    "points": "[points]",
    "visibility": ", ".join(VISIBILITIES),
    "radial_margin": "[m] over the reference IK's max radial error of Q",
    "orientation_margin": "[rad] over the reference plan's max orientation error of L7",
    "arc_end_margin_deg": "[deg] Q's angle about the hinge at the arc's end vs the reference",
    "door_opening_margin_deg": "[deg] the door's opening at the arc's end vs the reference",
    "helpers": "calc_p_Q and calc_R_WL7_ref: reference (doorlab's) or student",
    "self_check": "run by the handout's self-check (a hidden test never is)",
    "due": "ISO 8601 with its UTC offset, e.g. 2024-03-01T23:59:00-05:00; '' = none",
    "grace_minutes": "[min] a submission at most this late costs nothing",
    "penalty_per_day_percent": "[%] of the score earned, per day late or part of one",
    "max_penalty_percent": "[%] the penalty's cap",
}


def _test_lines(assignment: Assignment, keys: typing.Iterable[str] | None = None) -> list[str]:
    """The ``tests:`` block (``keys``: the tests written; default every one)."""
    names = {t.key: t.name for t in verdicts.TESTS}
    lines = ["tests:"]
    for f in dataclasses.fields(TestsSettings):
        if keys is not None and f.name not in keys:
            continue
        lines.append(f"  {f.name}:  # {names[f.name]}")
        settings = getattr(assignment.tests, f.name)
        for g in dataclasses.fields(settings):
            value = _yaml_value(getattr(settings, g.name))
            lines.append(f"    {g.name}: {value}  # {_COMMENTS[g.name]}")
    return lines


def _top_lines(assignment: Assignment) -> list[str]:
    """Every top-level field but ``tests``, commented."""
    lines = [
        f"seed: {assignment.seed}  # the course's: with each submission's files (their SHA-256), "
        "the unit tests' random inputs",
        f"visibility: {assignment.visibility}  # results' top level: {', '.join(VISIBILITIES)}",
        f"stdout_visibility: {assignment.stdout_visibility}  # the autograder's stdout on "
        "Gradescope",
        f"title: {_yaml_value(assignment.title)}  # the gradebook column (--export canvas)",
        "late:  # the late policy, from each submission's time",
    ]
    for g in dataclasses.fields(LatePolicy):
        value = _yaml_value(getattr(assignment.late, g.name))
        lines.append(f"  {g.name}: {value}  # {_COMMENTS[g.name]}")
    return lines


def assignment_yaml(assignment: Assignment, *, header: str = "") -> str:
    """The assignment as a commented YAML file (every field, with its unit and choices)."""
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    lines += _top_lines(assignment) + _test_lines(assignment)
    return "\n".join(lines) + "\n"


def write_default_assignment(out: str | Path) -> Path:
    """Writes the default assignment, with a fresh random seed, to ``out`` (a new file).

    Raises:
        OutputError: ``out`` exists (an instructor's settings are never replaced) or cannot
            be written.
    """
    out = Path(out)
    if out.exists() or out.is_symlink():
        raise OutputError(
            f"{out} already exists; not replacing it (move it away or choose another name)"
        )
    assignment = Assignment(seed=secrets.randbits(SEED_BITS))
    header = (
        "doorlab problem-set assignment: grading settings (doorlab pset assignment).\n"
        "Grade with: doorlab pset grade SUBMISSION --assignment THIS_FILE\n"
        "Gradescope: doorlab pset autograder OUT.zip --assignment THIS_FILE\n"
        "Every key is optional (left out: the default shown here)."
    )
    text = assignment_yaml(assignment, header=header)
    parse_assignment(text)  # what it writes, it reads back
    try:
        with open(out, "x") as f:
            f.write(text)
    except FileExistsError:
        raise OutputError(f"{out} already exists; not replacing it") from None
    except OSError as e:
        raise OutputError(f"cannot write {out}: {e.strerror or e}") from None
    return out


# Seeds -------------------------------------------------------------------------------------


def files_digest(folder: str | Path, files: tuple[str, ...]) -> str:
    """SHA-256 (hex) of a problem-set folder's graded files (their paths and bytes; a file
    that is missing or not a regular file counts as such)."""
    contents = {}
    for rel in files:
        path = Path(folder) / rel
        contents[rel] = path.read_bytes() if path.is_file() and not path.is_symlink() else None
    return bytes_digest(contents)


def bytes_digest(contents: dict[str, bytes | None]) -> str:
    """:func:`files_digest` of files given as ``{path: bytes}`` (None: missing), in order."""
    h = hashlib.sha256()
    for rel, data in contents.items():
        h.update(f"{rel}\0{-1 if data is None else len(data)}\0".encode())
        h.update(data or b"")
    return h.hexdigest()


def grading_seed(assignment_seed: int, digest: str) -> int:
    """The grading seed (32 bits) from the assignment's random seed and the graded files'
    SHA-256."""
    text = f"doorlab-grading-seed:{assignment_seed}:{digest}".encode()
    return int.from_bytes(hashlib.sha256(text).digest()[: SEED_BITS // 8], "big")


def job_seed(grading: int, job: str) -> int:
    """The random seed (64 bits) of one job's draws, from the grading seed."""
    return int.from_bytes(hashlib.sha256(f"{grading}:{job}".encode()).digest()[:8], "big")
