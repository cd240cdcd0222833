"""doorlab installs without its ``sweep`` extra (pandas, pyarrow, Dask): what runs, reports and
grades needs none of it; ``doorlab sweep`` and ``--scheduler`` then stop with one line saying
how to install it. (The extra is in the test environment: each case hides it from a child
process, as ``sys.modules`` entries of None.)"""

from __future__ import annotations

import subprocess
import sys

import pytest

_HIDE = """
import sys
for name in ("pandas", "pyarrow", "dask", "distributed"):
    sys.modules[name] = None  # import name: ImportError, as when it is not installed
"""


def _run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", _HIDE + code], capture_output=True, text=True, timeout=300
    )


@pytest.mark.parametrize(
    "argv, needs",
    [
        (["sweep", "--grid", "ik.knots=2,3", "--out", "x"], "doorlab sweep needs pandas"),
        (["report", "--scheduler", "tcp://127.0.0.1:1", "--out", "x"], "--scheduler needs"),
        (
            ["pset", "grade-all", ".", "--out", "x", "--scheduler", "tcp://127.0.0.1:1"],
            "--scheduler needs",
        ),
    ],
)
def test_without_the_sweep_extra_the_commands_that_need_it_say_so(tmp_path, argv, needs):
    code = f"import sys\nfrom doorlab.cli.parser import main\nsys.exit(main({argv!r}))"
    proc = subprocess.run(
        [sys.executable, "-c", _HIDE + code],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert proc.returncode == 2, proc.stderr
    assert needs in proc.stderr and 'pip install "doorlab[sweep]"' in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "x").exists()


def test_what_runs_and_grades_imports_none_of_it():
    modules = [
        "doorlab.cli.parser",
        "doorlab.cli.commands",
        "doorlab.episode.controllers",
        "doorlab.outputs.runs",
        "doorlab.report.runner",
        "doorlab.pset.grading.grader",
        "doorlab.pset.grading.jobs",
        "doorlab.pset.grading.checks",
        "doorlab.pset.grading.episodes",
        "doorlab.pset.isolation.worker",
        "doorlab.pset.isolation.intake",
        "doorlab.pset.classroom.gradescope",
        "doorlab.pset.classroom.handout_zip",
        "doorlab.pset.classroom.grade_all",
        "doorlab.pset.classroom.roster",
        "doorlab.pset.isolation.student_view",
        "doorlab.pset.isolation.zygote",
        "doorlab.runtime.executor",
    ]
    code = "import importlib\n" + "".join(f"importlib.import_module({m!r})\n" for m in modules)
    proc = _run(code)
    assert proc.returncode == 0, proc.stderr[-2000:]
