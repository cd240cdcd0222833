"""A semester as the teaching guide runs it, on a class of 13 in Gradescope's export layout.

The fixture ``semester`` runs the guide's steps (docs/guides/teaching.md, the block after
``<!-- semester-steps -->``) in order, through the command line as an instructor types them:
the assignment (a 16-point course with a late policy), the handout and its self-check, the
autograder zip, ``grade-all`` of the class (CPU measured), the same commands against a Dask
scheduler and worker started as the sweeps guide says (a class of 2), a points change and a
new export with one fixed submission (``--resume``), ``--only``, and the feedback PDFs and
gradebook exports. ``test_the_guide_s_steps_are_the_ones_run`` fails when the guide gains a
step the fixture does not run.

The class (:func:`build_class`) has the answer key three times (a folder, three flat files
for a group of two, a zip submitted late), the stubs twice and a notebook-only upload, four
single realistic mistakes (calc_p_Q not relative to the handle, the yaw turning the wrong
way, the impedance gain 10 times too small, the velocity error's sign), a syntax error, two
missing files and an absent student. Identical graded files are graded once, so the key's
three and the stubs' three uploads cost one grading each: 8 gradings for 12 uploads, most of
them failing at their first call (the reference episodes are the session's). An endless loop
is left out here: it costs its 60 s time limit (test_pset_sandbox.py grades one).
"""

from __future__ import annotations

import csv
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pset_fixtures
import pytest
from test_pset_batch import MISTAKES, _edited, _put
from test_report_browser import chromium, render_check

from doorlab.pset.handout.folder import init_folder
from doorlab.pset.rules.assignment import assignment_yaml, load_assignment

pytestmark = pytest.mark.slow

GUIDE = Path(__file__).resolve().parents[1] / "docs" / "guides" / "teaching.md"
FILES = ("ik_utils.py", "open_left_door.py", "manip_station_sim/robot_plans.py")
VELOCITY_STUB = '        raise NotImplementedError("velocity: not done")'
DUE = "2024-03-01T23:59:00-05:00"
COMMAND_TIMEOUT_S = 900


def guide_steps() -> list[str]:
    """The commands of the guide's semester block, in order (comments and blank lines out)."""
    text = GUIDE.read_text()
    block = text.split("<!-- semester-steps -->", 1)[1].split("```bash", 1)[1].split("```", 1)[0]
    return [line.split("  #")[0].strip() for line in block.splitlines() if line.strip()]


def _shape(command: str) -> tuple:
    """A command without its placeholders: the program, the subcommand and the options."""
    words = command.split()
    head = tuple(w for w in words[:3] if not w.startswith("-") and "/" not in w and "." not in w)
    return head, tuple(sorted(w for w in words if w.startswith("--")))


def _metadata(people: dict[str, tuple]) -> str:
    lines = []
    for sid, (students, created) in sorted(people.items()):
        lines.append(f"{sid}:\n  :submitters:")
        for name, student_id, email in students:
            lines.append(f"  - :name: {json.dumps(name)}\n    :sid: '{student_id}'")
            lines.append(f"    :email: {email}")
        lines.append(f"  :created_at: {created}\n  :score: 0.0")
    return "\n".join(lines) + "\n"


ON_TIME = "2024-03-01 20:00:00.000000000 -05:00"
LATE = "2024-03-03 01:30:00.000000000 -05:00"  # 25 h 31 min late: 2 days


def build_class(root: Path) -> tuple[Path, Path, dict[str, float]]:
    """Two exports of the class of 13 (the second with submission_7 fixed) and the totals
    expected under the 16-point course."""
    key = init_folder(root / "key", solutions=True)
    stubs = init_folder(root / "stubs")
    export = root / "export"
    export.mkdir()
    solved = {rel: (key / rel).read_text() for rel in FILES}
    stub = {rel: (stubs / rel).read_text() for rel in FILES}
    people: dict[str, tuple] = {}
    expected: dict[str, float] = {}

    def add(n: int, files: dict | None, total: float | None, who=None, created=ON_TIME):
        sid = f"submission_{n}"
        if files is not None:
            _put(export / sid, files)
        people[sid] = (who or [(f"Student {n}", f"{n:05d}", f"s{n}@example.edu")], created)
        if total is not None:
            expected[sid] = total
        return export / sid

    shutil.copytree(key, export / "submission_1")  # the key, the whole folder
    people["submission_1"] = ([("Ada Key", "00001", "ada@example.edu")], ON_TIME)
    expected["submission_1"] = 16.0
    flat = {Path(rel).name: text for rel, text in solved.items()}
    group = [("Grace One", "00002", "grace@example.edu"), ("Alan Two", "00022", "alan@example.edu")]
    add(2, flat, 16.0, who=group)  # the key's files flat, a group of two
    folder = add(3, None, 16.0 * 0.8, created=LATE)  # the key zipped, late: 2 days, -20 %
    folder.mkdir()
    with zipfile.ZipFile(folder / "pset5.zip", "w") as archive:
        for rel, text in solved.items():
            archive.writestr(f"pset5/{rel}", text)
    add(4, stub, 0.0)  # the untouched stubs
    add(5, stub, 0.0)  # again, another student
    rel, edits = MISTAKES["calc_p_Q_absolute"]
    add(6, {**stub, rel: _edited(key, rel, edits)}, 1.0)  # calc_R_WL7_ref's point only
    rel, edits = MISTAKES["impedance_gain_10"]
    add(7, {**stub, rel: _edited(key, rel, edits)}, 0.0)  # fixed in the second export
    rel, edits = MISTAKES["velocity_error_sign"]
    add(8, {**stub, rel: _edited(key, rel, edits)}, 0.0)
    add(9, {"pset5_open_cabinet_door.ipynb": '{"cells": []}'}, 0.0)  # the notebook only
    broken = stub["manip_station_sim/robot_plans.py"].replace(
        "    def CalcTorqueCommand(self,", "    def CalcTorqueCommand(self,,", 1
    )
    assert broken != stub["manip_station_sim/robot_plans.py"]
    add(10, {**stub, "manip_station_sim/robot_plans.py": broken}, 0.0)  # a syntax error
    add(11, {"open_left_door.py": solved["open_left_door.py"]}, 2.0)  # two files missing
    add(12, None, None)  # named in the metadata, nothing uploaded
    rel, edits = MISTAKES["yaw_turns_the_wrong_way"]
    add(13, {**stub, rel: _edited(key, rel, edits)}, 1.0)  # calc_p_Q's point only
    (export / "submission_metadata.yml").write_text(_metadata(people))
    assert len(people) == 13
    new = root / "new_export"
    shutil.copytree(export, new)
    fixed = _edited(
        key, "manip_station_sim/robot_plans.py", [(MISTAKES["impedance_gain_10"][1][1])]
    )
    _put(new / "submission_7", {"manip_station_sim/robot_plans.py": fixed})
    return export, new, expected


def _cpu_children() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


class Semester:
    """The commands run, their outputs and CPU times, and the folders."""

    def __init__(self, root: Path):
        self.root = root
        self.ran: list[str] = []
        self.outputs: dict[str, subprocess.CompletedProcess] = {}
        self.cpu: dict[str, float] = {}

    def run(self, label: str, argv: list[str], *, cwd: Path | None = None, check=True):
        """Runs a command of the guide (``doorlab ...`` through this interpreter), records
        its CPU time (its process tree's, as the kernel accounts it when it is reaped)."""
        self.ran.append(" ".join(argv))
        command = [sys.executable, "-m", "doorlab.cli", *argv[1:]] if argv[0] == "doorlab" else argv
        # The student's venv is active: its python3 is this interpreter.
        env = dict(
            os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"
        )
        before = _cpu_children()
        proc = subprocess.run(
            command,
            cwd=cwd or self.root,
            env=env,
            capture_output=True,
            text=True,
            timeout=COMMAND_TIMEOUT_S,
        )
        self.cpu[label] = _cpu_children() - before
        self.outputs[label] = proc
        if check:
            assert proc.returncode == 0, (argv, proc.stdout[-3000:], proc.stderr[-3000:])
        return proc


def _start(argv: list[str], pattern: str, timeout: float = 120) -> tuple[subprocess.Popen, str]:
    """Starts a Dask process; returns it and the first match of ``pattern`` in its stderr."""
    proc = subprocess.Popen(argv, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    deadline = time.monotonic() + timeout
    seen = []
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line and proc.poll() is not None:
            break
        seen.append(line)
        if match := re.search(pattern, line):
            return proc, match.group(1)
    proc.kill()
    pytest.fail(f"{argv[:2]} did not start: {''.join(seen)[-2000:]}")


def _stop(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def _try_the_cluster(s, address: str, keys: Path, small: Path, course: Path, ref) -> dict:
    """What the guide's TLS cluster lets in: a TLS client without a key, a Dask client with
    another authority's key, one with the course's (which runs code on the workers), and
    grade-all without --cluster-keys, or on the same scheduler named tcp://."""
    import asyncio

    import distributed

    from doorlab.pset.classroom.cluster import accepts_anonymous, cluster_security

    out = {"anonymous": accepts_anonymous(address, str(keys / "ca.pem"))}
    other = distributed.Security.temporary()
    try:
        asyncio.run(
            distributed.comm.connect(address, timeout=5, **other.get_connection_args("client"))
        )
        out["other_key"] = "connected"
    except (OSError, TimeoutError) as e:
        out["other_key"] = type(e).__name__
    with distributed.Client(address, security=cluster_security(keys), timeout=30) as client:
        out["course_key"] = sorted(client.run(os.getpid).values())
    common = ["--out", str(s.root / "refused"), "--assignment", str(course), *ref]
    plain = address.replace("tls://", "tcp://")
    for label, more in (("no-keys", ["--scheduler", address]), ("tcp", ["--scheduler", plain])):
        proc = s.run(
            label, ["doorlab", "pset", "grade-all", str(small), *common, *more], check=False
        )
        s.ran.pop()
        out[label] = (proc.returncode, proc.stderr.strip())
    return out


def _results_files(out: Path) -> dict[str, tuple]:
    return {
        p.parent.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in out.glob("*/results.json")
    }


def read_sheet(path: Path) -> dict[str, dict]:
    with open(path, newline="") as f:
        return {row["submission"]: row for row in csv.DictReader(f)}


@pytest.fixture(scope="module")
def semester(tmp_path_factory) -> Semester:
    root = tmp_path_factory.mktemp("semester")
    os.chmod(root, 0o755)
    s = Semester(root)
    s.export, s.new_export, s.expected = build_class(root)
    reference = root / "reference.json"
    reference.write_text(json.dumps({"extra_data": {"reference": pset_fixtures.reference()}}))
    ref = ["--reference", str(reference)]
    course, grades = root / "course.yaml", root / "grades"
    common = ["--out", str(grades), "--assignment", str(course)]

    # 1. The settings: a 16-point course (Task 3's episode 4 points), a late policy.
    s.run("assignment", ["doorlab", "pset", "assignment", str(course)])
    settings = load_assignment(course)
    settings.tests.impedance_episode.points = 4.0
    settings.late.due = DUE
    settings.late.grace_minutes = 15.0
    settings.late.penalty_per_day_percent = 10.0
    settings.late.max_penalty_percent = 50.0
    settings.title = "Problem set 5"
    course.write_text(assignment_yaml(settings))
    # 2. The handout; 3. its self-check on a folder with the impedance plan done.
    handout = root / "pset5_handout.zip"
    s.run("handout", ["doorlab", "pset", "handout", str(handout), "--assignment", str(course)])
    student = root / "student"
    with zipfile.ZipFile(handout) as archive:
        archive.extractall(student)
    folder = student / "pset5"
    fixed = (s.new_export / "submission_7" / "manip_station_sim" / "robot_plans.py").read_text()
    (folder / "manip_station_sim" / "robot_plans.py").write_text(fixed)
    s.run("self-check", ["python3", "test_pset_5a.py", "test_results.json", *ref], cwd=folder)
    # 4. The autograder zip.
    s.run(
        "autograder",
        [
            "doorlab",
            "pset",
            "autograder",
            str(root / "pset5_autograder.zip"),
            "--assignment",
            str(course),
        ],
    )
    # 5. The class, on local workers (its CPU: the first grading).
    s.run(
        "grade-all",
        [
            "doorlab",
            "pset",
            "grade-all",
            str(s.export),
            *common,
            "--export",
            "canvas",
            *ref,
            "--jobs",
            "2",
        ],
    )
    s.first_sheet = (grades / "grades.csv").read_text()
    s.first_results = {
        sid: json.loads((grades / sid / "results.json").read_text())
        for sid in ("submission_1", "submission_3", "submission_10")
    }
    # 6. The course's TLS keys, a Dask scheduler and worker started with them from the
    # command line as the guide says (a class of two: the stubs and a copy).
    distributed = pytest.importorskip("distributed")
    del distributed
    small = root / "small"
    for sid in ("submission_4", "submission_5"):
        shutil.copytree(s.export / sid, small / sid)
    keys = root / "keys"
    s.run("keys", ["doorlab", "pset", "cluster-keys", str(keys), "--host", "127.0.0.1"])
    dask = str(Path(sys.executable).with_name("dask"))

    def tls(role: str) -> list[str]:
        return ["--tls-ca-file", str(keys / "ca.pem"), "--tls-cert", str(keys / f"{role}.pem"),
                "--tls-key", str(keys / f"{role}.key")]  # fmt: skip

    argv = [dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard"]
    scheduler, address = _start([*argv, *tls("scheduler")], r"Scheduler at:\s+(tls://\S+)")
    s.ran.append(" ".join(["dask", *argv[1:], *tls("scheduler"), "&"]))
    try:
        argv = [dask, "worker", address, "--nthreads", "1", "--nworkers", "1", "--no-dashboard"]
        worker, _ = _start([*argv, *tls("worker")], r"(Registered to)")
        s.ran.append(" ".join(["dask", *argv[1:], *tls("worker"), "&"]))
        try:
            dask_out = root / "dask_grades"
            s.run(
                "dask",
                ["doorlab", "pset", "grade-all", str(small), "--out", str(dask_out),
                 "--assignment", str(course), "--scheduler", address, "--cluster-keys",
                 str(keys), *ref],
            )  # fmt: skip
            s.dask_sheet = read_sheet(dask_out / "grades.csv")
            s.cluster = _try_the_cluster(s, address, keys, small, course, ref)
        finally:
            _stop(worker)
    finally:
        _stop(scheduler)
    s.ran.append("kill %1 %2")
    # 7. A points change (Task 1's unit test 2 -> 3): re-scored, nothing simulated; then a
    # new export in which submission_7 is fixed.
    settings.tests.ik_unit.points = 3.0
    course.write_text(assignment_yaml(settings))
    s.run("points", ["doorlab", "pset", "grade-all", str(s.export), *common, "--resume"])
    s.points_changes = (grades / "changes.csv").read_text()
    s.after_points = _results_files(grades)
    s.run("new-export", ["doorlab", "pset", "grade-all", str(s.new_export), *common, "--resume"])
    s.new_changes = (grades / "changes.csv").read_text()
    s.after_new = _results_files(grades)
    # 8. One student again.
    s.run(
        "only",
        ["doorlab", "pset", "grade-all", str(s.new_export), *common, "--only", "submission_7"],
    )
    s.only_changes = (grades / "changes.csv").read_text()
    s.after_only = _results_files(grades)
    # 9. Published: the feedback as PDFs, the gradebook files.
    if chromium() is not None:
        s.run(
            "publish",
            ["doorlab", "pset", "grade-all", str(s.new_export), *common, "--resume", "--published",
             "--pdf", "--export", "canvas", "--export", "gradescope"],
        )  # fmt: skip
    s.grades, s.folder = grades, folder
    return s


def test_the_guide_s_steps_are_the_ones_run(semester):
    """Every command of the guide's semester block was run, in its order (with the guide's
    options; the test adds --reference, the session's reference episodes, and --jobs)."""
    shapes = [_shape(c) for c in semester.ran]
    position = 0
    for command in guide_steps():
        head, options = _shape(command)
        found = [
            i
            for i, (h, o) in enumerate(shapes)
            if h == head and set(options) <= set(o) and i >= position
        ]
        if "--pdf" in command and chromium() is None:
            continue
        assert found, f"the guide's step {command!r} is not run by this test"
        position = found[0]


def test_the_handout_s_self_check_grades_with_the_course_s_16_points(semester):
    out = semester.outputs["self-check"].stdout
    assert "Graded with your course's settings (course.yaml)." in out
    assert "[PASS] Task 3 episode: impedance plan, doors closed: 4 / 4" in out
    assert "[PASS] Task 3 unit test: IiwaTaskSpaceImpedancePlan.CalcTorqueCommand: 2 / 2" in out
    assert out.strip().splitlines()[-1] == "Total score: 6 / 16"
    results = json.loads((semester.folder / "test_results.json").read_text())
    assert sum(t["max_score"] for t in results["tests"]) == 16


def test_the_class_is_graded_as_expected_once_per_distinct_files(semester):
    first = semester.outputs["grade-all"]
    sheet = {row["submission"]: row for row in csv.DictReader(semester.first_sheet.splitlines())}
    assert len(sheet) == 13
    for sid, total in semester.expected.items():
        assert float(sheet[sid]["total"]) == pytest.approx(total), (sid, sheet[sid])
    assert sheet["submission_12"]["status"] == "absent"
    assert sheet["submission_2"]["same_files_as"] == "submission_1"
    assert sheet["submission_3"]["same_files_as"] == "submission_1"
    assert sheet["submission_5"]["same_files_as"] == "submission_4"
    assert sheet["submission_2"]["names"] == "Grace One; Alan Two"
    # The late one: 2 days late (each started day), 10 % a day.
    assert (sheet["submission_3"]["late_days"], sheet["submission_3"]["late_penalty"]) == (
        "2",
        "3.200",
    )
    late = semester.first_results["submission_3"]
    assert late["score"] == pytest.approx(12.8) and late["extra_data"]["late"]["days_late"] == 2
    assert "2 days counted, -20 % of the score (3.2 points: 16 -> 12.8)" in late["output"]
    # Tests in number order; Gradescope's stdout_visibility.
    key = semester.first_results["submission_1"]
    assert [t["number"] for t in key["tests"]] == [
        "1.1",
        "1.2",
        "2.1",
        "2.2",
        "2.3",
        "2.4",
        "3.1",
        "3.2",
    ]
    assert key["stdout_visibility"] == "hidden" and key["score"] == 16
    # A syntax error: one line naming the file and line, on each of that file's tests.
    broken = semester.first_results["submission_10"]
    for t in broken["tests"]:
        if t["number"] in ("2.3", "3.1"):
            assert t["output"].startswith(
                "your file manip_station_sim/robot_plans.py did not import (SyntaxError: "
            ), t["output"]
            assert "so every test that uses manip_station_sim/robot_plans.py fails" in t["output"]
            assert "frozen" not in t["output"]
    # The notebook-only upload holds none of the student files: not graded (every path's rule).
    assert sheet["submission_9"]["status"] == "not_graded"
    assert "13 of 13 submissions in the sheet: 1 absent, 11 graded, 1 not graded" in first.stdout
    print(f"first grading: {semester.cpu['grade-all']:.1f} CPU-s for 12 uploads")


def test_a_points_change_regrades_the_class_in_a_tenth_of_its_first_grading_s_cpu(semester):
    """Re-scored from the stored figures: every row's Task 1 unit test is worth 3 points,
    nothing simulated (no results file rewritten but by the re-score), the previous sheet
    kept in history/, every re-scored submission in changes.csv with why."""
    first, points = semester.cpu["grade-all"], semester.cpu["points"]
    print(f"points change: {points:.2f} CPU-s against {first:.1f} for the first grading")
    assert points < 0.1 * first, (points, first)
    changes = list(csv.DictReader(semester.points_changes.splitlines()))
    assert len(changes) == 12  # every upload, not the absent one
    assert {c["action"] for c in changes} == {"rescore"}
    assert all(c["why"] == "tests.ik_unit.points: 2 -> 3" for c in changes)
    key = next(c for c in changes if c["submission"] == "submission_1")
    assert (key["old_total"], key["new_total"], key["tests"]) == ("16", "17", "ik_unit 2 -> 3")
    late = next(c for c in changes if c["submission"] == "submission_3")
    assert (late["old_total"], late["new_total"]) == ("12.8", "13.6")  # 17 less 20 %
    history = semester.grades / "history" / "grades-001.csv"
    assert history.read_text() == semester.first_sheet


def test_a_fixed_submission_in_a_new_export_is_regraded_by_resume(semester):
    changes = list(csv.DictReader(semester.new_changes.splitlines()))
    assert [c["submission"] for c in changes] == ["submission_7"]
    (row,) = changes
    assert row["action"] == "grade" and row["why"].startswith("its files changed (SHA-256 ")
    assert (row["old_total"], row["new_total"]) == ("0", "6")
    assert row["tests"] == "impedance_unit 0 -> 2; impedance_episode 0 -> 4"
    before, after = semester.after_points, semester.after_new
    assert {k: v for k, v in after.items() if k != "submission_7"} == {
        k: v for k, v in before.items() if k != "submission_7"
    }  # the others' results untouched
    assert after["submission_7"] != before["submission_7"]
    only = list(csv.DictReader(semester.only_changes.splitlines()))
    assert [(c["submission"], c["action"], c["why"]) for c in only] == [
        ("submission_7", "grade", "regraded on request (--only)")
    ]
    assert {k: v for k, v in semester.after_only.items() if k != "submission_7"} == {
        k: v for k, v in after.items() if k != "submission_7"
    }


def test_the_guide_s_tls_cluster_lets_in_no_client_without_the_course_s_key(semester):
    """Issue 43: the guide's cluster (TLS, the keys of doorlab pset cluster-keys) refuses a
    client without a key and one with another authority's, so neither can run code on the
    workers; the course's key can. grade-all without the keys, or on the scheduler named
    tcp://, is refused in one line (exit 2), nothing graded."""
    tried = semester.cluster
    assert tried["anonymous"] is False, tried
    assert tried["other_key"] != "connected", tried  # the handshake fails (an OSError)
    assert len(tried["course_key"]) == 1, tried  # the one worker ran the client's function
    for label in ("no-keys", "tcp"):
        code, said = tried[label]
        assert code == 2 and len(said.splitlines()) == 1, (label, said)
    assert "--cluster-keys" in tried["no-keys"][1], tried
    assert "--insecure-cluster" in tried["tcp"][1] and "every grade" in tried["tcp"][1], tried
    assert not (semester.root / "refused").exists()


def test_the_dask_cluster_grades_as_the_local_workers(semester):
    local = read_sheet(semester.grades / "history" / "grades-001.csv")
    for sid, row in semester.dask_sheet.items():
        same = ("total", "status", "seed", "same_files_as")
        assert {k: row[k] for k in same} == {k: local[sid][k] for k in same}, sid


def test_the_canvas_export_has_a_row_per_student_with_canvas_s_columns(semester):
    table = list(csv.reader((semester.grades / "canvas.csv").read_text().splitlines()))
    assert table[0] == ["Student", "ID", "SIS User ID", "SIS Login ID", "Section", "Problem set 5"]
    assert table[1] == ["Points Possible", "", "", "", "", "17"]
    rows = {r[0]: r for r in table[2:]}
    assert len(rows) == 14  # 13 submissions, a group of two
    assert rows["Grace One"][2:] == ["00002", "grace@example.edu", "", "17"]
    assert rows["Alan Two"][5] == "17"  # each member gets the group's grade
    assert rows["Student 3"][5] == "13.600"  # late
    assert rows["Student 7"][5] == "6"  # the fixed one
    assert rows["Student 12"][5] == ""  # absent: Canvas changes nothing
    gradescope = list(csv.DictReader((semester.grades / "gradescope.csv").read_text().splitlines()))
    assert len(gradescope) == 14 and gradescope[0]["Email"] == "ada@example.edu"


def test_the_feedback_pages_and_the_class_page_render_with_every_figure(semester, tmp_path):
    """In headless Chromium: the key's page has its three episodes' figures, a stub's none,
    every image decodes, every table has rows; class.html has its three figures."""
    feedback = semester.grades / "feedback"
    pages = sorted(p.name for p in feedback.glob("*.html"))
    assert len(pages) == 12  # every upload, not the absent one
    key = (feedback / "submission_1.html").read_text()
    for job in ("student-ik", "student-velocity", "student-impedance"):
        assert f'id="figure-{job}"' in key
    result = render_check(key, tmp_path)
    assert result["images"] == 3 and result["broken_images"] == [] and result["empty_tables"] == []
    assert "Score: <strong>17 / 17</strong>" in key
    stub = (feedback / "submission_4.html").read_text()
    assert "<img" not in stub and "NotImplementedError" in stub
    late = (feedback / "submission_3.html").read_text()
    assert "after the late penalty: 3.4 points, 20 %, 2 days late" in late
    page = (semester.grades / "class.html").read_text()
    result = render_check(page, tmp_path)
    assert result["images"] == 3 and result["broken_images"] == [], result
    stats = json.loads((semester.grades / "summary.json").read_text())
    assert stats["submissions"] == 13 and stats["by_status"] == {
        "absent": 1,
        "graded": 11,
        "not_graded": 1,
    }
    velocity = next(t for t in stats["tests"] if t["key"] == "velocity_unit")
    assert velocity["pass_rate"] == pytest.approx(3 / 12)  # the key's three uploads
    groups = stats["identical_files"]
    assert ["submission_1", "submission_2", "submission_3"] in groups
    assert any(g[:2] == ["submission_4", "submission_5"] for g in groups)


def test_the_feedback_pdfs_print(semester):
    if chromium() is None:
        pytest.skip("chromium not installed: apt-get install chromium")
    pdfs = sorted((semester.grades / "feedback").glob("*.pdf"))
    assert len(pdfs) == 12
    assert "12 printed to PDF" in semester.outputs["publish"].stdout
    assert all(p.read_bytes().startswith(b"%PDF") for p in pdfs)
