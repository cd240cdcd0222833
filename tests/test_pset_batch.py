"""``doorlab pset grade-all``: a class of 30 submissions in Gradescope's export layout.

The class (:func:`build_class`): the answer key, the stubs, each mistake of ``test_pset.py``
planted alone (its file's other functions left as stubs, so that only that mistake's episode
runs), and the upload shapes of the one intake: three files flat, the folder under another
top folder, a zip, a zip with a member pointing outside, a missing file, no file at all, a
folder nested past the intake's bound (not graded), extra files, a group of two students.
Most of them fail fast (a stub's episode ends at its first call), so a grading of the class
costs about a minute of CPU; the reference episodes are the session's
(``pset_fixtures.reference``).

Three gradings of the class serve the acceptance: ``grade-all`` interrupted with Ctrl-C in
the middle then ``--resume``d (local processes); ``grade-all`` on a Dask LocalCluster of 2
workers (a third of the class, a submission of each kind, graded again: the identical rows);
and 13 submissions graded alone (``grade_submission``, as ``doorlab pset grade``; every upload
shape and every way a grading ends): the same rows.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pset_fixtures
import pytest

from doorlab.cli.parser import main
from doorlab.errors import ConfigError
from doorlab.pset.classroom.final_grade import restore
from doorlab.pset.classroom.grade_all import GRADES_CSV, RESULTS_JSON, summarize
from doorlab.pset.classroom.roster import (
    Submission,
    columns,
    find_submissions,
    read_metadata,
    sheet_row,
    sheet_text,
)
from doorlab.pset.grading.grader import grade_submission
from doorlab.pset.handout.folder import init_folder
from doorlab.pset.rules.verdicts import TESTS

FILES = ("ik_utils.py", "open_left_door.py", "manip_station_sim/robot_plans.py")
FULL = sum(t.max_score for t in TESTS)
TIMES = ("wall_time_s", "same_files_as")
"""The sheet's columns that differ between gradings: the times, and which of the submissions
with identical files (graded once) was graded (the first to land: a kept one on --resume)."""

VELOCITY_SOLVED = (
    "        q_dot_des = np.linalg.pinv(self.Jv_WL7q) @ V_des\n"
    "        return q_iiwa + q_dot_des * control_period"
)
IMPEDANCE_SOLVED = "        return self.Jv_WL7q.T @ F"
VELOCITY_STUB = '        raise NotImplementedError("velocity: not done")'
IMPEDANCE_STUB = '        raise NotImplementedError("impedance: not done")'

MISTAKES = {
    # name: (file, [(old, new), ...]) on the key's file; the file's other function a stub
    "ik_ignores_duration": (
        "ik_utils.py",
        [("np.linspace(0.0, duration,", "np.linspace(0.0, 10.0,")],
    ),
    "calc_p_Q_absolute": ("open_left_door.py", [("return p_WQ - p_WC_handle", "return p_WQ")]),
    "yaw_turns_the_wrong_way": ("open_left_door.py", [("yaw = -(angle_end", "yaw = (angle_end")]),
    "velocity_error_sign": (
        "manip_station_sim/robot_plans.py",
        [
            ("100.0 * err_xyz])\n        q_dot", "-100.0 * err_xyz])\n        q_dot"),
            (IMPEDANCE_SOLVED, IMPEDANCE_STUB),
        ],
    ),
    "velocity_axis_in_L7": (
        "manip_station_sim/robot_plans.py",
        [
            (
                "theta_n_W = self.R_WL7 @ (angle_axis.angle() * angle_axis.axis())\n        V_des",
                "theta_n_W = angle_axis.angle() * angle_axis.axis()\n        V_des",
            ),
            (IMPEDANCE_SOLVED, IMPEDANCE_STUB),
        ],
    ),
    "velocity_nan": (
        "manip_station_sim/robot_plans.py",
        [
            (
                "return q_iiwa + q_dot_des * control_period",
                "return q_iiwa + q_dot_des * control_period * np.nan",
            ),
            (IMPEDANCE_SOLVED, IMPEDANCE_STUB),
        ],
    ),
    "impedance_gain_10": (
        "manip_station_sim/robot_plans.py",
        [
            (
                "F = np.concatenate([50.0 * theta_n_W, 100.0",
                "F = np.concatenate([50.0 * theta_n_W, 10.0",
            ),
            (VELOCITY_SOLVED, VELOCITY_STUB),
        ],
    ),
    "impedance_divides_by_zero": (
        "manip_station_sim/robot_plans.py",
        [
            (IMPEDANCE_SOLVED, "        return self.Jv_WL7q.T @ F * (1 // 0)"),
            (VELOCITY_SOLVED, VELOCITY_STUB),
        ],
    ),
}
"""test_pset.py's mistakes, one per submission."""


def _edited(key: Path, rel: str, edits: list[tuple[str, str]]) -> str:
    text = (key / rel).read_text()
    for old, new in edits:
        assert text.count(old) == 1, (rel, old)
        text = text.replace(old, new)
    return text


def _put(folder: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        path = folder / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def build_class(root: Path) -> dict[str, int]:
    """The 30 submissions in ``root/export`` (Gradescope's layout); returns each one's
    expected total where it is known without grading."""
    key = init_folder(root / "key", solutions=True)
    stubs = init_folder(root / "stubs")
    export = root / "export"
    export.mkdir()
    solved = {rel: (key / rel).read_text() for rel in FILES}
    stub = {rel: (stubs / rel).read_text() for rel in FILES}
    helpers_only = {**stub, "open_left_door.py": solved["open_left_door.py"]}  # 2 points
    expected: dict[str, int] = {}
    people = {}

    def add(number: int, files: dict[str, str] | None, total: int | None, where=""):
        sid = f"submission_{number}"
        folder = export / sid
        folder.mkdir()
        if files is not None:
            _put(folder / where, files)
        if total is not None:
            expected[sid] = total
        people[sid] = [(f"Student {number}", f"{number:05d}", f"s{number}@example.edu")]
        return folder

    shutil.copytree(key, export / "submission_101")  # the answer key, the whole folder
    people["submission_101"] = [("Ada Key", "00101", "ada@example.edu")]
    expected["submission_101"] = FULL
    add(102, stub, 0)  # the untouched stubs
    for number, (name, (rel, edits)) in enumerate(MISTAKES.items(), start=103):
        files = {**stub, rel: _edited(key, rel, edits)}
        add(number, files, None, where=name)  # each under a folder named after it
    add(111, helpers_only, 2)  # three files, flat (as Gradescope stores most uploads)
    add(112, helpers_only, 2, where="pset5_open_cabinet_door/")  # the folder under another
    zipped = add(113, None, 2)
    with zipfile.ZipFile(zipped / "handin.zip", "w") as archive:
        for rel, text in helpers_only.items():
            archive.writestr(f"pset5/{rel}", text)
    outside = add(114, None, 0)  # a zip whose open_left_door.py points outside: not taken
    with zipfile.ZipFile(outside / "handin.zip", "w") as archive:
        archive.writestr("../open_left_door.py", solved["open_left_door.py"])
        archive.writestr("ik_utils.py", stub["ik_utils.py"])
    add(115, {"open_left_door.py": solved["open_left_door.py"]}, 2)  # two files missing
    add(116, {"README.txt": "I ran out of time."}, 0)  # none of the files: not graded
    deep = add(117, None, 0)  # nested past the intake's bound: not graded
    _put(deep / "/".join(f"d{i}" for i in range(40)), {"open_left_door.py": "x = 1\n"})
    extras = {**helpers_only, "notes.pdf": "%PDF-1.4\n", "pset.ipynb": "{}"}
    add(118, extras, 2)  # extra files beside the three
    group = add(119, stub, 0)
    # A group; a name a spreadsheet would run as a formula at the start of its cell.
    people["submission_119"] = [("=cmd|' /C calc'!A0", "2", ""), ("Grace One", "00119", "g1@x.edu")]
    del group
    for number in range(120, 131):  # more stubs, as a class has many unfinished ones
        add(number, stub if number % 2 else helpers_only, 0 if number % 2 else 2)
    lines = []
    for sid, students in sorted(people.items()):
        lines.append(f"{sid}:\n  :submitters:")
        for name, student_id, email in students:
            lines.append(f"  - :name: {json.dumps(name)}\n    :sid: '{student_id}'")
            lines.append(f"    :email: {email}")
        lines.append("  :created_at: 2024-03-01 12:00:00.000000000 -05:00\n  :score: 0.0")
    (export / "submission_metadata.yml").write_text("\n".join(lines) + "\n")
    assert len(people) == 30
    return expected


ON_DASK = tuple(f"submission_{n}" for n in (101, 102, 103, 104, 109, 113, 115, 116, 119, 121))
"""The submissions graded again on a Dask cluster: the key, the stubs, a mistake of each task
(103 ik, 104 calc_p_Q, 109 impedance), a zip of the helpers, two files missing, nothing to
grade, a group of two (a name a spreadsheet would run), one of the class's copies of the
stubs."""


ALONE = tuple(f"submission_{n}" for n in (101, 102, 103, 109, *range(111, 120)))
"""The submissions graded alone: the key, the stubs, a mistake of a helper (103) and of a
plan (109), the helpers in their four upload shapes (111 flat, 112 under a folder, 113
zipped, 118 with extra files), a zip pointing outside (114), two files missing (115), none of
the files (116), nested past the bound (117), a group of two (119)."""

COPIES = tuple(f"submission_{n}" for n in range(120, 131))
"""The class's unfinished uploads: flat copies of the stubs (odd) or of the helpers (even)."""


def sub_export(export: Path, ids: tuple[str, ...], dest: Path) -> Path:
    """A copy of ``export`` with the submissions ``ids`` only (their folders and their
    entries in submission_metadata.yml, as Gradescope exports a part of a class)."""
    dest.mkdir(parents=True)
    for sid in ids:
        shutil.copytree(export / sid, dest / sid)
    blocks: list[list[str]] = []  # the file's top-level entries, as written
    for line in (export / "submission_metadata.yml").read_text().splitlines():
        if not line.startswith(" "):
            blocks.append([])
        blocks[-1].append(line)
    kept = [line for block in blocks if block[0].rstrip(":") in ids for line in block]
    (dest / "submission_metadata.yml").write_text("\n".join(kept) + "\n")
    return dest


@pytest.fixture(scope="module")
def klass(tmp_path_factory) -> tuple[Path, dict[str, int], Path]:
    root = tmp_path_factory.mktemp("class")
    expected = build_class(root)
    reference = root / "reference.json"
    reference.write_text(json.dumps({"extra_data": {"reference": pset_fixtures.reference()}}))
    return root / "export", expected, reference


def read_sheet(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def without_times(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in row.items() if k not in TIMES} for row in rows]


def _results_files(out: Path) -> dict[str, tuple]:
    """Each submission's results.json: (inode, modification time) (changed: rewritten)."""
    return {
        p.parent.name: (p.stat().st_ino, p.stat().st_mtime_ns)
        for p in out.glob(f"*/{RESULTS_JSON}")
    }


@pytest.fixture(scope="module")
def resumed(klass, tmp_path_factory) -> dict:
    """grade-all with 2 local workers, Ctrl-C (SIGINT to its process group, as a terminal
    sends it) once 12 submissions are in the sheet, then --resume."""
    export, _, reference = klass
    out = tmp_path_factory.mktemp("resumed") / "class"
    tmp = tmp_path_factory.mktemp("resumed_tmp")  # its TMPDIR: what it leaves there is seen
    os.chmod(tmp, 0o755)
    argv = ["pset", "grade-all", str(export), "--out", str(out), "--reference", str(reference)]
    process = subprocess.Popen(
        [sys.executable, "-m", "doorlab.cli", *argv, "--jobs", "2"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        env={**os.environ, "TMPDIR": str(tmp)},
    )
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        sheet = out / GRADES_CSV
        if sheet.is_file() and len(read_sheet(sheet)) >= 12:
            break
        assert process.poll() is None, process.communicate()
        time.sleep(0.05)
    else:
        process.kill()
        pytest.fail("12 submissions were not graded in time")
    os.killpg(process.pid, signal.SIGINT)
    _, err = process.communicate(timeout=120)
    deadline = time.monotonic() + 20  # the supervisors end with their workers, a moment later
    while time.monotonic() < deadline and (_alive_in(process.pid) or any(tmp.iterdir())):
        time.sleep(0.1)
    first = {
        "code": process.returncode,
        "err": err,
        "rows": read_sheet(out / GRADES_CSV),
        "files": _results_files(out),
        "left": sorted(
            p.name for p in out.iterdir() if p.name.startswith(".") and "partial" in p.name
        ),
        "tmp_left": sorted(p.name for p in tmp.iterdir()),
    }
    code = main([*argv, "--resume", "--jobs", "2"])
    return {"out": out, "first": first, "code": code, "rows": read_sheet(out / GRADES_CSV)}


def _alive_in(session: int) -> bool:
    """Whether a process of session ``session`` (the interrupted command's) is still there."""
    for entry in Path("/proc").iterdir():
        try:
            if entry.name.isdigit() and os.getsid(int(entry.name)) == session:
                return True
        except OSError:
            continue
    return False


@pytest.mark.slow
def test_ctrl_c_leaves_a_consistent_sheet_and_resume_grades_each_submission_once(resumed):
    first = resumed["first"]
    assert first["code"] == 130, first["err"][-2000:]
    assert "interrupted;" in first["err"] and "Traceback" not in first["err"], first["err"][-2000:]
    assert first["left"] == []  # no staging folder left behind
    # Issue 31: nothing in its TMPDIR either (no supervisor's, grading's or submission's
    # folder: the last held the students' files).
    assert first["tmp_left"] == []
    done = {row["submission"] for row in first["rows"]}
    # The sheet after Ctrl-C: the finished submissions, each with its whole results file; a
    # grading the grader failed (an "error" row, the grader's, not the student's; seen once, on
    # a host so starved that statuses came seconds late; its error is printed) has none, by
    # design, and --resume grades it again.
    failed = {row["submission"] for row in first["rows"] if row["status"] == "error"}
    shown = [(r["submission"], r["status"], r.get("error", "")) for r in first["rows"]]
    print("the sheet at Ctrl-C:", shown)
    assert 12 <= len(done) < 30
    assert len(failed) <= 1, shown  # one grader failure at most, else it is not the host's
    graded = done - failed
    assert set(first["files"]) == graded, (shown, first["err"][-1500:])
    assert resumed["code"] == 0
    final = {row["submission"]: row for row in resumed["rows"]}
    assert len(resumed["rows"]) == 30 == len(final)
    assert [r["submission"] for r in resumed["rows"]] == sorted(final)
    assert not [sid for sid, row in final.items() if row["status"] == "error"]
    # Graded exactly once: the resumed run left the first run's results as they were (same
    # file, same time) and wrote each of the others once.
    after = _results_files(resumed["out"])
    assert {k: after[k] for k in graded} == first["files"]
    assert set(after) == set(final)
    assert without_times(r for r in resumed["rows"] if r["submission"] in graded) == without_times(
        r for r in first["rows"] if r["submission"] in graded
    )
    assert not [p for p in resumed["out"].iterdir() if "partial" in p.name]


@pytest.mark.slow
def test_the_sheet_holds_the_expected_scores_names_and_statuses(klass, resumed):
    _, expected, _ = klass
    rows = {row["submission"]: row for row in resumed["rows"]}
    for sid, total in expected.items():
        assert float(rows[sid]["total"]) == total, rows[sid]
    assert (
        rows["submission_101"]["names"] == "Ada Key" and rows["submission_101"]["sids"] == "00101"
    )
    assert rows["submission_119"]["names"] == "'=cmd|' /C calc'!A0; Grace One"  # no formula
    assert rows["submission_119"]["sids"] == "2; 00119"
    assert rows["submission_117"]["status"] == "not_graded"
    assert rows["submission_116"]["status"] == "not_graded"  # a README alone: nothing to grade
    assert (
        rows["submission_115"]["missing_files"] == "ik_utils.py, manip_station_sim/robot_plans.py"
    )
    for sid, row in rows.items():
        if sid not in ("submission_116", "submission_117"):
            assert row["status"] == "graded" and row["sandbox"] == "bwrap", row
            assert row["seed"].isdigit()
            # A copy of identical files (graded once) took no time of its own.
            assert float(row["wall_time_s"]) > 0 or row["same_files_as"], row
    # Each planted mistake costs its tests, never every test.
    for number, name in enumerate(MISTAKES, start=103):
        row = rows[f"submission_{number}"]
        assert 0 <= float(row["total"]) < FULL, (name, row)
    assert float(rows["submission_104"]["calc_p_Q_unit"]) == 0  # the handle not subtracted
    assert float(rows["submission_104"]["calc_R_WL7_ref_unit"]) == 1
    assert float(rows["submission_103"]["ik_unit"]) == 0  # duration ignored: the unit test
    assert float(rows["submission_103"]["ik_episode"]) == 2  # but the episode's duration is 10 s
    assert float(rows["submission_109"]["impedance_unit"]) == 0
    assert float(rows["submission_109"]["impedance_episode"]) == 0  # K_v = 10: the door stays


@pytest.mark.slow
def test_each_submission_graded_alone_gives_its_row(klass, resumed):
    """grade_submission on submission folders of the export (the one intake, as ``doorlab
    pset grade`` runs it; two gradings at a time): the row of the class's sheet, times aside;
    and the same results file, times and the total's line aside.

    Graded alone: every upload shape and every way a grading ends, once each (ALONE). The
    six other single mistakes (104-108, 110) take the same path through the intake as 103
    and 109 and differ only in what the student's code computes, which the sheet test checks
    against each one's expected scores; grading them alone as well cost six gradings that run
    episodes. The eleven unfinished ones (COPIES) get the results of the submission whose
    files they have."""
    from concurrent.futures import ThreadPoolExecutor

    export, _, reference_file = klass
    reference = json.loads(reference_file.read_text())["extra_data"]["reference"]
    submissions = [s for s in find_submissions(export) if s.id in ALONE or s.id in COPIES]
    rows = {row["submission"]: row for row in resumed["rows"]}
    same_files = {1: "submission_102", 0: "submission_111"}
    alone_ones = [s for s in submissions if s.id in ALONE]
    assert len(alone_ones) == len(ALONE)

    def alone(submission: Submission) -> dict:
        return grade_submission(submission.path, reference=reference, jobs=1)

    with ThreadPoolExecutor(max_workers=2) as pool:
        graded = dict(zip([s.id for s in alone_ones], pool.map(alone, alone_ones), strict=True))
    for n in range(120, 131):  # COPIES (build_class): the stubs (odd) or the helpers (even)
        graded[f"submission_{n}"] = json.loads(json.dumps(graded[same_files[n % 2]]))
    for submission in submissions:
        sid, results = submission.id, graded[submission.id]
        text = sheet_text([sheet_row(submission, results)], [t.key for t in TESTS])
        row = next(csv.DictReader(text.splitlines()))
        assert without_times([row]) == without_times([rows[sid]]), sid
        # The class's results as graded (its total's line, written for the student, out).
        batch = restore(json.loads((resumed["out"] / sid / RESULTS_JSON).read_text()))
        for data in (batch, results):
            data.pop("execution_time", None)
            data["extra_data"].pop("batch", None)
        assert batch == results, sid


@pytest.mark.slow
def test_the_class_graded_again_on_a_dask_cluster_gives_the_identical_sheet(
    klass, resumed, tmp_path
):
    """A LocalCluster of 2 worker processes through --scheduler: the identical rows (times
    aside), and the identical results files. The cluster is doorlab's (TLS, a key made for
    it); the command connects with the certificates in Dask's configuration, as the docs
    tell a course to.

    Graded there: a third of the class (:data:`ON_DASK`), one submission of each kind of
    result (the key, the stubs, a mistake of each of the three tasks, a missing file, a zip
    of the helpers, a group, nothing to grade): the cluster's path is the same for every
    submission, and the other 20 would only add gradings of kinds already compared."""
    pytest.importorskip("distributed")
    import dask

    from doorlab.pset.classroom.cluster import local_cluster

    whole, _, reference = klass
    export = sub_export(whole, ON_DASK, tmp_path / "export")
    out = tmp_path / "dask"
    with local_cluster(2) as cluster:
        files = {}
        for name, key in (
            ("ca.pem", "tls_ca_file"),
            ("client.pem", "tls_client_cert"),
            ("client.key", "tls_client_key"),
        ):
            files[key] = tmp_path / name
            files[key].write_text(getattr(cluster.security, key))
        config = {
            "distributed.comm.tls.ca-file": str(files["tls_ca_file"]),
            "distributed.comm.tls.client.cert": str(files["tls_client_cert"]),
            "distributed.comm.tls.client.key": str(files["tls_client_key"]),
            "distributed.comm.require-encryption": True,
        }
        argv = ["pset", "grade-all", str(export), "--out", str(out), "--reference", str(reference)]
        assert cluster.address.startswith("tls://")
        with dask.config.set(config):
            assert main([*argv, "--scheduler", cluster.address]) == 0
    rows = [row for row in resumed["rows"] if row["submission"] in ON_DASK]
    assert len(rows) == len(ON_DASK)
    assert without_times(read_sheet(out / GRADES_CSV)) == without_times(rows)
    for row in rows:
        sid = row["submission"]
        if row["status"] != "absent":
            pair = [json.loads((o / sid / RESULTS_JSON).read_text()) for o in (out, resumed["out"])]
            for data in pair:
                data.pop("execution_time")
                data["extra_data"].pop("batch", None)
            assert pair[0] == pair[1], sid


# What needs no grading -----------------------------------------------------------------------


def test_the_metadata_is_read_within_bounds_and_refused_in_one_line(tmp_path):
    meta = tmp_path / "submission_metadata.yml"
    meta.write_text(
        'submission_1:\n  :submitters:\n  - :name: "Al\\x1b[31m\\u202eB"\n    :sid: 7\n'
        "    :email: a@b.c\n  :results: {tests: [1, 2]}\n  :history: []\n"
        "submission_2: 5\n"
    )
    people = read_metadata(meta)
    assert people["submission_1"] == ({"name": "Al?[31m?B", "sid": "7", "email": "a@b.c"},)
    assert people["submission_2"] == ()
    for text, expected in [
        ("- a\n- b\n", "must map each submission"),
        ("a: [\n", "not valid YAML"),
        ("[" * 5000 + "]" * 5000, "not valid YAML"),  # libyaml: too deep
    ]:
        meta.write_text(text)
        with pytest.raises(ConfigError, match=expected) as error:
            read_metadata(meta)
        assert "\n" not in str(error.value)


def test_submissions_are_folders_and_zips_by_name(tmp_path):
    (tmp_path / "b").mkdir()
    (tmp_path / "a.zip").write_bytes(b"PK")
    (tmp_path / "b.zip").write_bytes(b"PK")  # a folder has that name: the zip keeps .zip
    (tmp_path / ".hidden").mkdir()
    (tmp_path / "__MACOSX").mkdir()
    (tmp_path / "notes.txt").write_text("a flat upload")
    (tmp_path / "b.zip.zip").write_bytes(b"PK")  # its stem is b.zip's whole name
    (tmp_path / "submission_metadata.yml.zip").write_bytes(b"PK")
    found = find_submissions(tmp_path)
    assert [(s.id, s.path.name) for s in found] == [
        ("a", "a.zip"),
        ("b", "b"),
        ("b.zip", "b.zip"),
        ("b.zip.zip", "b.zip.zip"),
        ("notes.txt", "notes.txt"),
        ("submission_metadata.yml", "submission_metadata.yml.zip"),
    ]
    # The class's own files' names are never a submission's (its folder would replace them).
    (tmp_path / "grades.csv").mkdir()
    (tmp_path / "class.json.zip").write_bytes(b"PK")
    found = find_submissions(tmp_path, reserved=("grades.csv", "class.json"))
    assert {s.id: s.path.name for s in found if s.id.startswith(("grades", "class"))} == {
        "grades.csv~2": "grades.csv",
        "class.json.zip": "class.json.zip",
    }
    (tmp_path / "submission_metadata.yml").write_text("c:\n  :submitters: [{':name': Cy}]\n")
    found = {s.id: s for s in find_submissions(tmp_path)}
    assert found["c"] == Submission("c", None, ({"name": "Cy", "sid": "", "email": ""},))
    row = sheet_row(found["c"], None)
    assert row["status"] == "absent" and row["names"] == "Cy"
    assert sheet_text([row], ["k"]).splitlines()[0].split(",") == columns(["k"])


def test_the_summary_gives_the_distribution_and_the_most_failed_test():
    keys = [t.key for t in TESTS]
    full = {k: t.max_score for k, t in zip(keys, TESTS, strict=True)}
    rows = [
        {"submission": "a", "status": "graded", "total": FULL, "max_total": FULL, **full},
        {
            "submission": "b",
            "status": "graded",
            "total": 12,
            "max_total": FULL,
            **full,
            "ik_unit": 0,
        },
        {
            "submission": "c",
            "status": "graded",
            "total": 0,
            "max_total": FULL,
            **dict.fromkeys(keys, 0),
        },
        {"submission": "d", "status": "error", "error": "the grading process failed"},
    ]
    lines = summarize(rows, keys, 5)
    assert lines[0] == "4 of 5 submissions in the sheet: 1 error, 3 graded"
    assert lines[1] == f"scores (of {FULL:g}): mean 8.67, median 12, min 0, max 14"
    assert lines[2] == "distribution (total: submissions): 14: 1, 12: 1, 0: 1"
    assert lines[3].startswith("most often failed: Task 1 unit test: InverseKinPointwise (2 of 3)")
    assert "1 grading errors" in lines[4] and "d: the grading process failed" in lines[4]


@pytest.mark.parametrize(
    "extra, expected",
    [
        (["--resume", "--force"], "exclude each other"),
        (["--jobs", "0"], "--jobs"),
        (["--scheduler", "localhost"], "tcp://HOST:PORT"),
    ],
)
def test_bad_command_lines_are_one_line_and_write_nothing(tmp_path, capsys, extra, expected):
    out = tmp_path / "out"
    (tmp_path / "class" / "s1").mkdir(parents=True)
    assert main(["pset", "grade-all", str(tmp_path / "class"), "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert expected in err and err.count("\n") == 1, err
    assert not out.exists()


def test_an_existing_folder_needs_resume_or_force_and_keeps_what_doorlab_did_not_write(
    tmp_path, capsys
):
    (tmp_path / "class").mkdir()
    out = tmp_path / "out"
    out.mkdir()
    (out / "mine.txt").write_text("my notes")
    argv = ["pset", "grade-all", str(tmp_path / "class"), "--out", str(out)]
    (tmp_path / "class" / "s1").mkdir()
    assert main(argv) == 2
    assert "pass --resume" in capsys.readouterr().err
    assert main([*argv, "--force"]) == 2
    assert "'mine.txt', which doorlab did not write" in capsys.readouterr().err
    assert main([*argv, "--resume"]) == 2
    assert "nothing to resume" in capsys.readouterr().err
    assert (out / "mine.txt").read_text() == "my notes"
    shutil.rmtree(tmp_path / "class" / "s1")
    assert main([*argv, "--force"]) == 2
    assert "holds no submission" in capsys.readouterr().err


@pytest.mark.slow
def test_a_grading_the_grader_fails_is_a_row_and_resume_grades_it_again(klass, tmp_path):
    """A grading whose supervisor fails (here: an isolation policy it does not know) is the
    row of its submission with status error and the message, no results file, exit code 1;
    --resume grades it again, and it lands."""
    from doorlab.pset.classroom.grade_all import grade_class

    export, _, reference_file = klass
    reference = json.loads(reference_file.read_text())["extra_data"]["reference"]
    small = tmp_path / "small"
    small.mkdir()
    shutil.copytree(export / "submission_102", small / "only")  # the stubs
    out = tmp_path / "out"
    failed = grade_class(small, out, reference=reference, isolation="no-such-policy")
    [row] = failed.rows
    assert row["status"] == "error" and "the grading process failed" in row["error"], row
    assert failed.errors == 1 and not (out / "only").exists()
    assert read_sheet(out / GRADES_CSV)[0]["status"] == "error"
    again = grade_class(small, out, reference=reference, resume=True)
    assert again.graded == ["only"] and again.errors == 0
    assert again.rows[0]["status"] == "graded" and again.rows[0]["total"] == 0
    assert (out / "only" / RESULTS_JSON).is_file()


def test_every_upload_is_one_row_and_names_cannot_forge_summary_lines(tmp_path):
    """Issue 31: uploads ``hw0/``, ``hw0.zip`` and a classmate's ``hw0.zip.zip`` are 3 rows,
    each with its own files; file names holding every character str.splitlines breaks on
    (U+2028 and U+2029 among them) print no line of their own: one "Total score" line. None of
    these holds a student file, so nothing is graded (and no worker is started)."""
    from doorlab.pset.classroom.grade_all import grade_class
    from doorlab.pset.grading.grader import pretty_format_json_results

    uploads = tmp_path / "uploads"
    (uploads / "hw0").mkdir(parents=True)
    (uploads / "hw0" / "mine_folder.txt").write_text("folder")
    breaks = "\u2028\u2029\x85\x0b\x0c\x1c\x1d\x1e"
    # "\u2215" (a division slash) looks like "/" but is no folder separator in a zip.
    forged = "".join(f"{c}[PASS] forged {i}: 2 \u2215 2" for i, c in enumerate(breaks))
    forged += "\u2028Total score: 14 \u2215 14"
    for name, member in (("hw0.zip", "mine_zip.txt"), ("hw0.zip.zip", "x" + forged)):
        with zipfile.ZipFile(uploads / name, "w") as archive:
            archive.writestr(member, "zip")
    out = tmp_path / "out"
    outcome = grade_class(uploads, out, reference=pset_fixtures.reference())
    rows = {row["submission"]: row for row in outcome.rows}
    assert sorted(rows) == ["hw0", "hw0.zip", "hw0.zip.zip"]
    assert len(read_sheet(out / GRADES_CSV)) == 3
    assert {r["status"] for r in rows.values()} == {"not_graded"}
    held = {sid: json.loads((out / sid / RESULTS_JSON).read_text())["output"] for sid in rows}
    assert "mine_folder.txt" in held["hw0"] and "mine_zip.txt" in held["hw0.zip"]
    assert "forged" in held["hw0.zip.zip"] and "mine" not in held["hw0.zip.zip"]
    summary = pretty_format_json_results(out / "hw0.zip.zip" / RESULTS_JSON)
    lines = summary.splitlines()
    assert [line for line in lines if line.startswith("Total score")] == [lines[-1]], summary
    assert lines[-1] == "Total score: 0 / 14"
    assert not [line for line in lines if line.lstrip().startswith("[PASS]")], summary
    assert "forged 7" in summary  # the name is shown, on its line
