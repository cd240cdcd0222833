"""A semester as the teaching guide runs it, on a class of 15 in Gradescope's export layout.

The fixture ``semester`` runs the guide's steps (docs/guides/teaching.md, the block after
``<!-- semester-steps -->``) in order, through the command line as an instructor types them:
the assignment (a 16-point course with a late policy and a hidden test), the handout and its
self-check, the autograder zip (rehearsed: a late submission with Gradescope's own extension
in its metadata, its results.json checked against the specification and shown as Gradescope
renders HTML), ``grade-all`` of the class with the course's Canvas roster (CPU measured),
the same commands against a Dask scheduler and worker started as the sweeps guide says (a
class of 2), a new export with one fixed submission (``--resume`` without ``--assignment``:
the class's), a points change (``--assignment``), ``--only``, the feedback PDFs and
gradebook exports, and the feedback files for a course without Gradescope. Between them the
instructor's files: an extension (``extensions.csv``, before the first grading) and an
adjustment (``adjustments.csv``, after it). After every run, every export equals the sheet.
``test_the_guide_s_steps_are_the_ones_run`` fails when the guide gains a step the fixture
does not run.

The class (:func:`build_class`) has the answer key four times (a folder, three flat files
for a group of two, a zip submitted late, a late one with an extension), the stubs twice and
a notebook-only upload, five single realistic mistakes (calc_p_Q not relative to the
handle, the yaw turning the wrong way, the impedance gain 10 times too small, the missing
``scipy`` import, the impedance gains swapped, by a group of three), a syntax error, two
missing files and an absent student. Identical graded files are graded once, so the key's
four and the stubs' three uploads cost one grading each: 9 gradings for 14 uploads, most of
them failing at their first call (the reference episodes are the session's). An endless
loop is left out here: it costs its 60 s time limit (test_pset_sandbox.py grades one).
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

import jsonschema
import pset_fixtures
import pytest
from gradescope_view import student_view
from test_pset_autograder import _install, _run
from test_pset_batch import (
    IMPEDANCE_SOLVED,
    MISTAKES,
    VELOCITY_SOLVED,
    VELOCITY_STUB,
    _edited,
    _put,
)
from test_report_browser import chromium, render_check

from doorlab.pset.classroom.roster import read_metadata
from doorlab.pset.handout.folder import init_folder
from doorlab.pset.rules.assignment import assignment_yaml, load_assignment

pytestmark = pytest.mark.slow

GUIDE = Path(__file__).resolve().parents[1] / "docs" / "guides" / "teaching.md"
SCHEMA = Path(__file__).with_name("gradescope_results.schema.json")
FILES = ("ik_utils.py", "open_left_door.py", "manip_station_sim/robot_plans.py")
DUE = "2024-03-01T23:59:00-05:00"
EXTENDED = "2024-03-04T23:59:00-05:00"
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


def _plans(key: Path, old: str, new: str, stub: tuple[str, str]) -> str:
    """The key's robot_plans.py with one mistake (``old`` -> ``new``) and one plan a stub."""
    return _edited(key, "manip_station_sim/robot_plans.py", [(old, new), stub])


def build_class(root: Path) -> tuple[Path, Path, dict[str, float]]:
    """Two exports of the class of 15 (the second with submission_7 fixed) and the totals
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
    scipy = _plans(
        key,
        "np.linalg.pinv(self.Jv_WL7q)",
        "scipy.linalg.pinv(self.Jv_WL7q)",
        (IMPEDANCE_SOLVED, '        raise NotImplementedError("impedance: not done")'),
    )
    add(8, {**stub, "manip_station_sim/robot_plans.py": scipy}, 0.0)  # the missing import
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
    add(14, solved, 16.0, created=LATE)  # late, with an extension (extensions.csv): no penalty
    swapped = _plans(
        key,
        "F = np.concatenate([50.0 * theta_n_W, 100.0 * err_xyz])",
        "F = np.concatenate([100.0 * theta_n_W, 50.0 * err_xyz])",
        (VELOCITY_SOLVED, VELOCITY_STUB),
    )
    three = [(f"Member {c}", f"0015{i}", f"m{c.lower()}@example.edu") for i, c in enumerate("ABC")]
    add(15, {**stub, "manip_station_sim/robot_plans.py": swapped}, None, who=three)  # gains swapped
    (export / "submission_metadata.yml").write_text(_metadata(people))
    assert len(people) == 15
    new = root / "new_export"
    shutil.copytree(export, new)
    fixed = _edited(
        key, "manip_station_sim/robot_plans.py", [(MISTAKES["impedance_gain_10"][1][1])]
    )
    _put(new / "submission_7", {"manip_station_sim/robot_plans.py": fixed})
    return export, new, expected


def canvas_roster(export: Path) -> str:
    """The course's Canvas gradebook export: every student of the export's metadata (Canvas's
    own ID, "Last, First", the e-mail as login, a section), one student who dropped the
    course without submitting, an earlier assignment's column and the Points Possible row."""
    lines = ["Student,ID,SIS User ID,SIS Login ID,Section,Problem set 4 (801),Problem set 5 (802)"]
    lines.append("    Points Possible,,,,,10,16")
    metadata = read_metadata(export / "submission_metadata.yml")
    students = [p for people in metadata.values() for p in people]
    students.append({"name": "Dropped Out", "sid": "09999", "email": "gone@example.edu"})
    for number, person in enumerate(students):
        first, last = person["name"].rsplit(" ", 1)
        section = "Section A" if number % 2 else "Section B"
        lines.append(
            f'"{last}, {first}",{7000 + number},{person["sid"]},{person["email"]},{section},9,'
        )
    return "\n".join(lines) + "\n"


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
    return read_sheet_text(path.read_text())


def read_sheet_text(text: str) -> dict[str, dict]:
    return {row["submission"]: row for row in csv.DictReader(text.splitlines())}


def exports_equal_the_sheet(grades: Path) -> list[str]:
    """Where the exports in ``grades`` differ from its sheet (empty: nowhere): each student's
    cell is their submission's total (empty for an absent or failed one)."""
    sheet = read_sheet(grades / "grades.csv")
    total = {}
    for row in sheet.values():
        cell = row["total"] if row["status"] in ("graded", "not_graded") else ""
        for email in row["emails"].split("; "):
            total[email] = cell
    wrong = []
    if (grades / "canvas.csv").is_file():
        table = list(csv.reader((grades / "canvas.csv").read_text().splitlines()))
        login = table[0].index("SIS Login ID")
        for row in table[2:]:
            if row[login] in total and row[-1] != total[row[login]]:
                wrong.append(f"canvas.csv {row[login]}: {row[-1]} != {total[row[login]]}")
    if (grades / "gradescope.csv").is_file():
        for row in csv.DictReader((grades / "gradescope.csv").read_text().splitlines()):
            if row["Total Score"] != total[row["Email"]]:
                wrong.append(f"gradescope.csv {row['Email']}: {row['Total Score']}")
    return wrong


def rehearse_autograder(s: Semester, zip_path: Path, reference: Path) -> None:
    """The course's zip in a stand-in for Gradescope's /autograder (test_pset_autograder's
    offline install), grading the fixed submission_7 (its impedance plan: 6 points), 2 days
    late with Gradescope's own extension for it in submission_metadata.json."""
    root = _install(s.root / "autograder", zip_path, sys.executable)
    _put(root / "submission", {
        rel: (s.new_export / "submission_7" / rel).read_text()
        for rel in ("manip_station_sim/robot_plans.py",)
    })  # fmt: skip
    (root / "results").mkdir()
    metadata = {
        "id": 7,
        "created_at": "2024-03-03T01:30:00.000000-05:00",
        "assignment": {"due_date": "2024-03-01T23:59:00.000000-05:00", "title": "Problem set 5"},
        "users": [
            {"email": "s7@example.edu", "id": 7, "name": "Student 7",
             "assignment": {"due_date": "2024-03-04T23:59:00.000000-05:00"}}
        ],
    }  # fmt: skip
    (root / "submission_metadata.json").write_text(json.dumps(metadata))
    s.ran.append("run_autograder")
    s.outputs["run_autograder"] = _run(root, "--jobs", "2", "--reference", str(reference))
    s.autograder_results = json.loads((root / "results" / "results.json").read_text())


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
    s.equal: dict[str, list[str]] = {}

    # 1. The settings: a 16-point course (Task 3's episode 4 points, calc_R_WL7_ref's unit
    # test hidden), a late policy.
    s.run("assignment", ["doorlab", "pset", "assignment", str(course)])
    settings = load_assignment(course)
    settings.tests.impedance_episode.points = 4.0
    settings.tests.calc_R_WL7_ref_unit.visibility = "hidden"
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
    # 4. The autograder zip, rehearsed.
    zip_path = root / "pset5_autograder.zip"
    s.run(
        "autograder", ["doorlab", "pset", "autograder", str(zip_path), "--assignment", str(course)]
    )
    rehearse_autograder(s, zip_path, reference)
    # 5. The class, on local workers (its CPU: the first grading), its Canvas roster; one
    # student's extension in the class's folder before it is graded.
    (grades).mkdir()
    (grades / "extensions.csv").write_text(
        f"student,due,reason\ns14@example.edu,{EXTENDED},illness\n"
    )
    roster = root / "canvas_gradebook.csv"
    roster.write_text(canvas_roster(s.export))
    s.run(
        "grade-all",
        ["doorlab", "pset", "grade-all", str(s.export), *common, "--export", "canvas",
         "--roster", str(roster), *ref, "--jobs", "2"],
    )  # fmt: skip
    s.equal["grade-all"] = exports_equal_the_sheet(grades)
    s.first_sheet = (grades / "grades.csv").read_text()
    s.first_canvas = (grades / "canvas.csv").read_text()
    s.first_results = {
        sid: json.loads((grades / sid / "results.json").read_text())
        for sid in ("submission_1", "submission_3", "submission_10", "submission_14")
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
    # The instructor grants a point's half by hand: a row of adjustments.csv, never the sheet.
    (grades / "adjustments.csv").write_text(
        "student,test,points,score,reason\nsubmission_7,,0.5,,office hours: the gain's units\n"
    )
    # 7. A new export in which submission_7 is fixed: --resume with the class's assignment.
    new = ["doorlab", "pset", "grade-all", str(s.new_export), "--out", str(grades)]
    s.run("new-export", [*new, "--resume"])
    s.new_changes = (grades / "changes.csv").read_text()
    s.after_new = _results_files(grades)
    s.equal["new-export"] = exports_equal_the_sheet(grades)
    s.new_sheet = (grades / "grades.csv").read_text()
    # 8. A points change (Task 1's unit test 2 -> 3): re-scored, nothing simulated.
    settings.tests.ik_unit.points = 3.0
    course.write_text(assignment_yaml(settings))
    s.run("points", [*new, "--assignment", str(course), "--resume"])
    s.points_changes = (grades / "changes.csv").read_text()
    s.after_points = _results_files(grades)
    s.equal["points"] = exports_equal_the_sheet(grades)
    # 9. One student again (simulated), with the class's assignment.
    s.run("only", [*new, "--only", "submission_7"])
    s.only_changes = (grades / "changes.csv").read_text()
    s.after_only = _results_files(grades)
    s.equal["only"] = exports_equal_the_sheet(grades)
    # 10. Published: the feedback as PDFs, the gradebook files.
    if chromium() is not None:
        s.run("publish", [*new, "--resume", "--published", "--pdf", "--export", "gradescope"])
        s.equal["publish"] = exports_equal_the_sheet(grades)
    # 11. A course without Gradescope: each student's feedback, named for upload.
    s.run("hand-out", ["doorlab", "pset", "feedback", str(grades), str(root / "feedback_files")])
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


def test_the_guide_quotes_the_zip_s_size_and_the_regrade_s_cpu_from_this_run(semester):
    """The teaching guide's numbers of this run: the autograder zip's size (within 10 %: it
    changes with every file of doorlab) and the steps' CPU (printed for the guide)."""
    text = GUIDE.read_text()
    quoted = float(re.search(r"assignment \((\d+) kB, the size the command", text).group(1))
    size = (semester.root / "pset5_autograder.zip").stat().st_size / 1e3
    assert abs(size - quoted) <= 0.1 * quoted, (size, quoted)
    print("CPU-s per step:", {k: round(v, 1) for k, v in semester.cpu.items()})


def test_the_handout_s_self_check_grades_with_the_course_s_16_points(semester):
    """Its total is the course's, the hidden test's point named."""
    out = semester.outputs["self-check"].stdout
    assert "Graded with your course's settings (course.yaml)." in out
    assert "[PASS] Task 3 episode: impedance plan, doors closed: 4 / 4" in out
    assert "[PASS] Task 3 unit test: IiwaTaskSpaceImpedancePlan.CalcTorqueCommand: 2 / 2" in out
    assert out.strip().splitlines()[-1] == (
        "Total score: 6 / 16 (1 in hidden tests: graded by your course, not shown or run here)"
    )
    results = json.loads((semester.folder / "test_results.json").read_text())
    assert sum(t["max_score"] for t in results["tests"]) == 15  # the hidden test not run


def test_the_autograder_honours_gradescope_s_extension_and_shows_the_figures(semester, tmp_path):
    """run_autograder's results.json: valid against Gradescope's specification; the late
    submission with its own due date in Gradescope's metadata loses nothing; the total names
    the hidden point; the episode that ran shows its figure as Gradescope renders HTML (every
    image decodes), the text of each test escaped."""
    proc = semester.outputs["run_autograder"]
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    results = semester.autograder_results
    jsonschema.validate(results, json.loads(SCHEMA.read_text()))
    assert results["score"] == 6 and results["extra_data"]["late"]["penalty_points"] == 0
    assert (
        "Gradescope's due date for this submission (its extension): no penalty"
        in (results["output"])
    )
    assert results["output"].splitlines()[-1] == (
        "Total: 6 / 16 points (1 point in a hidden test, never shown)"
    )
    html = {t["number"]: t for t in results["tests"] if t["output_format"] == "html"}
    assert list(html) == ["3.2"]  # the impedance episode ran; the others stopped at a stub
    assert "data:image/png;base64," in html["3.2"]["output"]
    page = student_view(results)
    (tmp_path / "gradescope.html").write_text(page)
    check = render_check(page, tmp_path)
    assert check["images"] == 1 and check["broken_images"] == []
    assert "Calc_R_WL7_ref" not in page and "calc_R_WL7_ref unit" not in page  # hidden


def test_the_class_is_graded_as_expected_once_per_distinct_files(semester):
    first = semester.outputs["grade-all"]
    sheet = {row["submission"]: row for row in csv.DictReader(semester.first_sheet.splitlines())}
    assert len(sheet) == 15
    for sid, total in semester.expected.items():
        assert float(sheet[sid]["total"]) == pytest.approx(total), (sid, sheet[sid])
    assert sheet["submission_12"]["status"] == "absent"
    for copy in ("submission_2", "submission_3", "submission_14"):
        assert sheet[copy]["same_files_as"] == "submission_1"
    assert sheet["submission_5"]["same_files_as"] == "submission_4"
    assert sheet["submission_2"]["names"] == "Grace One; Alan Two"
    assert sheet["submission_15"]["names"] == "Member A; Member B; Member C"
    # The late one: 2 days late (each started day), 10 % a day.
    assert (sheet["submission_3"]["late_days"], sheet["submission_3"]["late_penalty"]) == (
        "2",
        "3.200",
    )
    late = semester.first_results["submission_3"]
    assert late["score"] == pytest.approx(12.8) and late["extra_data"]["late"]["days_late"] == 2
    assert "2 days counted, -20 % of the score (3.2 points: 16 -> 12.8)" in late["output"]
    # The one as late with an extension in the class's file: no penalty, and the sheet says why.
    assert (sheet["submission_14"]["total"], sheet["submission_14"]["late_penalty"]) == ("16", "0")
    assert sheet["submission_14"]["extension"] == (
        f"due {EXTENDED}: an extension (extensions.csv: illness)"
    )
    # Tests in number order; Gradescope's stdout_visibility; the total names the hidden point.
    key = semester.first_results["submission_1"]
    assert [t["number"] for t in key["tests"]] == [
        "1.1", "1.2", "2.1", "2.2", "2.3", "2.4", "3.1", "3.2"
    ]  # fmt: skip
    assert key["stdout_visibility"] == "hidden" and key["score"] == 16
    assert key["output"].splitlines()[-1] == (
        "Total: 16 / 16 points (1 point in a hidden test, never shown)"
    )
    assert late["output"].splitlines()[-1] == (
        "Total: 12.8 / 16 points (1 point in a hidden test, never shown; late penalty -3.2 "
        "(20 %, 2 days late))"
    )
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
    assert "15 of 15 submissions in the sheet: 1 absent, 13 graded, 1 not graded" in first.stdout
    print(f"first grading: {semester.cpu['grade-all']:.1f} CPU-s for 14 uploads")


def test_every_export_equals_the_sheet_after_every_run(semester):
    """After the first grading, --resume (a new export), a re-score (a points change),
    --only and the publishing run, every export in the folder (canvas.csv from the first
    run on, gradescope.csv from the last) holds the sheet's totals: none stale."""
    assert set(semester.equal) >= {"grade-all", "new-export", "points", "only"}
    assert semester.equal == {step: [] for step in semester.equal}
    canvas_before = semester.first_canvas
    canvas_now = (semester.grades / "canvas.csv").read_text()
    assert canvas_now != canvas_before  # rewritten: submission_7 fixed, a point moved
    assert "canvas export: canvas.csv (19 students, filled from canvas_roster.csv" in (
        semester.outputs["only"].stdout
    )


def test_a_regrade_without_assignment_keeps_the_course_s_settings(semester):
    """Step 7 names no --assignment: the class's (16 points, the late policy, the hidden
    test) grades the fixed submission and keeps every total; nothing else is touched."""
    assert (
        "assignment: the class's (recorded in class.json" in semester.outputs["new-export"].stdout
    )
    changes = list(csv.DictReader(semester.new_changes.splitlines()))
    by_id = {c["submission"]: c for c in changes}
    assert set(by_id) == {"submission_7"}  # the adjustment rides on its regrade
    row = by_id["submission_7"]
    assert row["action"] == "grade" and row["why"].startswith("its files changed (SHA-256 ")
    assert row["why"].endswith("adjustments.csv: 0.5 points added on the total (office hours: "
                               "the gain's units)")  # fmt: skip
    assert (row["old_total"], row["new_total"]) == ("0", "6.5")
    assert row["tests"] == "impedance_unit 0 -> 2; impedance_episode 0 -> 4"
    first, new = read_sheet_text(semester.first_sheet), read_sheet_text(semester.new_sheet)
    for sid, old in first.items():
        if sid != "submission_7":
            assert (new[sid]["total"], new[sid]["max_total"]) == (old["total"], old["max_total"])
    assert new["submission_3"]["total"] == "12.800"  # the late policy kept


def test_a_points_change_regrades_the_class_in_a_tenth_of_its_first_grading_s_cpu(semester):
    """Re-scored from the stored figures, named before anything is simulated: every row's
    Task 1 unit test is worth 3 points, nothing simulated, the previous sheet kept in
    history/, every re-scored submission in changes.csv with why."""
    first, points = semester.cpu["grade-all"], semester.cpu["points"]
    print(f"points change: {points:.2f} CPU-s against {first:.1f} for the first grading")
    assert points < 0.1 * first, (points, first)
    assert (
        "the assignment differs from the class's (tests.ik_unit.points: 2 -> 3): 14 "
        "submission(s) re-scored from their stored figures, nothing simulated"
    ) in semester.outputs["points"].stderr
    changes = list(csv.DictReader(semester.points_changes.splitlines()))
    assert len(changes) == 14  # every upload, not the absent one
    assert {c["action"] for c in changes} == {"rescore"}
    assert all(c["why"] == "tests.ik_unit.points: 2 -> 3" for c in changes)
    key = next(c for c in changes if c["submission"] == "submission_1")
    assert (key["old_total"], key["new_total"], key["tests"]) == ("16", "17", "ik_unit 2 -> 3")
    late = next(c for c in changes if c["submission"] == "submission_3")
    assert (late["old_total"], late["new_total"]) == ("12.8", "13.6")  # 17 less 20 %
    history = semester.grades / "history"
    assert (history / "grades-001.csv").read_text() == semester.first_sheet
    assert (history / "grades-002.csv").read_text() == semester.new_sheet


def test_one_student_again_keeps_the_others_and_the_adjustment(semester):
    """--only (simulated again, the class's assignment): the others' results untouched; the
    adjustment survives the regrade and shows in every output."""
    only = list(csv.DictReader(semester.only_changes.splitlines()))
    assert [(c["submission"], c["action"], c["why"]) for c in only] == [
        ("submission_7", "grade", "regraded on request (--only)")
    ]
    assert {k: v for k, v in semester.after_only.items() if k != "submission_7"} == {
        k: v for k, v in semester.after_points.items() if k != "submission_7"
    }
    grades = semester.grades
    results = json.loads((grades / "submission_7" / "results.json").read_text())
    assert results["score"] == 6.5 and results["extra_data"]["adjusted"]["points"] == 0.5
    assert (
        "Adjustment: +0.5 points on the total by the instructor (6 -> 6.5; office hours: "
        "the gain's units)" in results["output"]
    )
    row = read_sheet(grades / "grades.csv")["submission_7"]
    assert (row["total"], row["adjustment"]) == ("6.500", "0.500")
    assert row["adjustments"] == "0.5 points added on the total (office hours: the gain's units)"
    page = (grades / "feedback" / "submission_7.html").read_text()
    assert "the instructor&#39;s adjustments: +0.5" in page and "office hours" in page
    canvas = {r[3]: r[-1] for r in csv.reader((grades / "canvas.csv").read_text().splitlines())}
    assert canvas["s7@example.edu"] == "6.500"


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


def test_the_canvas_export_is_the_course_s_own_gradebook_filled_in(semester):
    """Canvas's export of the course, with its ID, "Last, First", SIS ids and sections, the
    assignment's existing column and Points Possible; the student who dropped out and the
    absent one left empty (Canvas then changes nothing)."""
    table = list(csv.reader((semester.grades / "canvas.csv").read_text().splitlines()))
    assert table[0] == ["Student", "ID", "SIS User ID", "SIS Login ID", "Section",
                        "Problem set 5 (802)"]  # fmt: skip
    assert table[1] == ["Points Possible", "", "", "", "", "17"]
    rows = {r[3]: r for r in table[2:]}
    assert len(rows) == 19  # 15 submissions, a group of two and one of three, one dropped out
    roster = {r[3]: r for r in csv.reader(canvas_roster(semester.export).splitlines()[2:])}
    grace = rows["grace@example.edu"]
    assert grace[:5] == roster["grace@example.edu"][:5] and grace[0] == "One, Grace"
    assert grace[1].startswith("70") and grace[4].startswith("Section ") and grace[5] == "17"
    assert rows["alan@example.edu"][5] == "17"  # each member gets the group's grade
    assert rows["s3@example.edu"][5] == "13.600"  # late
    assert rows["s14@example.edu"][5] == "17"  # late, with an extension
    assert rows["s12@example.edu"][5] == ""  # absent
    assert rows["gone@example.edu"][5] == ""  # in the roster, no submission
    gradescope = list(csv.DictReader((semester.grades / "gradescope.csv").read_text().splitlines()))
    assert len(gradescope) == 18 and gradescope[0]["Email"] == "ada@example.edu"
    seven = next(r for r in gradescope if r["Email"] == "s7@example.edu")
    assert (seven["Total Score"], seven["Adjustment"]) == ("6.500", "0.500")  # the adjustment
    page = (semester.grades / "class.html").read_text()
    assert "<td>+0.5</td>" in page.split(">submission_7<", 1)[1].split("</tr>", 1)[0]
    out = semester.outputs["grade-all"].stdout
    assert "1 student(s) of the roster have no submission" in out and "Out, Dropped" in out


def test_the_feedback_pages_and_the_class_page_render_with_every_figure(semester, tmp_path):
    """In headless Chromium: the key's page has its three episodes' figures, a stub's none,
    every image decodes, every table has rows; each score names the hidden point; class.html
    has its three figures, every mistake under its test and a link to every page."""
    feedback = semester.grades / "feedback"
    pages = sorted(p.name for p in feedback.glob("*.html"))
    assert len(pages) == 15  # every submission, the absent one's saying so
    key = (feedback / "submission_1.html").read_text()
    for job in ("student-ik", "student-velocity", "student-impedance"):
        assert f'id="figure-{job}"' in key
    result = render_check(key, tmp_path)
    assert result["images"] == 3 and result["broken_images"] == [] and result["empty_tables"] == []
    assert "Score: <strong>17 / 17</strong> (1 point in 1 hidden test (not on this page))" in key
    stub = (feedback / "submission_4.html").read_text()
    assert "<img" not in stub and "NotImplementedError" in stub
    late = (feedback / "submission_3.html").read_text()
    assert "Score: <strong>13.6 / 17</strong>" in late
    assert "after the late penalty: 3.4 points, 20 %, 2 days late" in late
    absent = (feedback / "submission_12.html").read_text()
    assert "No submission was received" in absent
    page = (semester.grades / "class.html").read_text()
    result = render_check(page, tmp_path)
    assert result["images"] == 3 and result["broken_images"] == [], result
    for sid in (f"submission_{n}" for n in range(1, 16)):
        assert f'<a href="feedback/{sid}.html">' in page
    stats = json.loads((semester.grades / "summary.json").read_text())
    assert stats["submissions"] == 15 and stats["by_status"] == {
        "absent": 1,
        "graded": 13,
        "not_graded": 1,
    }
    tests = {t["key"]: t for t in stats["tests"]}
    velocity = tests["velocity_unit"]
    assert velocity["pass_rate"] == pytest.approx(4 / 13, abs=1e-4)  # the key's four uploads
    messages = {k: [m["message"] for m in t["messages"]] for k, t in tests.items()}
    assert any(m.startswith("your file manip_station_sim/robot_plans.py did not import "
                            "(SyntaxError") for m in messages["impedance_unit"])  # fmt: skip
    assert "NameError: name 'scipy' is not defined" in messages["velocity_unit"]
    assert any("the gains swapped" in m for m in messages["impedance_unit"])
    assert all(len(m) <= 300 for ms in messages.values() for m in ms)
    assert velocity["not_attempted"] >= 6  # the stubs left: counted apart from the mistakes
    section = page.split('id="test-impedance_unit"', 1)[1].split("</tr>", 1)[0]
    assert "gains swapped" in section and "SyntaxError" in section  # under their test
    groups = stats["identical_files"]
    assert ["submission_1", "submission_14", "submission_2", "submission_3"] in [
        sorted(g) for g in groups
    ]
    assert not any("submission_4" in g for g in groups)  # the untouched stubs left out


def test_the_feedback_pdfs_print(semester):
    if chromium() is None:
        pytest.skip("chromium not installed: apt-get install chromium")
    pdfs = sorted((semester.grades / "feedback").glob("*.pdf"))
    assert len(pdfs) == 15
    assert "15 printed to PDF" in semester.outputs["publish"].stdout
    assert all(p.read_bytes().startswith(b"%PDF") for p in pdfs)


def test_each_student_s_feedback_is_a_file_named_for_upload(semester):
    folder = semester.root / "feedback_files"
    index = list(csv.DictReader((folder / "index.csv").read_text().splitlines()))
    assert len(index) == 19 - 1  # every student of the class (the roster's drop-out is not)
    alan = next(r for r in index if r["email"] == "alan@example.edu")
    assert alan["file"] == "00022_Two_Alan_submission_2.html"
    assert (folder / alan["file"]).read_text() == (
        semester.grades / "feedback" / "submission_2.html"
    ).read_text()
    assert len(list(folder.glob("*.html"))) == 18
