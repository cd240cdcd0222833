"""A semester's bookkeeping without simulating: re-scoring and re-judging from stored figures,
the regrade plan, the late policy, the course's file in the handout, the gradebook exports,
the class statistics, the messages (a file that does not import, a duplicated YAML key).

The figures judged here are given (the judges are arithmetic on them); what has to run is in
``test_pset_semester.py``.
"""

from __future__ import annotations

import csv
import datetime
import importlib
import json
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from doorlab.errors import ConfigError
from doorlab.pset.classroom import gradebook
from doorlab.pset.classroom.class_statistics import class_statistics
from doorlab.pset.classroom.late import apply_late, lateness, submission_time
from doorlab.pset.classroom.regrade import Step, changed_tests, plan_step
from doorlab.pset.classroom.roster import Submission, read_metadata_entries
from doorlab.pset.grading.grader import pretty_format_json_results
from doorlab.pset.grading.rescore import NeedsGrading, rejudge, settings_change
from doorlab.pset.grading.scoring import results_from_jobs, results_not_graded
from doorlab.pset.handout.course import COURSE_FILE, course_yaml, load_course
from doorlab.pset.handout.folder import render_folder
from doorlab.pset.isolation.worker import import_failure
from doorlab.pset.rules.assignment import Assignment, LatePolicy, assignment_yaml, parse_assignment
from doorlab.pset.rules.verdicts import TESTS
from doorlab.runtime.inputs import load_yaml

DEG = 3.141592653589793 / 180


def _figures(**overrides) -> dict:
    base = {
        "max_radial_error_m": 0.0012,
        "max_orientation_error_rad": 0.009,
        "q_end_angle_rad": 0.87,
        "door_opening_at_arc_end_rad": 0.55,
        "theta0_rad": 0.15,
        "handle_held": True,
        "series": {"t_s": [0.0, 0.05], "door_opening_deg": [0.0, 0.1]},
    }
    return {"figures": base | overrides}


def _jobs() -> dict:
    """Every job of a grading whose calc_p_Q failed and whose impedance plan opened the door
    3.4 deg less than the reference (inside the default 5 deg, outside 3 deg)."""
    jobs = {f"reference:{n}": _figures() for n in ("ik", "velocity", "impedance")}
    jobs["student:ik"] = _figures(max_radial_error_m=0.0030)
    jobs["student:velocity"] = _figures(max_radial_error_m=0.0011)
    jobs["student:impedance"] = _figures(door_opening_at_arc_end_rad=0.55 - 3.4 * DEG)
    for unit in ("ik", "calc_R_WL7_ref", "velocity", "impedance"):
        jobs[f"unit:{unit}"] = {"passed": True, "output": f"{unit}: all draws match"}
    jobs["unit:calc_p_Q"] = {"passed": False, "output": "calc_p_Q is off by 0.31 m"}
    return jobs


def _graded(assignment: Assignment | None = None) -> dict:
    assignment = assignment or Assignment()
    drawn = {"grading": 7, "source": "test", "files_sha256": "ab" * 32}
    return results_from_jobs(TESTS, _jobs(), 1.0, assignment, drawn)


def test_rejudging_with_the_grading_s_settings_gives_back_its_results():
    results = _graded()
    assert [t["number"] for t in results["tests"]] == [
        "1.1", "1.2", "2.1", "2.2", "2.3", "2.4", "3.1", "3.2"
    ]  # fmt: skip
    assert results["stdout_visibility"] == "hidden"
    stored = results["extra_data"]["episodes"]
    assert set(stored) == {"student:ik", "student:velocity", "student:impedance"}
    assert rejudge(results, Assignment()) == results


def test_a_points_change_rescores_and_a_margin_change_rejudges_as_a_grading_would():
    """Re-judging the stored figures under new settings gives what grading the same job
    results under them gives (points, visibility, margins, their messages)."""
    results = _graded()
    new = Assignment()
    new.tests.impedance_episode.points = 4.0
    new.tests.ik_unit.visibility = "after_due_date"
    new.stdout_visibility = "visible"
    assert settings_change(results["extra_data"]["settings"], new.to_dict()).action == "rescore"
    rescored = rejudge(results, new)
    assert rescored["tests"] == _graded(new)["tests"]
    assert rescored["score"] == results["score"] + 2.0 == 15.0  # calc_p_Q's point lost
    assert rescored["stdout_visibility"] == "visible"
    stricter = replace(new, tests=replace(new.tests))
    stricter.tests.impedance_episode = replace(new.tests.impedance_episode)
    stricter.tests.impedance_episode.door_opening_margin_deg = 3.0
    change = settings_change(results["extra_data"]["settings"], stricter.to_dict())
    assert change.action == "rejudge"
    assert "tests.impedance_episode.door_opening_margin_deg: 5 -> 3" in change.why
    rejudged = rejudge(results, stricter)
    assert rejudged["tests"] == _graded(stricter)["tests"]
    impedance = next(t for t in rejudged["tests"] if t["number"] == "3.2")
    assert impedance["score"] == 0.0 and "margin 3.00 deg" in impedance["output"]
    # Another reference: the same figures judged against it.
    moved = {k: v for k, v in _jobs().items() if k.startswith("reference:")}
    moved["reference:impedance"] = _figures(door_opening_at_arc_end_rad=0.55 - 3.4 * DEG)
    against = rejudge(results, Assignment(), moved)
    impedance = next(t for t in against["tests"] if t["number"] == "3.2")
    assert impedance["score"] == 2.0
    assert f"reference {0.55 / DEG - 3.4:.2f} deg" in impedance["output"]


@pytest.mark.parametrize(
    "change, why",
    [
        (lambda a: setattr(a, "seed", 99), "seed: 0 -> 99"),
        (
            lambda a: setattr(a.tests.velocity_episode, "helpers", "student"),
            "tests.velocity_episode.helpers: reference -> student",
        ),
    ],
)
def test_what_the_stored_figures_cannot_answer_needs_a_grading(change, why):
    results = _graded()
    new = Assignment()
    change(new)
    found = settings_change(results["extra_data"]["settings"], new.to_dict())
    assert found.action == "grade" and why in found.why
    with pytest.raises(NeedsGrading, match=why.split(":")[0]):
        rejudge(results, new)
    old = json.loads(json.dumps(results))
    del old["extra_data"]["settings"]  # results of an older doorlab
    with pytest.raises(NeedsGrading, match="older doorlab"):
        rejudge(old, Assignment())
    # Title, late policy and self_check change no result.
    quiet = Assignment(title="PS5", late=LatePolicy(due="2024-03-01T23:59:00-05:00"))
    quiet.tests.ik_unit.self_check = False
    assert settings_change(results["extra_data"]["settings"], quiet.to_dict()).action == "keep"


def test_the_regrade_plan_of_each_submission():
    results = _graded()
    results["extra_data"]["batch"] = {"files_sha256": "cd" * 32}
    settings = Assignment().to_dict()
    assert plan_step(results, "cd" * 32, settings) == Step("keep", "")
    step = plan_step(results, "ef" * 32, settings)
    assert step.action == "grade" and step.why == (
        "its files changed (SHA-256 cdcdcdcdcdcd -> efefefefefef)"
    )
    assert plan_step(None, "ef" * 32, settings, failed=True) == Step(
        "grade", "its grading failed before"
    )
    assert plan_step(results, "cd" * 32, settings, requested=True).action == "grade"
    more = Assignment()
    more.tests.ik_unit.points = 3.0
    assert plan_step(results, "cd" * 32, more.to_dict()) == Step(
        "rescore", "tests.ik_unit.points: 2 -> 3"
    )
    assert plan_step(results, "cd" * 32, settings, reference_changed=True).action == "rejudge"
    late = Assignment(late=LatePolicy(due="2024-03-01T23:59:00-05:00"))
    assert plan_step(results, "cd" * 32, late.to_dict()) == Step(
        "rescore", "the late policy changed"
    )
    after = rejudge(results, more)
    assert changed_tests(results, after) == "ik_unit 2 -> 3"


# The late policy ---------------------------------------------------------------------------

DUE = "2024-03-01T23:59:00-05:00"


@pytest.mark.parametrize(
    "late_by, days, percent",
    [
        (datetime.timedelta(minutes=-30), 0, 0.0),  # early
        (datetime.timedelta(minutes=10), 0, 0.0),  # within the 15-minute grace
        (datetime.timedelta(minutes=16), 1, 10.0),  # past it: the first day counts
        (datetime.timedelta(hours=25), 2, 20.0),  # each started day
        (datetime.timedelta(days=5, hours=1), 6, 25.0),  # the cap
    ],
)
def test_lateness_counts_started_days_after_the_grace_up_to_the_cap(late_by, days, percent):
    policy = LatePolicy(
        due=DUE, grace_minutes=15, penalty_per_day_percent=10, max_penalty_percent=25
    )
    due = datetime.datetime.fromisoformat(DUE)
    found = lateness(policy, due + late_by)
    assert (found.days, found.percent) == (days, percent)


def test_the_late_penalty_is_applied_once_and_says_so():
    results = _graded()  # 13 of 14
    policy = LatePolicy(due=DUE, penalty_per_day_percent=10, max_penalty_percent=50)
    when = datetime.datetime.fromisoformat("2024-03-03T01:30:00-05:00")
    apply_late(results, policy, when)
    assert results["score"] == pytest.approx(13 * 0.8)
    assert results["extra_data"]["late"]["days_late"] == 2
    assert results["extra_data"]["late"]["penalty_points"] == pytest.approx(2.6)
    line = [x for x in results["output"].split("\n") if x.startswith("Late policy: ")]
    assert line == [
        "Late policy: submitted 2024-03-03T01:30:00-05:00, 1 d 1 h 31 min after the due date "
        "2024-03-01T23:59:00-05:00; 2 days counted, -20 % of the score (2.6 points: 13 -> 10.4)"
    ]
    again = apply_late(json.loads(json.dumps(results)), policy, when)
    assert again == results  # idempotent: the score before the penalty is the tests' sum
    apply_late(results, LatePolicy(), when)  # no policy: the tests' sum, no line
    assert results["score"] == 13 and "Late policy" not in results["output"]
    apply_late(results, policy, None)  # no submission time: no penalty, said so
    assert results["score"] == 13 and "no submission time" in results["output"]


def test_submission_times_as_gradescope_writes_them(tmp_path):
    expected = datetime.datetime.fromisoformat("2024-03-01T12:00:00.123456-05:00")
    assert submission_time("2024-03-01 12:00:00.123456789 -05:00") == expected  # export, text
    assert submission_time("2024-03-01T12:00:00.123456-05:00") == expected  # metadata.json
    assert submission_time(expected) == expected  # YAML read it as a timestamp
    assert submission_time("yesterday") is None and submission_time(None) is None
    meta = tmp_path / "submission_metadata.yml"
    meta.write_text(
        "submission_1:\n  :submitters:\n  - :name: Ada\n  :created_at: "
        "2024-03-01 12:00:00.000000000 -05:00\nsubmission_2:\n  :created_at: soon\n"
    )
    entries = read_metadata_entries(meta)
    assert entries["submission_1"][1] == "2024-03-01T12:00:00-05:00"
    assert entries["submission_2"] == ((), "")


# The course's file and the self-check ------------------------------------------------------


def _course() -> Assignment:
    course = Assignment(seed=4321, title="PS 5")
    course.tests.impedance_episode.points = 4.0  # 16 in all
    course.tests.velocity_episode.visibility = "after_due_date"
    course.tests.ik_episode.visibility = "after_published"
    course.tests.ik_episode.self_check = False
    course.tests.calc_p_Q_unit.visibility = "hidden"
    course.tests.impedance_episode.door_opening_margin_deg = 4.5
    return course


def test_the_handout_carries_the_course_s_settings_but_the_hidden_tests(tmp_path):
    course = _course()
    files = render_folder(solutions=False, assignment=course, course=True)
    text = files[COURSE_FILE]
    assert "calc_p_Q_unit" not in text and "seed: 4321" in text
    assert "door_opening_margin_deg: 4.5" in text
    assert "Task 2 unit test: calc_p_Q" not in files["README.md"]
    assert "Your course also grades tests that are not listed here." in files["README.md"]
    assert "after the due date" in files["README.md"]
    path = tmp_path / COURSE_FILE
    path.write_text(text)
    check = load_course(path)
    assert check.assignment.seed == 4321
    assert check.assignment.tests.impedance_episode.door_opening_margin_deg == 4.5
    assert check.course_points == 15.0  # 16 but the hidden test's point
    assert "Task 2 unit test: calc_p_Q" not in check.run
    assert "Task 1 episode: IK with 10 knots, doors open" not in check.run
    assert check.not_run == [
        {
            "name": "Task 1 episode: IK with 10 knots, doors open",
            "points": 2.0,
            "why": "Gradescope shows this test once the course publishes its grades",
        }
    ]
    assert check.notes == {
        "Task 2 episode: velocity plan, doors open": "Gradescope shows this test after the due date"
    }


def test_the_self_check_summary_prints_the_course_s_points_and_total(tmp_path):
    course = _course()
    path = tmp_path / COURSE_FILE
    path.write_text(course_yaml(course))
    check = load_course(path)
    specs = [t for t in TESTS if t.name in check.run]
    results = results_from_jobs(specs, _jobs(), 1.0, check.assignment)
    results["extra_data"]["self_check"] = check.to_dict()
    out = tmp_path / "results.json"
    out.write_text(json.dumps(results))
    text = pretty_format_json_results(out)
    assert "[PASS] Task 3 episode: impedance plan, doors closed: 4 / 4" in text
    assert (
        "[PASS] Task 2 episode: velocity plan, doors open: 2 / 2 (Gradescope shows this test "
        "after the due date)"
    ) in text
    assert "[LATER] Task 1 episode: IK with 10 knots, doors open: 2 points, not run here" in text
    assert text.splitlines()[-1] == (  # the course's 16 points, the hidden test's 1 named
        "Total score: 13 / 16 (2 of them in tests this check does not run; 1 in hidden tests: "
        "graded by your course, not shown or run here)"
    )


# Exports and statistics --------------------------------------------------------------------


def _class():
    people = {
        "s1": ({"name": "Ada Key", "sid": "101", "email": "ada@x.edu"},),
        "s2": (
            {"name": "=cmd|' /C calc'!A0", "sid": "102", "email": "b@x.edu"},
            {"name": "Grace One", "sid": "103", "email": "g@x.edu"},
        ),
        "s3": ({"name": "Absent Al", "sid": "104", "email": "al@x.edu"},),
        "s4": ({"name": "Error Eve", "sid": "105", "email": "eve@x.edu"},),
    }
    submissions = [
        Submission(i, Path(i), p, "2024-03-01T12:00:00-05:00") for i, p in people.items()
    ]
    rows = {
        "s1": {"status": "graded", "total": 16.0, "max_total": 16.0},
        "s2": {"status": "graded", "total": 12.8, "max_total": 16.0, "late_penalty": 3.2},
        "s3": {"status": "absent"},
        "s4": {"status": "error", "error": "the grading process failed"},
    }
    return submissions, rows


def test_the_canvas_export_has_the_columns_canvas_s_gradebook_import_expects():
    """Canvas's guide: Student, ID, SIS User ID, SIS Login ID, Section, then the assignment's
    column; its export's Points Possible row; one row per student (a group's members each
    get the group's grade) named as Canvas does ("Last, First"); no cell a spreadsheet runs;
    no grade: an empty cell."""
    submissions, rows = _class()
    text, notes = gradebook.canvas_text(submissions, rows, Assignment(title="Problem set 5"))
    table = list(csv.reader(text.splitlines()))
    assert table[0] == ["Student", "ID", "SIS User ID", "SIS Login ID", "Section", "Problem set 5"]
    assert table[1] == ["Points Possible", "", "", "", "", "16"]
    assert table[2:] == [
        ["Key, Ada", "", "101", "ada@x.edu", "", "16"],
        ["calc'!A0, =cmd|' /C", "", "102", "b@x.edu", "", "12.800"],
        ["One, Grace", "", "103", "g@x.edu", "", "12.800"],
        ["Al, Absent", "", "104", "al@x.edu", "", ""],
        ["Eve, Error", "", "105", "eve@x.edu", "", ""],
    ]
    assert notes == []
    text, _ = gradebook.gradescope_text(submissions, rows)
    table = list(csv.DictReader(text.splitlines()))
    assert [r["Email"] for r in table] == [
        "ada@x.edu",
        "b@x.edu",
        "g@x.edu",
        "al@x.edu",
        "eve@x.edu",
    ]
    assert table[1]["Name"] == "'=cmd|' /C calc'!A0"  # the guard: no formula
    assert table[2]["Total Score"] == "12.800" and table[2]["Late Penalty"] == "3.200"
    # A student in two submissions (one SID): refused, never one row replacing the other.
    again = Submission("s5", Path("s5"), submissions[0].submitters, "2024-03-02T12:00:00-05:00")
    with pytest.raises(ConfigError) as error:
        gradebook.check_exports(["canvas"], [*submissions, again])
    assert str(error.value).startswith(
        "--export canvas: SID '101' is both s1 (Ada Key, ada@x.edu)'s and s5 (Ada Key, "
        "ada@x.edu)'s: one row would replace the other; correct the student's identity in "
        "the class's adjustments.csv"
    )


def test_the_class_statistics_count_each_mistake_once_whatever_its_numbers():
    """Every distinct mistake with its count (numbers as #, the catalogue's diagnosis where
    the test made one, shortened at a word), the stubs and the uploads not graded apart."""
    graded = _graded()
    other = json.loads(json.dumps(graded))
    stub = json.loads(json.dumps(graded))
    swapped = "on 6 of 6 draws your answer is J^T F with the gains swapped"
    long = "calc_p_Q " + " ".join(["wrongly"] * 60) + " 0.1 m"
    for t in other["tests"]:
        if t["number"] == "2.1":
            t["output"] = "calc_p_Q is off by 0.12 m"
        if t["number"] == "3.1":
            t.update(status="failed", score=0.0, output=f"grading seed 5; tol\n{swapped}\ndraw 0")
    for t in stub["tests"]:
        if t["number"] == "2.1":
            t["output"] = "your code raised NotImplementedError: calc_p_Q: your code here"
        if t["number"] == "3.1":
            t.update(status="failed", score=0.0, output=long)
    rows = [
        {"submission": "a", "status": "graded", "total": 13.0, "wall_time_s": 8.0},
        {"submission": "b", "status": "graded", "total": 13.0, "wall_time_s": 0.0,
         "same_files_as": "a"},
        {"submission": "s", "status": "graded", "total": 11.0, "wall_time_s": 2.0},
        {"submission": "n", "status": "not_graded", "total": 0.0},
        {"submission": "c", "status": "error"},
    ]  # fmt: skip
    not_graded = results_not_graded(TESTS, "none of the student files")
    stats = class_statistics(rows, {"a": graded, "b": other, "s": stub, "n": not_graded})
    assert stats["by_status"] == {"error": 1, "graded": 3, "not_graded": 1}
    assert stats["histogram"] == [
        {"total": 0.0, "submissions": 1},
        {"total": 11.0, "submissions": 1},
        {"total": 13.0, "submissions": 2},
    ]
    by_key = {t["key"]: t for t in stats["tests"]}
    assert by_key["calc_p_Q_unit"]["graded"] == 3  # the upload not graded counted apart
    assert by_key["calc_p_Q_unit"]["pass_rate"] == 0.0
    assert by_key["calc_p_Q_unit"]["not_attempted"] == 1
    assert by_key["calc_p_Q_unit"]["messages"] == [
        {"message": "calc_p_Q is off by # m", "kind": "message", "count": 2}
    ]
    impedance = by_key["impedance_unit"]["messages"]
    assert impedance[1] == {
        "message": "your answer is J^T F with the gains swapped",
        "kind": "diagnosis",
        "count": 1,
    }
    cut = impedance[0]["message"]  # shortened at a word, never in the middle of one
    assert cut.endswith("wrongly ...") and len(cut) <= 300
    assert by_key["ik_unit"]["pass_rate"] == 1.0 and by_key["ik_unit"]["mean_score"] == 2.0
    assert stats["time_per_submission_s"]["n"] == 2  # a copy's grading is the original's
    assert stats["identical_files"] == [["a", "b"]]
    assert [r["page"] for r in stats["rows"]] == [
        f"feedback/{i}.html" for i in ("a", "b", "s", "n", "c")
    ]


# Messages ----------------------------------------------------------------------------------


def test_a_file_that_does_not_import_is_one_line_naming_it_and_its_line(tmp_path, monkeypatch):
    folder = tmp_path / "pset"
    (folder / "pkg_doorlab_t").mkdir(parents=True)
    (folder / "pkg_doorlab_t" / "__init__.py").write_text("")
    (folder / "pkg_doorlab_t" / "plans_t.py").write_text("x = 1\ndef f(:\n    pass\n")
    (folder / "helpers_t.py").write_text("import math\nvalue = undefined_name + 1\n")
    monkeypatch.syspath_prepend(str(folder))
    messages = []
    for name in ("pkg_doorlab_t.plans_t", "helpers_t"):
        try:
            importlib.import_module(name)
        except Exception as e:  # noqa: BLE001
            messages.append(import_failure(name, e, folder.resolve()))
        sys.modules.pop(name, None)
    assert (
        messages[0].startswith("your file pkg_doorlab_t/plans_t.py did not import (SyntaxError: ")
        and "at line 2), so every test that uses pkg_doorlab_t/plans_t.py fails" in messages[0]
    )
    assert messages[1].startswith(
        "your file helpers_t.py did not import (NameError: name 'undefined_name' is not "
        "defined at line 2)"
    )
    assert all("\n" not in m and "frozen" not in m for m in messages)


def test_a_duplicated_yaml_key_is_refused_in_one_line():
    with pytest.raises(ConfigError) as error:
        parse_assignment("tests:\n  ik_unit: {points: 1}\n  ik_unit:\n    points: 2\n")
    assert str(error.value) == (
        "the key 'ik_unit' appears twice in one mapping (line 3, column 3): keep one of them"
    )
    with pytest.raises(ConfigError, match="'points' appears twice"):
        load_yaml("a:\n  b: [{points: 1, points: 2}]\n")
    assert load_yaml("x: [{a: 1}, {a: 2}]\ny: {a: 3}\n") == {
        "x": [{"a": 1}, {"a": 2}],
        "y": {"a": 3},
    }


def test_every_new_assignment_field_round_trips():
    course = _course()
    course.late = LatePolicy(due=DUE, grace_minutes=15, penalty_per_day_percent=10)
    course.stdout_visibility = "visible"
    assert parse_assignment(assignment_yaml(course)) == course
    unquoted = parse_assignment("late: {due: 2024-03-01T23:59:00-05:00}\n")  # YAML's timestamp
    assert unquoted.late.due == DUE


def test_the_feedback_page_shows_each_test_as_its_visibility_allows():
    from doorlab.pset.classroom.feedback import Visibility, page_context

    course = Assignment(late=LatePolicy(due=DUE))
    course.tests.calc_p_Q_unit.visibility = "hidden"
    course.tests.velocity_episode.visibility = "after_due_date"
    course.tests.impedance_episode.visibility = "after_published"
    results = _graded(course)
    submission = Submission("s1", Path("s1"), ({"name": "Ada", "sid": "1", "email": ""},))
    due = datetime.datetime.fromisoformat(DUE)

    def shown(now, published=False):
        context = page_context(submission, results, course, Visibility(now, published))
        return [t["number"] for t in context["tests"]], context

    before, context = shown(due - datetime.timedelta(hours=1))
    assert before == ["1.1", "1.2", "2.2", "2.3", "3.1"]  # no hidden 2.1, nor 2.4 or 3.2 yet
    assert [t["when"] for t in context["later"]] == [
        f"shown after the due date ({DUE})",
        "shown once the course publishes its grades",
    ]
    # The score is the grade with the course's points, naming the points not on the page.
    assert context["final"] == results["score"] and context["max_score"] == 14
    assert context["notes"] == [
        "1 point in 1 hidden test (not on this page)",
        "4 points in 2 tests not shown yet (not on this page)",
    ]
    assert context["score"] == sum(t["score"] for t in context["tests"])
    after, _ = shown(due + datetime.timedelta(hours=1))
    assert after == ["1.1", "1.2", "2.2", "2.3", "2.4", "3.1"]
    published, context = shown(due + datetime.timedelta(hours=1), published=True)
    assert published == ["1.1", "1.2", "2.2", "2.3", "2.4", "3.1", "3.2"]
    assert "2.1" not in published and context["later"] == []  # hidden: never
    assert {"student:ik", "student:velocity", "student:impedance"} <= context["shown_jobs"]
