"""The problem set (``doorlab pset``): the folder, the 2019 notebook's own cells, the grader.

Expensive work is shared (``pset_fixtures``, cached per session): one solutions folder runs
the 2019 notebook's code cells (three episodes) and its last cell runs the full grader (with the
reference episodes); the other gradings reuse those reference figures and run only the tests
a case needs (``only=``), so this module simulates about a dozen episodes in all.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pset_fixtures
import pytest

from doorlab.cli.parser import main
from doorlab.pset.grading.grader import TESTS, grade, pretty_format_json_results
from doorlab.pset.handout.folder import STUDENT_FUNCTIONS, init_folder

UNIT = {t.name.split(": ", 1)[1]: t.name for t in TESTS if "unit test" in t.name}
EPISODE = {
    key: next(t.name for t in TESTS if "episode" in t.name and word in t.name)
    for key, word in (("ik", "IK"), ("velocity", "velocity"), ("impedance", "impedance"))
}


@pytest.fixture(scope="module")
def notebook_cells() -> list[str]:
    return pset_fixtures.notebook_cells()


@pytest.fixture(scope="module")
def solutions_run(notebook_cells):
    """A fresh ``--solutions`` folder in which the notebook's cells ran in order (shared)."""
    return pset_fixtures.solutions_run()


@pytest.fixture(scope="module")
def reference() -> dict:
    """The reference episodes' figures from the solutions' grading (reused below)."""
    return pset_fixtures.reference()


def _wrong_folder(tmp_path_factory, name: str, edits: list[tuple[str, str, str]]) -> Path:
    """A solutions folder with the given (file, old, new) text replacements."""
    folder = tmp_path_factory.mktemp("wrong") / name
    init_folder(folder, solutions=True)
    for rel, old, new in edits:
        path = folder / rel
        text = path.read_text()
        assert text.count(old) == 1, f"{old!r} not found once in {rel}"
        path.write_text(text.replace(old, new))
    return folder


def _scores(results: dict) -> dict[str, float]:
    return {t["name"]: t["score"] for t in results["tests"]}


def _failed(results: dict) -> set[str]:
    return {t["name"] for t in results["tests"] if t["score"] < t["max_score"]}


def _output(results: dict, name: str) -> str:
    return next(t["output"] for t in results["tests"] if t["name"] == name)


# The folder ------------------------------------------------------------------------------


def test_init_writes_the_original_layout_with_stubs_or_solutions(tmp_path):
    stubs, solutions = tmp_path / "stubs", tmp_path / "solutions"
    assert main(["pset", "init", str(stubs)]) == 0
    assert main(["pset", "init", str(solutions), "--solutions"]) == 0
    expected = {
        "open_left_door.py",
        "ik_utils.py",
        "manip_station_sim/__init__.py",
        "manip_station_sim/manipulation_station_simulator.py",
        "manip_station_sim/robot_plans.py",
        "manip_station_sim/plan_utils.py",
        "pset5_open_cabinet_door.ipynb",
        "test_pset_5a.py",
        "README.md",
        ".doorlab-manifest.json",  # what pset init wrote (doorlab.runtime.folders.MANIFEST_NAME)
    }
    for folder in (stubs, solutions):
        files = {str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()}
        assert files == expected
        notebook = json.loads((folder / "pset5_open_cabinet_door.ipynb").read_text())
        assert notebook["nbformat"] == 4
        assert sum(c["cell_type"] == "code" for c in notebook["cells"]) >= 8
        for rel in expected - {"pset5_open_cabinet_door.ipynb", "README.md"}:
            compile((folder / rel).read_text(), rel, "exec")  # valid Python
            # Thin files: everything but the student's code delegates to doorlab.
            assert len((folder / rel).read_text().splitlines()) < 130, rel
    stub_text = "".join((stubs / f).read_text() for f in expected if f.endswith(".py"))
    solution_text = "".join((solutions / f).read_text() for f in expected if f.endswith(".py"))
    assert stub_text.count("raise NotImplementedError") == len(STUDENT_FUNCTIONS)
    assert stub_text.count("Your code here") == len(STUDENT_FUNCTIONS)
    assert "NotImplementedError" not in solution_text
    readme = (stubs / "README.md").read_text()
    for t in TESTS:
        assert t.name in readme


def test_init_refuses_a_bad_destination(tmp_path, capsys):
    folder = tmp_path / "pset"
    assert main(["pset", "init", str(folder)]) == 0
    marker = folder / "mine.txt"
    marker.write_text("keep")
    capsys.readouterr()
    assert main(["pset", "init", str(folder)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--force" in err
    assert marker.exists()
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    assert main(["pset", "init", str(a_file / "pset")]) == 2
    assert "is a file" in capsys.readouterr().err
    assert main(["pset", "init", str(folder), "--force", "--solutions"]) == 2  # issue 19
    assert "mine.txt" in capsys.readouterr().err and marker.read_text() == "keep"
    marker.unlink()
    assert main(["pset", "init", str(folder), "--force", "--solutions"]) == 0
    capsys.readouterr()
    empty = tmp_path / "empty"
    empty.mkdir()
    for target, needle in [
        (tmp_path / "nowhere", "does not exist"),
        (a_file, "holds none of"),  # a flat file: taken only if it is a student file
        (empty, "holds none of"),  # a mistyped folder is not graded as the stubs
    ]:
        assert main(["pset", "grade", str(target)]) == 2
        err = capsys.readouterr().err
        assert needle in err and len(err.strip().splitlines()) == 1, err
    assert not (empty / "test_results.json").exists()


# The 2019 notebook's own cells, and the solutions' full marks ------------------------------


@pytest.mark.slow
def test_notebook_cells_run_unchanged_in_a_solutions_folder(notebook_cells, solutions_run):
    folder, proc = solutions_run
    # setup, 2 meshcat cells, 3 tasks x (simulate + 4 analysis cells), 3 plots, the grader
    assert len(notebook_cells) >= 18, len(notebook_cells)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert proc.stdout.count("--- cell") == len(notebook_cells)
    assert "--- all cells ran" in proc.stdout
    # The last cell printed the grader's summary.
    assert "Total score:" in proc.stdout
    # The notebook slices its logs by index (t_start = 11 -> sample 1100): samples every 0.01 s
    # from t = 0, and the arc plan starts at 11 s (hold 2 s, move 7 s, grasp 1 + 1 s).
    facts = json.loads(proc.stdout.split("FACTS ", 1)[1].splitlines()[0])
    t = np.array(facts["t"])
    assert t[0] == 0.0 and np.allclose(np.diff(t), 0.01)
    assert t[1100] == pytest.approx(11.0) and t[2100] == pytest.approx(21.0)
    assert facts["t_plan"] == pytest.approx([0.0, 2.0, 9.0, 11.0, 22.0])


def test_solutions_score_full_marks_with_fresh_references(solutions_run):
    folder, proc = solutions_run
    results = json.loads((folder / "test_results.json").read_text())
    assert [t["name"] for t in results["tests"]] == [t.name for t in TESTS]
    assert results["score"] == sum(t.max_score for t in TESTS), pretty_format_json_results(
        folder / "test_results.json"
    )
    assert set(results["extra_data"]["reference"]) == {
        "reference:ik",
        "reference:velocity",
        "reference:impedance",
    }
    for t in results["tests"]:
        assert t["output"].strip(), t["name"]


# Stubs, wrong implementations, exceptions, NaN, endless loops ------------------------------


@pytest.mark.slow
def test_stubs_score_zero_without_crashing(tmp_path, reference, capsys):
    """`doorlab pset grade` on the untouched stubs (reusing the reference episodes)."""
    reference_file = tmp_path / "earlier_results.json"
    reference_file.write_text(json.dumps({"extra_data": {"reference": reference}}))
    folder = tmp_path / "stubs"
    assert main(["pset", "init", str(folder)]) == 0
    assert main(["pset", "grade", str(folder), "--reference", str(reference_file)]) == 0
    out = capsys.readouterr().out
    assert f"Total score: 0 / {sum(t.max_score for t in TESTS):g}" in out
    results = json.loads((folder / "test_results.json").read_text())
    assert results["score"] == 0
    assert len(results["tests"]) == len(TESTS)
    for t in results["tests"]:
        assert "NotImplementedError" in t["output"], t


@pytest.mark.slow
def test_two_disjoint_mistakes_lose_exactly_their_tests(tmp_path_factory, reference):
    """IK ignores `duration` (knots at 0..10 s) and the impedance plan uses K_v = 10 N/m: the
    IK unit test fails but the IK episode (duration 10 s) passes; the impedance unit test and
    episode fail (the arm barely pulls); everything else passes."""
    folder = _wrong_folder(
        tmp_path_factory,
        "ik_duration_impedance_gain",
        [
            ("ik_utils.py", "np.linspace(0.0, duration,", "np.linspace(0.0, 10.0,"),
            (
                "manip_station_sim/robot_plans.py",
                "F = np.concatenate([50.0 * theta_n_W, 100.0 * err_xyz])",
                "F = np.concatenate([50.0 * theta_n_W, 10.0 * err_xyz])",
            ),
        ],
    )
    results = grade(folder, reference=reference)
    assert _failed(results) == {
        UNIT["InverseKinPointwise"],
        UNIT["IiwaTaskSpaceImpedancePlan.CalcTorqueCommand"],
        EPISODE["impedance"],
    }, pretty(results)
    assert "must span" in _output(results, UNIT["InverseKinPointwise"])
    assert "expected" in _output(results, UNIT["IiwaTaskSpaceImpedancePlan.CalcTorqueCommand"])
    assert "FAILED door opened" in _output(results, EPISODE["impedance"])


@pytest.mark.slow
def test_calc_p_Q_without_the_handle_offset_costs_its_own_point_only(tmp_path_factory, reference):
    """calc_p_Q returns the arc point itself (absolute, not relative to the start): by
    default the task 2 and 3 episodes run doorlab's helpers, so only calc_p_Q's unit test
    fails; with the student's helpers (the assignment's choice) both episodes fail and say
    that they used the student's calc_p_Q, which failed its unit test."""
    from doorlab.pset.rules.assignment import Assignment

    folder = _wrong_folder(
        tmp_path_factory,
        "calc_p_Q_absolute",
        [("open_left_door.py", "return p_WQ - p_WC_handle", "return p_WQ")],
    )
    episodes = [EPISODE["velocity"], EPISODE["impedance"]]
    only = [UNIT["calc_p_Q"], UNIT["calc_R_WL7_ref"], *episodes]
    results = grade(folder, reference=reference, only=only)
    assert _failed(results) == {UNIT["calc_p_Q"]}, pretty(results)
    assert "expected" in _output(results, UNIT["calc_p_Q"])
    for name in episodes:
        assert "runs doorlab's calc_p_Q and calc_R_WL7_ref" in _output(results, name)

    theirs = Assignment()
    theirs.tests.velocity_episode.helpers = "student"
    theirs.tests.impedance_episode.helpers = "student"
    results = grade(folder, reference=reference, only=episodes, assignment=theirs)
    assert _failed(results) == set(episodes), pretty(results)
    for name in episodes:
        text = _output(results, name)
        assert "this episode uses your calc_p_Q, which failed its unit test" in text, text
        assert "calc_R_WL7_ref, which failed" not in text, text


@pytest.mark.slow
def test_velocity_with_the_error_sign_flipped_fails_its_tests(tmp_path_factory, reference):
    folder = _wrong_folder(
        tmp_path_factory,
        "velocity_sign",
        [
            (
                "manip_station_sim/robot_plans.py",
                "V_des = np.concatenate([50.0 * theta_n_W, 100.0 * err_xyz])",
                "V_des = np.concatenate([50.0 * theta_n_W, -100.0 * err_xyz])",
            )
        ],
    )
    vel = UNIT["IiwaTaskSpaceVelocityPlan.CalcPositionCommand"]
    imp = UNIT["IiwaTaskSpaceImpedancePlan.CalcTorqueCommand"]
    results = grade(folder, reference=reference, only=[vel, imp, EPISODE["velocity"]])
    assert _failed(results) == {vel, EPISODE["velocity"]}, pretty(results)


@pytest.mark.slow
def test_orientation_axis_left_in_L7_and_wrong_yaw_fail_their_unit_tests(
    tmp_path_factory, reference
):
    """Two frame mistakes: the velocity plan's axis n not re-expressed in W, and
    calc_R_WL7_ref turning the wrong way."""
    folder = _wrong_folder(
        tmp_path_factory,
        "frames",
        [
            (
                "manip_station_sim/robot_plans.py",
                "theta_n_W = self.R_WL7 @ (angle_axis.angle() * angle_axis.axis())\n        V_des",
                "theta_n_W = angle_axis.angle() * angle_axis.axis()\n        V_des",
            ),
            ("open_left_door.py", "yaw = -(angle_end", "yaw = (angle_end"),
        ],
    )
    vel = UNIT["IiwaTaskSpaceVelocityPlan.CalcPositionCommand"]
    only = [vel, UNIT["calc_R_WL7_ref"], UNIT["calc_p_Q"]]
    results = grade(folder, reference=reference, only=only)
    assert _failed(results) == {vel, UNIT["calc_R_WL7_ref"]}, pretty(results)
    assert "roll-pitch-yaw" in _output(results, UNIT["calc_R_WL7_ref"])


@pytest.mark.slow
def test_exception_and_nan_fail_only_their_tests(tmp_path_factory, reference):
    """The velocity plan returns NaN, the impedance plan divides by zero: their tests fail
    with the cause in the output; the grader and the other tests carry on."""
    folder = _wrong_folder(
        tmp_path_factory,
        "nan_and_exception",
        [
            (
                "manip_station_sim/robot_plans.py",
                "return q_iiwa + q_dot_des * control_period",
                "return q_iiwa + q_dot_des * control_period * np.nan",
            ),
            (
                "manip_station_sim/robot_plans.py",
                "return self.Jv_WL7q.T @ F",
                "return self.Jv_WL7q.T @ F * (1 // 0)",
            ),
        ],
    )
    vel = UNIT["IiwaTaskSpaceVelocityPlan.CalcPositionCommand"]
    imp = UNIT["IiwaTaskSpaceImpedancePlan.CalcTorqueCommand"]
    only = [vel, imp, UNIT["calc_p_Q"], EPISODE["velocity"]]
    results = grade(folder, reference=reference, only=only)
    assert _failed(results) == {vel, imp, EPISODE["velocity"]}, pretty(results)
    assert "nan" in _output(results, vel)
    assert "ZeroDivisionError" in _output(results, imp)
    assert "non-finite" in _output(results, EPISODE["velocity"])


@pytest.mark.slow
def test_an_endless_loop_hits_the_time_limit_only(tmp_path_factory):
    folder = _wrong_folder(
        tmp_path_factory,
        "endless",
        [
            (
                "open_left_door.py",
                "    yaw = -(angle_end",
                "    while True:\n        pass\n    yaw = -(angle_end",
            )
        ],
    )
    only = [UNIT["calc_R_WL7_ref"], UNIT["calc_p_Q"]]
    # Unit limit 60 s x 0.1 = 6 s of the test's own time (a loaded machine's wait for a CPU
    # is not counted: pset/rules/clock.py): a correct unit test takes well under a second (a
    # whole grading of the key, 8 tests, takes 3.2 s here).
    results = grade(folder, only=only, time_limit_scale=0.1)
    assert _failed(results) == {UNIT["calc_R_WL7_ref"]}, pretty(results)
    assert "time limit" in _output(results, UNIT["calc_R_WL7_ref"])


@pytest.mark.slow
def test_using_the_wrong_argument_fails_the_unit_test_naming_it(tmp_path_factory):
    """The inputs tell the arguments apart: the velocity plan starting from q_cmd instead of
    the measured q_iiwa, the impedance plan adding damping from v_iiwa, and the IK aiming
    doorlab's default grasp point instead of its p_L7Q argument each lose their unit test,
    whose message names the argument."""
    folder = _wrong_folder(
        tmp_path_factory,
        "wrong_arguments",
        [
            (
                "manip_station_sim/robot_plans.py",
                "return q_iiwa + q_dot_des * control_period",
                "return q_cmd + q_dot_des * control_period",
            ),
            (
                "manip_station_sim/robot_plans.py",
                "return self.Jv_WL7q.T @ F",
                "return self.Jv_WL7q.T @ F - 0.5 * np.asarray(v_iiwa)",
            ),
            (
                "ik_utils.py",
                "l7_frame, p_L7Q, world_frame",
                "l7_frame, __import__('doorlab.cell.frames').cell.frames.p_L7Q, world_frame",
            ),
        ],
    )
    vel = UNIT["IiwaTaskSpaceVelocityPlan.CalcPositionCommand"]
    imp = UNIT["IiwaTaskSpaceImpedancePlan.CalcTorqueCommand"]
    ik = UNIT["InverseKinPointwise"]
    results = grade(folder, only=[vel, imp, ik])
    assert _failed(results) == {vel, imp, ik}, pretty(results)
    velocity = _output(results, vel)
    assert "q_cmd + J^+ V_des dt: q_ref must start from the measured q_iiwa" in velocity
    assert "your answer depends on q_cmd (the last position command)" in velocity
    impedance = _output(results, imp)
    assert "your answer depends on v_iiwa (the measured joint velocities)" in impedance
    assert "use the p_L7Q argument" in _output(results, ik)


def test_the_folder_s_grader_with_a_python_lacking_doorlab_says_which_to_use(tmp_path):
    """`python3 test_pset_5a.py` with an interpreter that has no doorlab: one line naming
    it and what to do, exit 2, no traceback."""
    import venv

    bare = tmp_path / "bare"
    venv.create(bare, with_pip=False)
    folder = init_folder(tmp_path / "pset")
    proc = subprocess.run(
        [str(bare / "bin" / "python"), "test_pset_5a.py"],
        cwd=folder,
        env={"PATH": f"{Path(sys.executable).parent}{os.pathsep}/usr/bin:/bin"},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "has no doorlab" in lines[0] and str(bare / "bin" / "python") in lines[0]
    doorlab_command = Path(sys.executable).parent / "doorlab"
    if doorlab_command.exists():  # the interpreter of the `doorlab` on PATH is named
        assert f"run it with {doorlab_command.read_text().splitlines()[0][2:]}" in lines[0]
    assert not (folder / "test_results.json").exists()


def pretty(results: dict) -> str:
    return "\n".join(
        f"{t['name']}: {t['score']}/{t['max_score']}\n{t['output']}" for t in results["tests"]
    )


@pytest.mark.slow
def test_our_notebook_runs_in_the_solutions_folder(solutions_run):
    """The notebook `init` writes: every code cell but the last (the grader, run above) runs."""
    folder, _ = solutions_run
    notebook = json.loads((folder / "pset5_open_cabinet_door.ipynb").read_text())
    cells = ["".join(c["source"]) for c in notebook["cells"] if c["cell_type"] == "code"]
    assert "test_pset_5a" in cells[-1]
    cells_file = folder.parent / "our_cells.json"
    cells_file.write_text(json.dumps([pset_fixtures.strip_magics(c) for c in cells[:-1]]))
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=str(folder))
    proc = subprocess.run(
        [sys.executable, "-c", pset_fixtures.DRIVER, str(cells_file)],
        cwd=folder,
        env=env,
        capture_output=True,
        text=True,
        timeout=pset_fixtures.NOTEBOOK_CELLS_TIMEOUT_S,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "--- all cells ran" in proc.stdout


def test_the_notebooks_code_cells_are_read_from_an_ipynb_or_its_text(tmp_path, monkeypatch):
    """$DOORLAB_PSET5_NOTEBOOK may name the .ipynb or its text; unset, the tests skip and say
    how to run them; naming a missing file fails them."""
    ipynb = tmp_path / "pset5_open_cabinet_door.ipynb"
    ipynb.write_text(
        json.dumps(
            {
                "cells": [
                    {"cell_type": "markdown", "source": ["# prose"]},
                    {"cell_type": "code", "source": ["import math\n", "x = 1"]},
                    {"cell_type": "code", "source": ""},
                    {"cell_type": "code", "source": "%matplotlib inline\ny = 2"},
                ],
                "nbformat": 4,
            }
        )
    )
    text = tmp_path / "notebook.txt"
    text.write_text("Some prose.\n\nIn [ ]:\n\nimport math\nx = 1\n\nMore prose here.\n")
    monkeypatch.setenv(pset_fixtures.NOTEBOOK_ENV, str(ipynb))
    assert pset_fixtures.notebook_cells() == ["import math\nx = 1", "%matplotlib inline\ny = 2"]
    monkeypatch.setenv(pset_fixtures.NOTEBOOK_ENV, str(text))
    assert pset_fixtures.notebook_cells() == ["import math\nx = 1\n"]
    monkeypatch.delenv(pset_fixtures.NOTEBOOK_ENV)
    with pytest.raises(pytest.skip.Exception, match="DOORLAB_PSET5_NOTEBOOK"):
        pset_fixtures.notebook_cells()
    monkeypatch.setenv(pset_fixtures.NOTEBOOK_ENV, str(tmp_path / "missing.ipynb"))
    with pytest.raises(pytest.fail.Exception, match="missing.ipynb"):
        pset_fixtures.notebook_cells()
