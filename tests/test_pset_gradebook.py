"""What reaches students and the gradebook, without simulating: the final grade (the
instructor's adjustments, extensions from the class's file and from Gradescope's metadata,
the total's line naming the points students do not see), the instructor's files' one-line
refusals, the Canvas export filled from the course's roster, the exports a run finds and
rewrites, code similar beyond identical bytes, the episode tests' HTML for Gradescope, the
feedback files to hand out, and the instructor's files kept by ``--force``.

The results judged here are given (``test_pset_regrade._graded``: the judges are arithmetic
on stored figures); what has to run is in ``test_pset_semester.py``.
"""

from __future__ import annotations

import copy
import csv
import datetime
import json
from pathlib import Path

import jsonschema
import pytest
from gradescope_view import sanitize
from test_pset_regrade import _graded

from doorlab.errors import ConfigError, OutputError
from doorlab.pset.classroom import canvas, gradebook
from doorlab.pset.classroom.adjustments import apply_identities, read_adjustments
from doorlab.pset.classroom.exports import plan_exports
from doorlab.pset.classroom.extensions import gradescope_due, read_extensions
from doorlab.pset.classroom.final_grade import finalize, restore
from doorlab.pset.classroom.gradescope import finalize_for_gradescope
from doorlab.pset.classroom.roster import Submission
from doorlab.pset.classroom.similarity import fingerprint
from doorlab.pset.handout.folder import STUDENT_FILES, render_folder
from doorlab.pset.rules.assignment import Assignment, LatePolicy
from doorlab.runtime.folders import staged_output

DUE = "2024-03-01T23:59:00-05:00"
LATE = datetime.datetime.fromisoformat("2024-03-03T01:30:00-05:00")  # 2 days counted
SCHEMA = json.loads(Path(__file__).with_name("gradescope_results.schema.json").read_text())


def _course() -> Assignment:
    """16 points, one of them hidden, 10 % a day late."""
    course = Assignment(late=LatePolicy(due=DUE, penalty_per_day_percent=10.0))
    course.tests.impedance_episode.points = 4.0
    course.tests.calc_R_WL7_ref_unit.visibility = "hidden"
    return course


def _class() -> list[Submission]:
    people = [
        ("s1", [("Ada Lovelace", "101", "ada@x.edu")]),
        ("s2", [("Grace Hopper", "102", "grace@x.edu"), ("Alan Turing", "103", "alan@x.edu")]),
        ("s3", [("Typed Sid", "101", "typed@x.edu")]),  # typed Ada's SID
    ]
    return [
        Submission(i, Path(i), tuple({"name": n, "sid": s, "email": e} for n, s, e in p), "")
        for i, p in people
    ]


def _write(folder: Path, name: str, text: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_text(text)
    return folder


# The final grade ---------------------------------------------------------------------------


def test_the_total_names_the_hidden_points_the_late_penalty_and_the_adjustments(tmp_path):
    course = _course()
    results = _graded(course)  # 16 points; calc_p_Q failed (1)
    assert results["score"] == 15
    final = finalize(results, course, LATE)
    assert final["score"] == pytest.approx(12)  # 15 less 20 %
    assert final["output"].splitlines()[-1] == (
        "Total: 12 / 16 points (1 point in a hidden test, never shown; late penalty -3 "
        "(20 %, 2 days late))"
    )
    submissions = [Submission("s1", Path("s1"), ({"name": "A", "sid": "1", "email": "a@x"},))]
    _write(tmp_path, "adjustments.csv", (
        "student,test,points,score,reason\n"
        "s1,calc_p_Q_unit,,1,regrade request granted\n"
        "a@x,,-0.5,,late-night resubmission\n"
    ))  # fmt: skip
    adjustments = read_adjustments(tmp_path, submissions, course).grades["s1"]
    adjusted = finalize(results, course, LATE, adjustments=adjustments)
    # 16 less 20 % = 12.8, then -0.5 on the total.
    assert adjusted["score"] == pytest.approx(12.3)
    unit = next(t for t in adjusted["tests"] if t["number"] == "2.1")
    assert (unit["score"], unit["status"]) == (1.0, "passed")
    lines = adjusted["output"].splitlines()
    assert lines[-3:] == [
        "Adjustment: 2.1 Task 2 unit test: calc_p_Q: 0 -> 1 by the instructor (regrade "
        "request granted)",
        "Adjustment: -0.5 points on the total by the instructor (12.8 -> 12.3; late-night "
        "resubmission)",
        "Total: 12.3 / 16 points (1 point in a hidden test, never shown; late penalty -3.2 "
        "(20 %, 2 days late); the instructor's adjustments +0.3)",
    ]
    assert adjusted["extra_data"]["adjusted"]["reasons"] == [
        "calc_p_Q_unit set to 1 (regrade request granted)",
        "0.5 points taken off on the total (late-night resubmission)",
    ]
    # Idempotent, and undone by restore: a regrade starts from the judged results.
    again = finalize(adjusted, course, LATE, adjustments=adjustments)
    assert again == adjusted
    assert restore(adjusted)["tests"] == results["tests"]
    assert finalize(adjusted, course, LATE) == final  # the adjustments removed


def test_an_extension_from_the_class_s_file_or_gradescope_s_metadata_costs_nothing(tmp_path):
    course = _course()
    results = _graded(course)
    results["extra_data"]["episodes"] = {}  # no figures to draw: the due dates are the point
    submissions = _class()[:2]
    _write(
        tmp_path, "extensions.csv", "student,due,reason\nada@x.edu,2024-03-04T09:00:00-05:00,ill\n"
    )
    own = read_extensions(tmp_path, submissions)
    final = finalize(results, course, LATE, own_due=own["s1"])
    assert final["score"] == 15 and final["extra_data"]["late"]["penalty_points"] == 0
    assert (
        "Late policy: submitted 2024-03-03T01:30:00-05:00, before the due date "
        "2024-03-04T09:00:00-05:00, an extension (extensions.csv: ill): no penalty"
    ) in final["output"]
    # Gradescope's metadata: a user's own due date (an extension) over the assignment's.
    metadata = {
        "created_at": "2024-03-03T01:30:00.000000-05:00",
        "assignment": {"due_date": "2024-03-01T23:59:00.000000-05:00"},
        "users": [
            {"email": "a@x", "name": "A", "assignment": {"due_date": "2024-03-05T23:59:00-05:00"}}
        ],
    }
    assert gradescope_due(metadata).due.day == 5
    gradescope = finalize_for_gradescope(copy.deepcopy(results), course, metadata)
    assert gradescope["score"] == 15 and "its extension" in gradescope["output"]
    jsonschema.validate(gradescope, SCHEMA)
    del metadata["users"][0]["assignment"]  # the assignment's due date: no extension
    assert finalize_for_gradescope(results, course, metadata)["score"] == pytest.approx(12)
    # An extension never brings the due date forward.
    early = read_extensions(
        _write(tmp_path / "b", "extensions.csv", "student,due\ns1,2024-02-01T00:00:00Z\n"),
        submissions,
    )
    assert finalize(results, course, LATE, own_due=early["s1"])["score"] == pytest.approx(12)


@pytest.mark.parametrize(
    "name, text, message",
    [
        ("adjustments.csv", "student,points\ns1,1\n", "the column 'reason' is missing"),
        ("adjustments.csv", "student,bonus,reason\n", "the column 'bonus' is none of"),
        (
            "adjustments.csv",
            "student,points,reason\nnobody,1,why\n",
            "adjustments.csv row 2: 'nobody' is no submission id, student id (SID) or e-mail",
        ),
        (
            "adjustments.csv",
            "student,points,reason\n101,1,why\n",
            "adjustments.csv row 2: '101' names 2 submissions (s1, s3); name one by its "
            "submission id",
        ),
        ("adjustments.csv", "student,points,reason\ns1,1,\n", "needs a reason"),
        ("adjustments.csv", "student,points,reason\ns1,lots,why\n", "points must be a number"),
        (
            "adjustments.csv",
            "student,test,score,reason\ns1,ik_unit,5,why\n",
            "ik_unit's score must be within 0 and 2",
        ),
        ("adjustments.csv", "student,test,points,reason\ns1,ik,1,why\n", "test must be one of"),
        ("adjustments.csv", "student,points,sid,reason\ns1,1,9,why\n", "give one of points"),
        (
            "adjustments.csv",
            "student,sid,reason\ns2,104,typo\n",
            "s2 has 2 students; name the one to correct by their SID or e-mail",
        ),
        ("extensions.csv", "student,due\ns1,friday\n", "due must be a date and time in ISO"),
        ("extensions.csv", "student,due\ns1,2024-03-04T09:00:00\n", "with its UTC offset"),
        (
            "extensions.csv",
            "student,due\ns1,2024-03-04T09:00:00Z\nada@x.edu,2024-03-05T09:00:00Z\n",
            "extensions.csv row 3: s1 has an extension already (row 2)",
        ),
    ],
)
def test_a_bad_row_of_the_instructor_s_files_is_one_line_naming_it(tmp_path, name, text, message):
    _write(tmp_path, name, text)
    with pytest.raises(ConfigError) as error:
        read_adjustments(tmp_path, _class(), _course())
        read_extensions(tmp_path, _class())
    assert message in str(error.value) and "\n" not in str(error.value)


def test_a_typed_sid_is_refused_by_every_export_until_the_identity_is_corrected(tmp_path):
    """Issue 43's gradebook identity: two submissions with one SID are refused in one line
    naming both and how to resolve it; a row of adjustments.csv corrects it."""
    submissions = _class()
    for fmt in gradebook.FORMATS:
        with pytest.raises(ConfigError) as error:
            gradebook.check_exports([fmt], submissions)
        assert str(error.value).startswith(
            f"--export {fmt}: SID '101' is both s1 (Ada Lovelace, ada@x.edu)'s and s3 (Typed "
            "Sid, typed@x.edu)'s: one row would replace the other; correct the student's "
            "identity in the class's adjustments.csv"
        )
    _write(tmp_path, "adjustments.csv", "student,sid,reason\ntyped@x.edu,104,typed Ada's SID\n")
    fixed = apply_identities(
        submissions, read_adjustments(tmp_path, submissions, _course()).identities
    )
    gradebook.check_exports(gradebook.FORMATS, fixed)  # no conflict left
    assert fixed[2].submitters[0]["sid"] == "104" and submissions[2].submitters[0]["sid"] == "101"
    rows = {"s1": {"status": "graded", "total": 10.0, "max_total": 16.0},
            "s2": {"status": "graded", "total": 16.0, "max_total": 16.0},
            "s3": {"status": "error"}}  # fmt: skip
    text, _ = gradebook.gradescope_text(fixed, rows)
    table = list(csv.DictReader(text.splitlines()))
    assert [(r["SID"], r["Total Score"]) for r in table] == [
        ("101", "10"), ("102", "16"), ("103", "16"), ("104", "")
    ]  # fmt: skip


ROSTER = """\
Student,ID,SIS User ID,SIS Login ID,Integration ID,Section,Problem set 4 (8801),Problem set 5 (8802)
    Points Possible,,,,,,10,16
,,,,,,Manual Posting,
"Lovelace, Ada",5001,101,ada@x.edu,,Section A,9,
"Hopper, Grace",5002,S-102,ghopper,,Section B,8,
"Turing, Alan",5003,103,alan@x.edu,,Section A,7,
"Student, Test",5099,,,,,,
"""


def test_the_canvas_export_fills_the_course_s_own_gradebook(tmp_path):
    """--roster: Canvas's own export's students in its order, with Canvas's ID, names
    ("Last, First"), SIS ids and sections; matched by e-mail (a login without a domain by
    the e-mail's name), then SID; the assignment's existing column; unmatched listed."""
    roster = canvas.parse_roster(ROSTER)
    assert roster.columns == [
        "Student", "ID", "SIS User ID", "SIS Login ID", "Integration ID", "Section"
    ]  # fmt: skip
    submissions = _class()
    submissions[2] = Submission(
        "s3", Path("s3"), ({"name": "Eve New", "sid": "", "email": "eve@x.edu"},)
    )
    typo = {"name": "Alan Turing", "sid": "101", "email": "alan@x.edu"}  # typed Ada's SID
    submissions[1] = Submission("s2", Path("s2"), (
        {"name": "Grace Hopper", "sid": "102", "email": "ghopper@x.edu"}, typo
    ))  # fmt: skip
    rows = {"s1": {"status": "graded", "total": 12.8, "max_total": 16.0},
            "s2": {"status": "graded", "total": 16.0, "max_total": 16.0},
            "s3": {"status": "graded", "total": 3.0, "max_total": 16.0}}  # fmt: skip
    gradebook.check_exports(["canvas"], submissions, roster)  # matched by e-mail: no conflict
    text, notes = gradebook.canvas_text(
        submissions, rows, Assignment(title="Problem set 5"), roster
    )
    table = list(csv.reader(text.splitlines()))
    assert table[0] == [*roster.columns, "Problem set 5 (8802)"]
    assert table[1] == ["Points Possible", "", "", "", "", "", "16"]
    assert table[2:] == [
        ["Lovelace, Ada", "5001", "101", "ada@x.edu", "", "Section A", "12.800"],
        ["Hopper, Grace", "5002", "S-102", "ghopper", "", "Section B", "16"],
        ["Turing, Alan", "5003", "103", "alan@x.edu", "", "Section A", "16"],
        ["Student, Test", "5099", "", "", "", "", ""],
    ]
    assert notes == [
        "SID 101 of Alan Turing (alan@x.edu) is Lovelace, Ada's in the roster: matched by "
        "e-mail to Turing, Alan",
        "1 student(s) of the class are not in the roster (no row for them): Eve New (eve@x.edu)",
        "1 student(s) of the roster have no submission (their cell is empty: Canvas changes "
        "nothing): Student, Test",
    ]
    # Two submissions matching one row of the roster: refused before grading.
    twice = [
        *submissions,
        Submission("s4", Path("s4"), ({"name": "A", "sid": "", "email": "ada@x.edu"},)),
    ]
    with pytest.raises(
        ConfigError, match=r"the roster's Lovelace, Ada \(SIS User ID 101\) matches s1"
    ):
        gradebook.check_exports(["canvas"], twice, roster)
    with pytest.raises(ConfigError, match="has no column 'Section'"):
        canvas.parse_roster("Student,ID,SIS User ID,SIS Login ID\n")
    assert canvas.sortable_name("Grace Brewster Hopper") == "Hopper, Grace Brewster"


def test_a_run_rewrites_every_export_it_finds_and_keeps_the_roster(tmp_path):
    out = _write(tmp_path / "grades", "gradescope.csv", "old\n")
    plan = plan_exports(out, ("canvas",), None)
    assert (plan.formats, plan.found, plan.roster) == (
        ("canvas", "gradescope"),
        ("gradescope",),
        None,
    )
    roster = _write(tmp_path, "export.csv", ROSTER) / "export.csv"
    plan = plan_exports(out, ("canvas",), roster)
    assert plan.roster.students[0]["ID"] == "5001" and plan.roster_bytes == ROSTER.encode()
    _write(out, canvas.ROSTER_COPY, ROSTER)
    later = plan_exports(out, (), None)  # a later run: the folder's copy
    assert later.roster.students == plan.roster.students and later.formats == ("gradescope",)


def test_similar_code_is_found_beyond_comments_layout_and_names_and_the_stubs_are_not():
    key = {
        rel: text.encode()
        for rel, text in render_folder(solutions=True).items()
        if rel in STUDENT_FILES
    }
    stubs = {
        rel: text.encode()
        for rel, text in render_folder(solutions=False).items()
        if rel in STUDENT_FILES
    }
    plans = key["manip_station_sim/robot_plans.py"].decode()
    disguised = dict(key)  # comments, blank lines, names of its own: the same code
    renamed = plans.replace("q_dot_des", "qd").replace("err_xyz", "e_p")
    disguised["manip_station_sim/robot_plans.py"] = (
        "# my own work\n\n" + renamed.replace("\nclass ", "\n\n# a plan\nclass ") + "# end\n"
    ).encode()
    assert renamed != plans
    assert fingerprint(disguised)[0] == fingerprint(key)[0]
    assert fingerprint(key)[1] > 100  # tokens of its own code
    assert fingerprint(stubs) is None and fingerprint({}) is None  # the untouched stubs
    other = dict(key)
    other["manip_station_sim/robot_plans.py"] = plans.replace("100.0 *", "10.0 *").encode()
    assert fingerprint(other)[0] != fingerprint(key)[0]  # another number is another code


def test_an_episode_test_s_html_shows_its_figure_and_never_renders_what_the_student_printed():
    course = _course()
    results = _graded(course)
    series = {"t_s": [0.0, 5.0, 10.0], "door_opening_deg": [0, 10, 30],
              "radial_error_mm": [0, 1, 0], "orientation_error_deg": [0, 0.5, 0.2]}  # fmt: skip
    for job in ("student:impedance", "reference:impedance"):
        stored = results["extra_data"]["episodes" if job.startswith("s") else "reference"]
        stored.setdefault(job, {"figures": {}})["figures"]["series"] = series
    episode = next(t for t in results["tests"] if t["number"] == "3.2")
    episode["output"] += "\n<script>alert('x')</script><img src=x onerror=alert(1)>"
    final = finalize_for_gradescope(results, course, None)
    jsonschema.validate(final, SCHEMA)
    html = next(t for t in final["tests"] if t["number"] == "3.2")
    assert html["output_format"] == "html" and html["output"].startswith("<pre>")
    assert "&lt;script&gt;alert(&#39;x&#39;)&lt;/script&gt;" in html["output"]
    assert '<img src="data:image/png;base64,iVBOR' in html["output"]
    assert sanitize(html["output"]).count("<img") == 1  # what survives Gradescope's sanitizer
    assert html["extra_data"]["text_output"] == episode["output"]
    html_tests = {t["number"] for t in final["tests"] if t["output_format"] == "html"}
    assert html_tests == {"1.2", "2.4", "3.2"}  # the episodes (the hidden test: a unit test)


def test_force_keeps_the_instructor_s_files_and_nothing_else(tmp_path):
    out = tmp_path / "grades"
    with staged_output(out, force=False) as staging:
        (staging / "grades.csv").write_text("old sheet\n")
    _write(out, "adjustments.csv", "student,points,reason\n")
    with pytest.raises(OutputError, match="adjustments.csv"):
        with staged_output(out, force=True):
            pass
    keep = ("adjustments.csv", "extensions.csv")
    with staged_output(out, force=True, keep=keep) as staging:
        (staging / "grades.csv").write_text("new sheet\n")
    assert (out / "grades.csv").read_text() == "new sheet\n"
    assert (out / "adjustments.csv").read_text() == "student,points,reason\n"
    manifest = json.loads((out / ".doorlab-manifest.json").read_text())["files"]
    assert "adjustments.csv" not in manifest  # still the instructor's, not doorlab's


# A regrade interrupted, and resumed --------------------------------------------------------


def _small_class(root: Path) -> Path:
    """Two uploads that fail fast (the stubs; calc_p_Q and calc_R_WL7_ref done: 2 points)."""
    from test_pset_batch import _put

    from doorlab.pset.handout.folder import init_folder

    stubs = init_folder(root / "stubs")
    key = init_folder(root / "key", solutions=True)
    export = root / "export"
    files = {rel: (stubs / rel).read_text() for rel in STUDENT_FILES}
    _put(export / "s1", files)
    _put(export / "s2", {**files, "open_left_door.py": (key / "open_left_door.py").read_text()})
    lines = [
        f"{sid}:\n  :submitters:\n  - :name: Student {n}\n    :sid: '{n}'\n    :email: "
        f"s{n}@x.edu\n  :created_at: 2024-03-03 01:30:00.000000000 -05:00\n"
        for n, sid in ((1, "s1"), (2, "s2"))
    ]
    (export / "submission_metadata.yml").write_text("".join(lines))
    return export


@pytest.mark.slow
def test_an_interrupted_regrade_leaves_the_sheet_and_exports_and_adjustments_survive(
    tmp_path, monkeypatch
):
    """A regrade (a new random seed: every submission simulated again) interrupted after its
    first grading leaves the sheet and the exports as they were; the next --resume keeps
    that grading, lists it in changes.csv and grades the rest; the adjustment (kept across
    the regrade) is in the results, the sheet, changes.csv and the export; without
    --assignment a regrade grades with the class's (its late policy kept)."""
    import pset_fixtures

    from doorlab.pset.classroom import grade_all
    from doorlab.pset.classroom.class_outputs import Outputs

    export, out = _small_class(tmp_path), tmp_path / "grades"
    reference = pset_fixtures.reference()
    course = _course()
    _write(out, "adjustments.csv", "student,points,reason\ns2,1.5,office hours\n")
    grade_class = grade_all.grade_class
    grade_class(export, out, assignment=course, reference=reference, jobs=1,
                outputs=Outputs(exports=("canvas",)))  # fmt: skip
    sheet, exported = (out / "grades.csv").read_bytes(), (out / "canvas.csv").read_bytes()
    totals = {r["submission"]: r["total"] for r in csv.DictReader(sheet.decode().splitlines())}
    assert totals == {"s1": "0", "s2": "3.100"}  # (2 less 20 %) + 1.5
    reseeded = copy.deepcopy(course)
    reseeded.seed = 99
    notices = []
    done = grade_all._ClassRun.done

    def interrupt_after_one(self, submission, outcome):
        done(self, submission, outcome)
        raise KeyboardInterrupt

    monkeypatch.setattr(grade_all._ClassRun, "done", interrupt_after_one)
    with pytest.raises(KeyboardInterrupt) as interrupted:
        grade_class(export, out, assignment=reseeded, reference=reference, resume=True,
                    jobs=1, notice=notices.append)  # fmt: skip
    assert notices == [
        "the assignment differs from the class's (seed: 0 -> 99): 0 submission(s) re-scored "
        f"from their stored figures, 2 graded again, simulated (their last gradings took "
        f"{notices[0].split('took ')[1].split(' s')[0]} s of worker time)"
    ]
    assert "the sheet and the exports" in interrupted.value.doorlab_left
    assert (out / "grades.csv").read_bytes() == sheet  # untouched
    assert (out / "canvas.csv").read_bytes() == exported
    monkeypatch.setattr(grade_all._ClassRun, "done", done)
    outcome = grade_class(export, out, reference=reference, resume=True, jobs=1)  # no --assignment
    changes = list(csv.DictReader((out / "changes.csv").read_text().splitlines()))
    assert sorted(c["submission"] for c in changes) == ["s1", "s2"]
    assert len(outcome.graded) == 1  # the interrupted run's grading kept
    why = {c["submission"]: c["why"] for c in changes}
    assert any(w.startswith("graded by an earlier run that was interrupted") for w in why.values())
    rows = {
        r["submission"]: r for r in csv.DictReader((out / "grades.csv").read_text().splitlines())
    }
    assert rows["s2"]["total"] == "3.100" and rows["s2"]["adjustments"] == (
        "1.5 points added on the total (office hours)"
    )  # the late policy of the class's assignment, the adjustment kept
    first = {r["submission"]: r for r in csv.DictReader(sheet.decode().splitlines())}
    assert all(rows[i]["seed"] != first[i]["seed"] for i in rows)  # graded with seed 99
    canvas_rows = list(csv.reader((out / "canvas.csv").read_text().splitlines()))[2:]
    assert [r[5] for r in canvas_rows] == ["0", "3.100"]  # the export equals the sheet


def test_feedback_files_are_named_for_upload_and_refused_without_a_class(tmp_path, capsys):
    from doorlab.cli.parser import main
    from doorlab.pset.classroom.handout_feedback import hand_out

    with pytest.raises(OutputError, match="holds no graded class"):
        hand_out(tmp_path, tmp_path / "out")
    grades = _write(tmp_path / "grades", "grades.csv", (
        "submission,names,sids,emails,total,max_total,status\n"
        "s1,Ada Lovelace,101,ada@x.edu,12,16,graded\n"
        "s2,Grace Hopper; Alan Turing,102; 103,g@x.edu; a@x.edu,16,16,graded\n"
        "s3,'=Eve,104,e@x.edu,,,absent\n"
    ))  # fmt: skip
    for sid in ("s1", "s2"):
        _write(grades / "feedback", f"{sid}.html", f"<p>{sid}</p>")
    assert main(["pset", "feedback", str(grades), str(tmp_path / "files")]) == 0
    files = tmp_path / "files"
    assert sorted(p.name for p in files.iterdir() if not p.name.startswith(".")) == [
        "101_Lovelace_Ada_s1.html", "102_Hopper_Grace_s2.html", "103_Turing_Alan_s2.html",
        "index.csv",
    ]  # fmt: skip
    index = list(csv.DictReader((files / "index.csv").read_text().splitlines()))
    assert index[3] == {"name": "'=Eve", "sid": "104", "email": "e@x.edu", "submission": "s3",
                        "total": "", "max_total": "", "file": ""}  # fmt: skip
    assert "no page for 1 student(s): =Eve" in capsys.readouterr().out
    assert main(["pset", "feedback", str(grades), str(files)]) == 2  # exists: --force
    assert (
        main(["pset", "grade-all", str(tmp_path), "--out", str(grades), "--roster", "r.csv"]) == 2
    )
    assert "--roster fills the Canvas export" in capsys.readouterr().err
