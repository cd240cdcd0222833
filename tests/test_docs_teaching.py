"""docs/guides/teaching.md's commands, as written (tests/doc_commands.py).

Its first block, an instructor's commands in brief, runs here on a class of two in
Gradescope's export layout (EXPORT/: the answer key's files and the untouched stubs), with
SUBMISSION the answer key the block's first command writes. Its second block, the semester
step by step, is run by tests/test_pset_semester.py on a class of 13 (it reads the block).
"""

from __future__ import annotations

import csv
import json
import zipfile

import pytest
from doc_commands import Page

from doorlab.pset.grading.grader import TESTS
from doorlab.pset.handout.folder import STUDENT_FILES, init_folder

pytestmark = pytest.mark.slow
FULL = sum(t.max_score for t in TESTS)


def _export(folder, key, stubs) -> None:
    """Gradescope's export: a folder per submission and submission_metadata.yml."""
    people = {"submission_1": ("Ada Key", "001", key), "submission_2": ("Bo Stub", "002", stubs)}
    lines = []
    for sid, (name, student_id, files) in people.items():
        for rel in STUDENT_FILES:
            (folder / sid / rel).parent.mkdir(parents=True, exist_ok=True)
            (folder / sid / rel).write_text((files / rel).read_text())
        lines += [f"{sid}:", "  :submitters:", f"  - :name: {name}", f"    :sid: '{student_id}'"]
        lines += [f"    :email: {student_id}@example.edu"]
        lines += ["  :created_at: 2024-03-01 12:00:00.000000000 -05:00", "  :score: 0.0"]
    (folder / "submission_metadata.yml").write_text("\n".join(lines) + "\n")


def test_teaching_first_block(tmp_path):
    """The key, the settings, the handout, one grading, the class's and the autograder zip:
    each written where the block says; the key 14/14, the stubs 0."""
    sources = tmp_path / "sources"
    export = tmp_path / "clone" / "export"
    export.mkdir(parents=True)
    _export(export, init_folder(sources / "key", solutions=True), init_folder(sources / "stubs"))
    values = {"SUBMISSION": "pset5_key/", "EXPORT/": "export/"}
    page = Page("docs/guides/teaching.md", tmp_path / "clone", values=values)
    outcomes = page.run_blocks()
    assert outcomes[0].how == "ran" and outcomes[1].how.startswith("run by tests/")
    work = page.root
    assert (work / "course.yaml").is_file()
    with zipfile.ZipFile(work / "pset5_handout.zip") as archive:
        assert any(n.endswith(".whl") for n in archive.namelist())
    graded = json.loads((work / "pset5_key" / "test_results.json").read_text())
    lost = [
        (t["name"], t["score"], t.get("status"), t.get("output", "")[-400:])
        for t in graded["tests"]
        if t["score"] != t["max_score"]
    ]
    assert graded["score"] == FULL, lost  # which test lost its points, and what it printed
    with open(work / "grades" / "grades.csv", newline="") as f:
        totals = {row["submission"]: float(row["total"]) for row in csv.DictReader(f)}
    assert totals == {"submission_1": FULL, "submission_2": 0.0}
    assert zipfile.is_zipfile(work / "pset5_autograder.zip")
