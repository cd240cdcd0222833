"""Which doorlab this is: the instructor's (the whole package) or the students' (the handout's).

The students' doorlab is built from the same files with the answer key left out
(:func:`doorlab.pset.classroom.wheel.student_wheel_bytes`: the reference solutions, what runs them,
the grader's expected answers, the solutions' templates, the report's answers), and with one
folder added, ``doorlab/pset/handout/students/``: the stub folder as the handout gave it
(``stubs/``) and the practice table (``practice.json``:
:func:`doorlab.pset.grading.answer_key.practice_table`). That folder is what tells the two apart
(:func:`students`). In the students' doorlab:

- ``doorlab pset init DIR`` writes the handout's stub folder; ``--solutions`` says in one
  line that the answer key is the instructor's (:data:`KEY_IS_THE_INSTRUCTORS`);
- grading (the folder's ``test_pset_5a.py``, ``doorlab pset grade``) judges the student's
  answers against the practice table: the same tests, on the practice draws and the
  reference figures computed where the handout was written; the course's grading draws its
  own from each submission's grading seed;
- a command that needs what was left out says so in one line (``doorlab run``, ``report``,
  ``sweep``, ``pset autograder``, ``pset handout``).
"""

from __future__ import annotations

import json
from functools import cache
from importlib.resources import files

FOLDER = "students"
"""The students' doorlab's own folder, in ``doorlab/pset/handout/``."""
PRACTICE = "practice.json"
STUBS = "stubs"
KEY_IS_THE_INSTRUCTORS = (
    "the answer key is the instructor's: this doorlab was installed from the problem set's "
    "handout, which holds no solutions (doorlab pset init DIR writes the stub folder)"
)
"""What ``pset init --solutions`` says in the students' doorlab."""


def _folder():
    return files("doorlab.pset.handout").joinpath(FOLDER)


@cache
def students() -> bool:
    """Whether this is the students' doorlab (installed from the handout)."""
    return _folder().joinpath(PRACTICE).is_file()


@cache
def _practice_text() -> str:
    return _folder().joinpath(PRACTICE).read_text()


def practice() -> dict:
    """The practice table (a fresh copy): ``seed`` (the practice draws' random seed),
    ``tests`` (the names of the tests it practises: never a hidden one), ``units`` (their
    unit tests' expectations), ``reference`` (their reference episodes' figures),
    ``helpers`` (the reference helpers' table)."""
    return json.loads(_practice_text())


def practised(names) -> list:
    """Of the test names ``names``, those the practice table has what to grade with (a
    table of an older handout, without ``tests``: all)."""
    tests = practice().get("tests")
    return list(names) if tests is None else [n for n in names if n in set(tests)]


def stub_files() -> dict[str, str]:
    """The handout's stub folder: relative path -> text."""
    out = {}

    def walk(node, prefix: str) -> None:
        for child in node.iterdir():
            rel = f"{prefix}{child.name}"
            if child.name == "__pycache__":  # pip compiles the stubs' Python files too
                continue
            if child.is_dir():
                walk(child, rel + "/")
            else:
                out[rel] = child.read_text()

    walk(_folder().joinpath(STUBS), "")
    return dict(sorted(out.items()))


def left_out(name: str) -> str:
    """One line for a command that needs module ``name``, which the students' doorlab
    leaves out."""
    return (
        f"this needs {name}, which the students' doorlab leaves out (it was installed from "
        "the problem set's handout, without the answer key): the course's instructor runs it"
    )
