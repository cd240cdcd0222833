"""Issue 31: the handout's wheel holds no answer key, and still runs and grades the problem set.

The handout's wheel is the students' doorlab
(:func:`doorlab.pset.classroom.wheel.student_wheel_bytes`): the installed package's files without
:data:`~doorlab.pset.classroom.wheel.STUDENT_WHEEL_LEAVES_OUT`. What "holds the key" means here,
derived from the instructor's doorlab rather than typed in: any line of the five solved functions
(the ``--solutions`` files' lines the stubs lack), any definition (source) or code object (compiled
``.pyc``) named like one of the left-out modules' own functions and classes (the reference laws, IK
and plans, the controllers, the grader's expected answers), any template of the solutions. The
installed tree is checked after pip installed it and ``compileall`` compiled every file (``--no-deps
--no-index``: the wheel is what is tested, the package index is not; doorlab's dependencies come
from this environment through a path file, as in ``test_pset_autograder.py``). In that venv ``pset
init --solutions`` says in one line that the key is the instructor's, and the folder's self-check
grades the key's files 14/14 and the stubs 0 against the handout's practice table.
"""

from __future__ import annotations

import ast
import json
import marshal
import shutil
import site
import subprocess
import sys
import zipfile
from pathlib import Path

import pset_fixtures
import pytest

import doorlab
from doorlab.pset.classroom import wheel
from doorlab.pset.classroom.handout_zip import FOLDER, write_handout
from doorlab.pset.grading.grader import TESTS
from doorlab.pset.handout import edition
from doorlab.pset.handout.folder import STUDENT_FILES, render_folder
from doorlab.pset.rules.assignment import Assignment

PACKAGE = Path(doorlab.__file__).resolve().parent


def _defined(source: str) -> set[str]:
    """Names of every function and class a module's source defines (at any depth)."""
    tree = ast.parse(source)
    return {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef | ast.ClassDef)}


def _kept_and_left_out() -> tuple[list[Path], list[Path]]:
    files = [PACKAGE.parent / str(rel) for rel in wheel.package_files()]
    left = [p for p in files if wheel._left_out(str(p.relative_to(PACKAGE.parent)))]
    return [p for p in files if p not in left], left


def key_names() -> set[str]:
    """The left-out modules' own functions and classes (names no kept module defines; the
    templates' given Python files, the stubs' own, are not modules of the key)."""
    kept, left = _kept_and_left_out()
    modules = [p for p in left if p.suffix == ".py" and "templates" not in p.parts]
    ours = set().union(*(_defined(p.read_text()) for p in modules))
    theirs = set().union(*(_defined(p.read_text()) for p in kept if p.suffix == ".py"))
    return ours - theirs


def key_lines() -> set[str]:
    """Each line of the five solved functions: the --solutions files' lines the stubs lack,
    but those of the handout's own helpers (the student side, which every student's view
    holds: SolveOneShotIk's InverseKinematics calls, InterpolateArc's arc)."""
    from doorlab.pset.isolation import bwrap_root

    given = set()
    for rel in bwrap_root.student_files():
        if rel.endswith(".py"):
            given |= {line.strip() for line in (PACKAGE.parent / rel).read_text().splitlines()}
    solved, stubs = render_folder(solutions=True), render_folder(solutions=False)
    out = set()
    for rel in STUDENT_FILES:
        stub_lines = {line.strip() for line in stubs[rel].splitlines()} | given
        for line in solved[rel].splitlines():
            text = line.strip()
            if len(text) >= 12 and text not in stub_lines and not text.startswith("#"):
                out.add(text)
    return out


def _code_names(code) -> set[str]:
    names = {code.co_name}
    for const in code.co_consts:
        if hasattr(const, "co_name"):
            names |= _code_names(const)
    return names


def holding_the_key(root: Path) -> list[str]:
    """What of the key a tree holds: files of left-out modules, definitions and code
    objects named like the key's, solved lines, the solutions' templates."""
    names, lines, found = key_names(), key_lines(), []
    assert len(names) >= 15 and {"velocity_law", "impedance_law", "pointwise_ik"} <= names
    assert any("Jv_WL7q.T @ F" in line for line in lines), lines
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        rel = str(path.relative_to(root))
        if path.suffix == ".pyc":
            code = marshal.loads(path.read_bytes()[16:])
            hits = _code_names(code) & names
            found += [f"{rel}: code {n}" for n in sorted(hits)]
            continue
        text = path.read_bytes().decode("utf-8", "replace")
        if path.suffix == ".py":
            found += [f"{rel}: defines {n}" for n in sorted(_defined(text) & names)]
        present = {line.strip() for line in text.splitlines()}
        found += [f"{rel}: {line!r}" for line in sorted(lines & present)]
        if "{% if solutions %}" in text:
            found.append(f"{rel}: a template of the solutions")
    return found


HIDDEN = ("velocity_unit", "impedance_episode")
"""The tests the handout's course hides (issue 43: their practice draws, mistakes and
reference figures were in the handout)."""


def course(hidden: tuple[str, ...] = HIDDEN) -> Assignment:
    """The course of the module's handout: the defaults, ``hidden`` hidden."""
    assignment = Assignment()
    for key in hidden:
        getattr(assignment.tests, key).visibility = "hidden"
    return assignment


@pytest.fixture(scope="module")
def handout(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("handout") / "pset5_handout.zip"
    return write_handout(out, assignment=course(), reference=pset_fixtures.reference())


def _floats(data) -> set[str]:
    """The JSON texts of the distinctive floats in ``data`` (12 characters or more)."""
    if isinstance(data, float):
        text = json.dumps(data)
        return {text} if len(text) >= 12 else set()
    if isinstance(data, dict):
        data = list(data.values())
    if isinstance(data, list):
        return set().union(*(_floats(x) for x in data)) if data else set()
    return set()


def hidden_and_shown() -> tuple[set[str], set[str]]:
    """Numbers of the practice table only the hidden tests have (their unit's draws,
    expectations and mistakes; their episode's reference figures), and of a shown test."""
    from doorlab.pset.grading.answer_key import practice_table

    full = practice_table(course(()), pset_fixtures.reference())
    hidden = _floats(full["units"]["velocity"])
    hidden |= _floats(full["reference"]["reference:impedance"])
    shown = _floats(full["units"]["impedance"]) | _floats(full["reference"]["reference:ik"])
    return hidden - shown, shown - hidden


def holding_hidden(tree: Path, numbers: set[str]) -> list[str]:
    """Where in ``tree`` any of ``numbers`` is written."""
    found = []
    for path in sorted(tree.rglob("*")):
        if path.is_file():
            data = path.read_bytes()
            found += [f"{path.relative_to(tree)}: {n}" for n in numbers if n.encode() in data]
    return found


@pytest.mark.slow
def test_the_full_doorlab_holds_the_key_the_check_looks_for(tmp_path):
    """The check can fail: the instructor's wheel (the autograder's) holds all of it."""
    _, data = wheel.wheel_bytes()
    with zipfile.ZipFile(__import__("io").BytesIO(data)) as archive:
        archive.extractall(tmp_path / "full")
    control = tmp_path / "full" / "doorlab" / "control"
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(control)], check=True)
    found = holding_the_key(tmp_path / "full")
    assert any("defines impedance_law" in f for f in found), found[:5]
    assert any(".pyc: code impedance_law" in f for f in found), found[:5]
    assert any("Jv_WL7q.T @ F" in f for f in found) and any("template" in f for f in found)


@pytest.mark.slow
def test_the_handout_s_wheel_holds_no_answer_key(handout, tmp_path):
    """The students' wheel: none of the left-out files, nothing of the key in what is left,
    the handout's stub folder and its practice table added."""
    with zipfile.ZipFile(handout) as archive:
        data = archive.read(f"{FOLDER}/{wheel_name()}")
    with zipfile.ZipFile(__import__("io").BytesIO(data)) as archive:
        names = archive.namelist()
        archive.extractall(tmp_path / "wheel")
    assert not [n for n in names if wheel._left_out(n)]
    assert holding_the_key(tmp_path / "wheel") == []
    students = tmp_path / "wheel" / "doorlab" / "pset" / "handout" / edition.FOLDER
    stubs = {
        str(p.relative_to(students / edition.STUBS)): p.read_text()
        for p in (students / edition.STUBS).rglob("*")
        if p.is_file()
    }
    assert stubs == render_folder(solutions=False, course=True, assignment=course())
    practice = json.loads((students / edition.PRACTICE).read_text())
    # Nothing of the hidden tests (Task 2's velocity unit test, Task 3's episode).
    assert set(practice["units"]) == {"ik", "calc_p_Q", "calc_R_WL7_ref", "impedance"}
    assert set(practice["reference"]) == {"reference:ik", "reference:velocity"}
    shown = [t.name for t in TESTS if t.key not in HIDDEN]
    assert practice["tests"] == shown


def wheel_name() -> str:
    return f"doorlab-{doorlab.__version__}-py3-none-any.whl"


def _venv(root: Path, wheel_file: Path) -> Path:
    """A venv with the wheel installed alone (its dependencies: this environment's)."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(root)], check=True)
    python = root / "bin" / "python"
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--quiet"]
        + ["--no-deps", "--no-index", str(wheel_file)],
        check=True,
    )
    purelib = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    Path(purelib, "doorlab_test_dependencies.pth").write_text("\n".join(site.getsitepackages()))
    return python


def _run(argv: list, **kwargs) -> subprocess.CompletedProcess:
    env = {"PATH": "/usr/bin:/bin", "HOME": "/tmp", "LANG": "C.UTF-8"}
    return subprocess.run(argv, capture_output=True, text=True, timeout=900, env=env, **kwargs)


@pytest.mark.slow
def test_installed_from_the_handout_no_key_and_the_self_check_is_the_course_s_tests(
    handout, tmp_path
):
    """pip installs the handout's wheel; its installed tree, compiled, holds no key; the
    left-out modules cannot be imported; ``pset init --solutions`` says in one line that the
    key is the instructor's; the stub folder it writes, with the key's files, grades 14/14
    through the folder's test_pset_5a.py (the notebook's last cell), the stubs 0."""
    with zipfile.ZipFile(handout) as archive:
        archive.extractall(tmp_path / "student")
    folder = tmp_path / "student" / FOLDER
    python = _venv(tmp_path / "venv", folder / wheel_name())
    installed = Path(
        _run([str(python), "-I", "-c", "import doorlab; print(doorlab.__file__)"]).stdout.strip()
    ).parent
    assert installed.is_relative_to(tmp_path / "venv"), installed
    subprocess.run([str(python), "-m", "compileall", "-q", str(installed)], check=True)
    assert holding_the_key(installed) == []
    hidden, shown = hidden_and_shown()
    assert len(hidden) > 20 and len(shown) > 20, (len(hidden), len(shown))
    assert holding_hidden(installed, hidden) == []  # issue 43: nothing of a hidden test
    assert len(holding_hidden(installed, shown)) == len(shown)  # the search finds what is there
    probe = (
        "import importlib, json\n"
        "out = {}\n"
        "for name in ('doorlab.control.laws', 'doorlab.control.ik_pointwise', "
        "'doorlab.control.plans', 'doorlab.pset.grading.answer_key', "
        "'doorlab.episode.controllers'):\n"
        "    try:\n"
        "        importlib.import_module(name); out[name] = 'imported'\n"
        "    except ImportError as e:\n"
        "        out[name] = type(e).__name__\n"
        "print(json.dumps(out))"
    )
    imports = json.loads(_run([str(python), "-I", "-c", probe]).stdout)
    assert set(imports.values()) == {"ModuleNotFoundError"}, imports
    command = tmp_path / "venv" / "bin" / "doorlab"
    refused = _run([str(command), "pset", "init", str(tmp_path / "key"), "--solutions"])
    assert refused.returncode == 2 and len(refused.stderr.strip().splitlines()) == 1, refused
    assert "the answer key is the instructor's" in refused.stderr
    assert not (tmp_path / "key").exists()
    ran = _run([str(command), "run"], cwd=tmp_path)  # its default folder: doorlab_out/ there
    assert ran.returncode == 2 and "leaves out" in ran.stderr and "Traceback" not in ran.stderr
    # The self-check, as the notebook's last cell runs it, on the key's files and the stubs.
    assert _run([str(command), "pset", "init", str(tmp_path / "mine")]).returncode == 0
    solved = render_folder(solutions=True)
    shutil.copytree(tmp_path / "mine", tmp_path / "stubs")
    for rel in STUDENT_FILES:
        (tmp_path / "mine" / rel).write_text(solved[rel])
    scores = {}
    for name in ("mine", "stubs"):
        proc = _run([str(python), "test_pset_5a.py", "out.json"], cwd=tmp_path / name)
        assert proc.returncode == 0, proc.stderr[-3000:]
        results = json.loads((tmp_path / name / "out.json").read_text())
        scores[name] = results["score"]
        assert "practice draws" in results["extra_data"]["seed"]["source"]
    practised = sum(t.max_score for t in TESTS if t.key not in HIDDEN)  # the self-check's
    assert scores == {"mine": practised, "stubs": 0}, scores
