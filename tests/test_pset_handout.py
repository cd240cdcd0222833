"""``doorlab pset handout OUT.zip``: what students get installs and grades from the zip alone.

The end-to-end test is what a student does, in a fresh virtual environment with nothing but
the handout: ``pip install "./doorlab-<version>-py3-none-any.whl[pset]"`` (the dependencies
from the package index, pip's cache reused; it skips, saying why, without the index), the
notebook headless in the folder with the key's three files (its last cell grades them: full
marks), and ``doorlab pset grade`` on the untouched stubs: 0.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import zipfile
from pathlib import Path

import pset_fixtures
import pytest
from package_index import clean_environment, fresh_venv, pip_install, require_index

import doorlab
from doorlab.cli.parser import main
from doorlab.pset.classroom.handout_zip import FOLDER
from doorlab.pset.classroom.wheel import student_wheel_bytes, wheel_bytes
from doorlab.pset.grading.answer_key import practice_table
from doorlab.pset.grading.grader import TESTS
from doorlab.pset.handout.folder import STUDENT_FILES, render_folder
from doorlab.pset.handout.notebook import NOTEBOOK_NAME

WHEEL = f"doorlab-{doorlab.__version__}-py3-none-any.whl"
NOTEBOOK_TIMEOUT_S = 1800
"""The notebook headless: its three episodes and a full grading (~2 min on a busy machine)."""


@pytest.fixture(scope="module")
def reference_args(tmp_path_factory) -> list[str]:
    """--reference with the session's reference episodes (the practice table's figures)."""
    path = tmp_path_factory.mktemp("reference") / "reference.json"
    path.write_text(json.dumps({"extra_data": {"reference": pset_fixtures.reference()}}))
    return ["--reference", str(path)]


@pytest.fixture(scope="module")
def handout_zip(tmp_path_factory, reference_args) -> Path:
    out = tmp_path_factory.mktemp("handout") / "pset5_handout.zip"
    assert main(["pset", "handout", str(out), *reference_args]) == 0
    return out


def test_the_handout_holds_the_stub_folder_and_the_students_wheel(
    handout_zip, tmp_path, reference_args
):
    stubs = render_folder(solutions=False, course=True)  # with the course's course.yaml
    with zipfile.ZipFile(handout_zip) as archive:
        names = set(archive.namelist())
        assert names == {f"{FOLDER}/{rel}" for rel in stubs} | {f"pset5/{WHEEL}"}
        for rel, text in stubs.items():
            assert archive.read(f"{FOLDER}/{rel}").decode() == text, rel
        practice = practice_table(None, pset_fixtures.reference())
        students = student_wheel_bytes(practice, stubs)
        assert archive.read(f"{FOLDER}/{WHEEL}") == students[1]
        assert students[1] != wheel_bytes()[1]  # not the instructor's (test_pset_student_wheel)
        readme = archive.read(f"{FOLDER}/README.md").decode()
    assert f'pip install "./{WHEEL}[pset]"' in readme
    assert "doorlab report" not in readme
    # The same doorlab writes the same bytes; --force replaces a handout, never a user's zip.
    again = tmp_path / "again.zip"
    assert main(["pset", "handout", str(again), *reference_args]) == 0
    assert again.read_bytes() == handout_zip.read_bytes()
    assert main(["pset", "handout", str(again), "--force", *reference_args]) == 0
    mine = tmp_path / "mine.zip"
    mine.write_bytes(b"a teacher's zip")
    assert main(["pset", "handout", str(mine), "--force", *reference_args]) == 2
    assert mine.read_bytes() == b"a teacher's zip"


def _run(argv: list[str], *, cwd: Path, env: dict, timeout: float) -> subprocess.CompletedProcess:
    proc = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, (argv, proc.stdout[-3000:], proc.stderr[-3000:])
    return proc


@pytest.mark.slow
def test_from_the_handout_alone_install_the_notebook_and_grade(handout_zip, tmp_path):
    require_index()
    student = tmp_path / "student"
    with zipfile.ZipFile(handout_zip) as archive:
        archive.extractall(student)
    folder = student / FOLDER
    python = fresh_venv(tmp_path / "venv")
    pip_install(python, f"./{WHEEL}[pset]", cwd=folder, compile=False)  # the README's line
    env = clean_environment(tmp_path / "venv", home=tmp_path / "home")
    where = _run(
        [str(python), "-c", "import doorlab; print(doorlab.__file__)"],
        cwd=tmp_path,
        env=env,
        timeout=120,
    )
    assert Path(where.stdout.strip()).is_relative_to(tmp_path / "venv"), where.stdout
    # Grading needs no sweep extra: none of it came with the handout.
    probe = (
        "import importlib.util as u; "
        "print([m for m in ('pandas', 'pyarrow', 'distributed') if u.find_spec(m)])"
    )
    assert (
        _run([str(python), "-c", probe], cwd=tmp_path, env=env, timeout=120).stdout.strip() == "[]"
    )

    # The key's three files in a copy of the folder; the notebook headless (its last cell
    # runs the folder's grader: Gradescope JSON in test_results.json).
    key = student / "key"
    shutil.copytree(folder, key)
    solutions = render_folder(solutions=True)
    for rel in STUDENT_FILES:
        (key / rel).write_text(solutions[rel])
    jupyter = tmp_path / "venv" / "bin" / "jupyter"
    _run(
        [str(jupyter), "nbconvert", "--to", "notebook", "--execute", NOTEBOOK_NAME]
        + ["--output", "executed.ipynb", f"--ExecutePreprocessor.timeout={NOTEBOOK_TIMEOUT_S}"],
        cwd=key,
        env=env,
        timeout=NOTEBOOK_TIMEOUT_S + 120,
    )
    results = json.loads((key / "test_results.json").read_text())
    full = sum(t.max_score for t in TESTS)
    assert results["score"] == full, [(t["name"], t["output"][-300:]) for t in results["tests"]]
    executed = (key / "executed.ipynb").read_text()
    assert f"Total score: {full:g} / {full:g}" in executed

    # The untouched stubs, with the installed doorlab command (the key's reference episodes).
    doorlab_command = tmp_path / "venv" / "bin" / "doorlab"
    argv = [str(doorlab_command), "pset", "grade", str(folder)]
    _run([*argv, "--reference", str(key / "test_results.json")], cwd=student, env=env, timeout=900)
    stubs = json.loads((folder / "test_results.json").read_text())
    assert stubs["score"] == 0 and len(stubs["tests"]) == len(TESTS)
