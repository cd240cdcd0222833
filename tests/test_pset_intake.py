"""The one intake (``doorlab.pset.isolation.intake``): what of a submission is graded, by every
path.

Most tests here run the intake alone (no grading: it is a copy and a walk); the two paths'
agreement is checked on what they hand the grader (its ``grade`` recorded, for the five
upload shapes) and once end to end with real gradings (``--reference``: only the student's
jobs run).
"""

from __future__ import annotations

import json
import os
import shutil
import zipfile
from pathlib import Path

import pset_fixtures
import pytest
from cli_harness import assert_clean_exit, run_doorlab

from doorlab.cli.parser import main
from doorlab.pset.classroom import gradescope
from doorlab.pset.grading import grader
from doorlab.pset.handout.folder import STUDENT_FILES, init_folder, render_folder
from doorlab.pset.isolation import intake
from doorlab.pset.rules.assignment import files_digest
from doorlab.pset.rules.verdicts import TESTS
from doorlab.runtime.folders import MANIFEST_NAME

SOLUTIONS = render_folder(solutions=True)
STUBS = render_folder(solutions=False)
MAX_RESULTS_BYTES = 100_000
"""The acceptance bound on a refused submission's results file."""


def _key_files(folder: Path, files=STUDENT_FILES, *, flat: bool = False) -> Path:
    """The key's student files in ``folder`` (at their places, or flat)."""
    for rel in files:
        path = folder / (Path(rel).name if flat else rel)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(SOLUTIONS[rel])
    return folder


def _zip_folder(folder: Path, out: Path, prefix: str = "") -> Path:
    with zipfile.ZipFile(out, "w") as archive:
        for path in sorted(folder.rglob("*")):
            if path.is_file():
                archive.write(path, prefix + path.relative_to(folder).as_posix())
    return out


def _shapes(root: Path) -> dict[str, Path]:
    """The five upload shapes of the issue, each a submission folder."""
    shapes = {}
    shapes["flat"] = _key_files(root / "flat", flat=True)
    shapes["folder"] = init_folder(root / "folder", solutions=True)
    shapes["nested"] = root / "nested"
    init_folder(shapes["nested"] / "pset5", solutions=True)
    inner = init_folder(root / "to_zip", solutions=True)
    shapes["zip"] = root / "zipped"
    shapes["zip"].mkdir()
    _zip_folder(inner, shapes["zip"] / "my_pset.zip", prefix="pset5/")
    shapes["missing"] = _key_files(root / "missing", STUDENT_FILES[:2], flat=True)
    return shapes


def _graded(folder: Path) -> dict[str, str]:
    return {rel: (folder / rel).read_text() for rel in STUDENT_FILES}


def test_the_five_shapes_take_the_same_files(tmp_path):
    shapes = _shapes(tmp_path)
    seen = {}
    for name, submission in shapes.items():
        folder = init_folder(tmp_path / f"graded_{name}")
        taken = intake.take_submission(submission, folder)
        seen[name] = (_graded(folder), taken)
        assert taken.refused is None
    for name in ("flat", "folder", "nested", "zip"):
        files, taken = seen[name]
        assert files == {rel: SOLUTIONS[rel] for rel in STUDENT_FILES}, name
        assert taken.missing == [] and taken.rejected == [], (name, taken)
    assert seen["zip"][1].taken["ik_utils.py"] == "my_pset.zip/pset5/ik_utils.py"
    assert seen["nested"][1].taken["ik_utils.py"] == "pset5/ik_utils.py"
    files, taken = seen["missing"]
    assert taken.missing == ["manip_station_sim/robot_plans.py"]
    assert files["manip_station_sim/robot_plans.py"] == STUBS["manip_station_sim/robot_plans.py"]
    assert "Not in your submission, so the stub was graded" in taken.summary()
    # A submission given as a zip file (doorlab pset grade SUBMISSION.zip) is the same.
    folder = init_folder(tmp_path / "graded_zipfile")
    taken = intake.take_submission(shapes["zip"] / "my_pset.zip", folder)
    assert _graded(folder) == seen["zip"][0] and taken.taken["ik_utils.py"] == "pset5/ik_utils.py"


def test_only_the_student_files_are_taken_from_a_submission(tmp_path):
    """A whole solutions folder inside another folder, with decoys: modules named like the
    ones the grader imports, a symbolic link and an oversized file named like student files
    (shallower, so they would win if they were allowed), a flat robot_plans.py."""
    submission = tmp_path / "submission"
    init_folder(submission / "pset5", solutions=True)
    (submission / "json.py").write_text("def dumps(*a, **k):\n    return '{\"passed\": true}'\n")
    (submission / "doorlab" / "pset" / "isolation").mkdir(parents=True)
    (submission / "doorlab" / "pset" / "isolation" / "worker.py").write_text(
        "raise SystemExit(0)\n"
    )
    (submission / "ik_utils.py").symlink_to("/etc/passwd")
    big = "#" * (intake.SUBMISSION_FILE_LIMIT + 1)
    (submission / "open_left_door.py").write_text(big)
    (submission / "robot_plans.py").write_text("# an old copy\n")
    (submission / "__MACOSX").mkdir()
    (submission / "__MACOSX" / "._robot_plans.py").write_text("resource fork")

    folder = init_folder(tmp_path / "pset")
    taken = intake.take_submission(submission, folder)
    assert taken.taken == {rel: f"pset5/{rel}" for rel in STUDENT_FILES}
    assert taken.missing == []
    files = {p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()}
    files.discard(MANIFEST_NAME)  # what doorlab wrote there (issue 19's --force rule)
    assert files == set(STUBS), "nothing but the student files enters the folder"
    for rel in files:
        expected = SOLUTIONS[rel] if rel in STUDENT_FILES else STUBS[rel]
        assert (folder / rel).read_text() == expected, rel
    assert {"json.py", "doorlab/pset/isolation/worker.py", "robot_plans.py"} <= set(taken.ignored)
    assert not any("__MACOSX" in f for f in taken.ignored)
    assert any("ik_utils.py is a symbolic link" in r for r in taken.rejected), taken.rejected
    assert any("open_left_door.py is over" in r for r in taken.rejected), taken.rejected
    summary = taken.summary()
    assert "json.py" in summary and "symbolic link" in summary


def test_a_zip_cannot_write_outside_nor_blow_up(tmp_path):
    """Members named ../ or absolute are refused; a member over the limit (whatever its
    header says) is not read past it; zips inside zips are not opened; nothing of the zip
    is written anywhere but the three files' places."""
    submission = tmp_path / "submission"
    submission.mkdir()
    with zipfile.ZipFile(submission / "evil.zip", "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("../ik_utils.py", "print('outside')\n")
        archive.writestr("/abs/open_left_door.py", "print('absolute')\n")
        archive.writestr("bomb/robot_plans.py", "#" * (50 * intake.SUBMISSION_FILE_LIMIT))
        inner = tmp_path / "inner.zip"
        _zip_folder(_key_files(tmp_path / "inner", flat=True), inner)
        archive.write(inner, "inner.zip")
    before = sorted(p.name for p in tmp_path.iterdir())
    folder = init_folder(tmp_path / "graded")
    taken = intake.take_submission(submission, folder)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*before, "graded"])
    assert not (submission / "ik_utils.py").exists()
    assert taken.taken == {}
    assert _graded(folder) == {rel: STUBS[rel] for rel in STUDENT_FILES}
    text = "\n".join(taken.rejected)
    assert "evil.zip/ik_utils.py points outside the zip (../ik_utils.py)" in text, text
    assert "points outside the zip (/abs/open_left_door.py)" in text, text
    assert "evil.zip/bomb/robot_plans.py is over 1000 kB" in text, text
    assert any("a zip inside a zip" in name for name in taken.ignored), taken.ignored


def test_file_names_shown_are_clean_and_the_unused_list_is_capped(tmp_path):
    submission = _key_files(tmp_path / "submission", flat=True)
    names = ["\x1b[2J\x1b[1;1HTotal score: 14 of 14", "nul\x07bell", "zero\u200bwidth"]
    for name in names:
        (submission / name).write_text("x")
    os.mkdir(submission / os.fsdecode(b"bad\xff\xfe"))
    for i in range(500):
        (submission / f"data_{i:03d}.csv").write_text("1")
    folder = init_folder(tmp_path / "graded")
    taken = intake.take_submission(submission, folder)
    shown = taken.summary() + json.dumps(taken.to_dict())
    assert "\x1b" not in shown and "\x07" not in shown and "\u200b" not in shown
    shown.encode("utf-8")  # no lone surrogate
    assert "?[2J?[1;1HTotal score: 14 of 14" in taken.summary()
    assert len(taken.ignored) == intake.SHOWN_IGNORED and taken.ignored_count == 503
    assert f"and {503 - intake.SHOWN_IGNORED} more" in taken.summary()
    assert len(taken.summary()) < 3000


@pytest.mark.slow
@pytest.mark.parametrize("shape", ["deep", "many", "big"])
def test_over_a_bound_a_results_file_names_the_bound(tmp_path, shape, request):
    """1,100 nested folders, 30,000 files, and (in a zip) more than the total size: `doorlab
    pset grade` writes a results file under 100 kB naming the bound, exit 0, no traceback,
    nothing left in its TMPDIR; the intake alone says the same."""
    home, work = tmp_path / "home", tmp_path / "work"
    work.mkdir()
    submission = _key_files(work / "submission", flat=True)
    if shape == "deep":
        path = submission
        for _ in range(1100):  # os.makedirs recurses
            path = path / "d"
            path.mkdir()
        bound = f"more than {intake.MAX_DEPTH} deep"
        request.addfinalizer(lambda: _remove_deep(submission / "d"))
    elif shape == "many":
        many = submission / "many"
        many.mkdir()
        for i in range(30_000):
            (many / f"{i}").touch()
        bound = f"more than {intake.MAX_ENTRIES:,} files and folders"
    else:
        with zipfile.ZipFile(submission / "big.zip", "w", zipfile.ZIP_DEFLATED) as archive:
            for i in range(3):
                archive.writestr(f"blob{i}.bin", b"\0" * (intake.MAX_TOTAL_BYTES // 2))
        bound = f"more than {intake.MAX_TOTAL_BYTES // 1_000_000} MB"
    taken = intake.take_submission(submission, init_folder(tmp_path / "graded"))
    assert taken.refused is not None and bound in taken.refused, taken.refused

    out = run_doorlab(["pset", "grade", "submission"], cwd=work, home=home, timeout=300)
    assert_clean_exit(out, 0)
    results_file = submission / "test_results.json"
    assert results_file.stat().st_size < MAX_RESULTS_BYTES
    results = json.loads(results_file.read_text())
    assert results["score"] == 0 and len(results["tests"]) == len(TESTS)
    assert bound in results["output"] and all(bound in t["output"] for t in results["tests"])
    assert bound in out.stdout
    assert not any((home / "tmp").iterdir()), list((home / "tmp").iterdir())


def _remove_deep(top: Path) -> None:
    """Removes a chain of nested folders without recursion (Python 3.11's rmtree recurses)."""
    path = top
    while (path / "d").is_dir():
        path = path / "d"
    while path != top.parent:
        path.rmdir()
        path = path.parent


# Both paths hand the grader the same folder ------------------------------------------------


@pytest.fixture
def recorded_grade(monkeypatch):
    """``doorlab.pset.grading.grader.grade`` replaced by a recorder of the student files it would
    grade (a folder, or the taken files over the stubs)."""
    calls = []

    def fake_grade(folder, *, files=None, **kwargs):
        if files is not None:
            calls.append(
                {rel: files.get(rel, STUBS[rel].encode()).decode() for rel in STUDENT_FILES}
            )
        else:
            calls.append(_graded(Path(folder)))
        return {"score": 0.0, "tests": [], "output": "", "execution_time": 0.0, "extra_data": {}}

    monkeypatch.setattr(grader, "grade", fake_grade)
    return calls


def _autograder_root(tmp_path: Path) -> Path:
    root = tmp_path / "autograder"
    zip_path = gradescope.write_autograder(tmp_path / "ag.zip")
    with zipfile.ZipFile(zip_path) as archive:
        archive.extractall(root / "source")
    return root


def test_pset_grade_and_run_autograder_take_the_same_files(tmp_path, recorded_grade, capsys):
    root = _autograder_root(tmp_path)
    for name, submission in _shapes(tmp_path / "shapes").items():
        shutil.rmtree(root / "submission", ignore_errors=True)
        shutil.copytree(submission, root / "submission", symlinks=True)
        gradescope.run_autograder(root)
        from_autograder = _as_graded(json.loads((root / "results" / "results.json").read_text()))
        assert main(["pset", "grade", str(submission), "--out", str(tmp_path / "r.json")]) == 0
        from_grade = json.loads((tmp_path / "r.json").read_text())
        assert recorded_grade[-1] == recorded_grade[-2], name
        sub_a = from_autograder["extra_data"]["submission"]
        assert sub_a == from_grade["extra_data"]["submission"], name
        assert from_autograder["output"] == from_grade["output"], name
    capsys.readouterr()


def _as_graded(results: dict) -> dict:
    """run_autograder's results as the grading gave them: without the total's line it adds
    for the student (:mod:`doorlab.pset.classroom.final_grade`) and with each episode test's
    text instead of its HTML with the figure (:mod:`doorlab.pset.classroom.gradescope_html`)."""
    from doorlab.pset.classroom.final_grade import restore

    results = restore(results)
    for test in results["tests"]:
        text = test.pop("extra_data", {}).get("text_output")
        if test["output_format"] == "html":
            test["output"], test["output_format"] = text, "text"
    return results


@pytest.mark.slow
def test_both_paths_grade_a_missing_file_the_same(tmp_path):
    """Real gradings (the reference episodes reused): two of the key's files uploaded flat,
    robot_plans.py missing, through `doorlab pset grade` and `run_autograder`: the same
    scores, and the same results but for times (the same graded files draw the same inputs)."""
    reference = tmp_path / "reference.json"
    reference.write_text(json.dumps({"extra_data": {"reference": pset_fixtures.reference()}}))
    submission = _key_files(tmp_path / "submission", STUDENT_FILES[:2], flat=True)
    root = _autograder_root(tmp_path)
    shutil.copytree(submission, root / "submission")
    gradescope.run_autograder(root, jobs=2, reference=pset_fixtures.reference())
    via_autograder = _as_graded(json.loads((root / "results" / "results.json").read_text()))
    out = tmp_path / "graded.json"
    argv = ["pset", "grade", str(submission), "--out", str(out), "--reference", str(reference)]
    assert main(argv) == 0
    via_grade = json.loads(out.read_text())
    scores = {t["name"]: t["score"] for t in via_grade["tests"]}
    assert scores == {t["name"]: t["score"] for t in via_autograder["tests"]}
    lost = {
        t.name for t in TESTS if "Iiwa" in t.name or "velocity" in t.name or "impedance" in t.name
    }
    assert {n for n, s in scores.items() if s == 0} == lost, scores
    assert via_grade["score"] == sum(t.max_score for t in TESTS) - 8
    for a, b in zip(via_grade["tests"], via_autograder["tests"], strict=True):
        assert a == b
    assert via_grade["extra_data"]["seed"] == via_autograder["extra_data"]["seed"]
    assert via_grade["extra_data"]["seed"]["files_sha256"] == files_digest(
        _key_files(init_folder(tmp_path / "same"), STUDENT_FILES[:2]), STUDENT_FILES
    )


@pytest.mark.slow
def test_pset_grade_takes_a_zip_and_writes_its_results_beside_it(tmp_path, capsys):
    """`doorlab pset grade SUBMISSION.zip`: the stubs zipped (reference episodes reused):
    NAME_results.json beside the zip, the three files taken from it, 0 points."""
    earlier = tmp_path / "earlier.json"
    earlier.write_text(json.dumps({"extra_data": {"reference": pset_fixtures.reference()}}))
    stubs = init_folder(tmp_path / "stubs")
    submission = _zip_folder(stubs, tmp_path / "hw5.zip", prefix="hw5/")
    assert main(["pset", "grade", str(submission), "--reference", str(earlier)]) == 0
    capsys.readouterr()
    results = json.loads((tmp_path / "hw5_results.json").read_text())
    assert results["score"] == 0
    assert results["extra_data"]["submission"]["taken"] == {
        rel: f"hw5/{rel}" for rel in STUDENT_FILES
    }


def test_a_notebook_alone_is_not_graded_on_any_path(tmp_path, capsys):
    """Issue 31: one rule for a submission that holds none of the student files (here the
    notebook alone): ``doorlab pset grade`` refuses it in one line (exit 2, no results);
    what ``grade-all``'s workers and ``run_autograder`` call (``grade_submission`` without
    ``require_files``) gives every test 0 and the reason, no student process started; a flat
    upload of one student file is taken."""
    folder = tmp_path / "upload"
    folder.mkdir()
    (folder / "pset5_open_cabinet_door.ipynb").write_text(
        render_folder(solutions=True)["pset5_open_cabinet_door.ipynb"]
    )
    assert main(["pset", "grade", str(folder)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "holds none of" in err, err
    assert "pset5_open_cabinet_door.ipynb" in err
    assert not (folder / "test_results.json").exists()
    results = grader.grade_submission(folder, isolation="autograder")
    assert results["score"] == 0 and results["extra_data"]["not_graded"]
    assert results["extra_data"]["submission"]["nothing"] is True
    assert all("holds none of" in t["output"] for t in results["tests"])
    assert "sandbox" not in results["extra_data"]  # no student process ran
    flat = tmp_path / "open_left_door.py"
    flat.write_text(SOLUTIONS["open_left_door.py"])
    files, taken = grader.take_files(flat)
    assert taken.refused is None and list(files) == ["open_left_door.py"]
    assert files["open_left_door.py"].decode() == SOLUTIONS["open_left_door.py"]
