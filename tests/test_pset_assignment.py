"""The assignment file (points, margins, visibility, seed, helpers) and reproducible gradings.

The verdicts under changed settings are checked on the judges with figures given here (the
margins are pure arithmetic); what has to run is run with the session's reference episodes
(``pset_fixtures``) and only the tests a case needs: the untouched stubs through the CLI
(their jobs fail at once), the unit tests alone for the seeds, one IK episode for a margin.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import replace
from pathlib import Path

import pset_fixtures
import pytest

from doorlab.cli.parser import main
from doorlab.pset.classroom import gradescope
from doorlab.pset.grading.grader import TESTS, grade
from doorlab.pset.grading.scoring import results_from_jobs
from doorlab.pset.handout.folder import STUDENT_FILES, init_folder
from doorlab.pset.rules.assignment import (
    Assignment,
    assignment_yaml,
    files_digest,
    grading_seed,
    load_assignment,
    parse_assignment,
)

UNITS = [t.name for t in TESTS if "unit test" in t.name]
IK_EPISODE = next(t.name for t in TESTS if t.key == "ik_episode")


@pytest.fixture(scope="module")
def reference() -> dict:
    return pset_fixtures.reference()


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


# The file ----------------------------------------------------------------------------------


def test_the_default_file_round_trips_and_is_never_overwritten(tmp_path, capsys):
    out = tmp_path / "assignment.yaml"
    assert main(["pset", "assignment", str(out)]) == 0
    loaded = load_assignment(out)
    assert loaded.tests == Assignment().tests and loaded.visibility == "visible"
    assert 0 <= loaded.seed < 2**32
    again = tmp_path / "again.yaml"
    assert main(["pset", "assignment", str(again)]) == 0
    assert load_assignment(again).seed != loaded.seed  # a fresh seed per course
    capsys.readouterr()
    before = out.read_text()
    assert main(["pset", "assignment", str(out)]) == 2
    err = capsys.readouterr().err
    assert "already exists" in err and len(err.strip().splitlines()) == 1
    assert out.read_text() == before
    # Every field written is read back as written.
    changed = replace(Assignment(seed=7), visibility="after_published")
    changed.tests.ik_episode.radial_margin = 0.0015
    assert parse_assignment(assignment_yaml(changed)) == changed


@pytest.mark.parametrize(
    "text, needle",
    [
        ("tests: {ik_unit: {points: many}}", "tests.ik_unit.points must be a number"),
        ("tests: {ik_unit: {pointz: 1}}", "unknown field 'tests.ik_unit.pointz'"),
        ("visibility: secret", "visibility must be one of visible, hidden, after_due_date"),
        ("tests: {velocity_episode: {helpers: mine}}", "helpers must be one of reference"),
        ("tests: {impedance_episode: {door_opening_margin_deg: -1}}", "in [0, 90]"),
        ("seed: -3", "seed must be an integer"),
        ("seed: &a 1\nvisibility: *a", "are not accepted"),
        ("- 1", "the assignment must be a mapping"),
    ],
)
def test_a_bad_field_is_a_one_line_error_before_any_grading(tmp_path, capsys, text, needle):
    folder = init_folder(tmp_path / "stubs")
    bad = _write(tmp_path / "bad.yaml", text)
    for argv in (
        ["pset", "grade", str(folder), "--assignment", str(bad)],
        ["pset", "autograder", str(tmp_path / "ag.zip"), "--assignment", str(bad)],
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert needle in err and "bad.yaml" in err, err
        assert len(err.strip().splitlines()) == 1, err
    assert not (folder / "test_results.json").exists()
    assert not (tmp_path / "ag.zip").exists()


# Points, margins and visibility ------------------------------------------------------------


def _figures(**overrides) -> dict:
    base = {
        "max_radial_error_m": 0.0012,
        "max_orientation_error_rad": 0.009,
        "q_end_angle_rad": 0.87,
        "door_opening_at_arc_end_rad": 0.55,
        "theta0_rad": 0.15,
        "handle_held": True,
    }
    return {"figures": base | overrides}


def test_margins_and_points_change_the_verdicts():
    """The same figures judged under two assignments: a tighter margin fails what the
    default passes, more points count more, and the message states the margin used."""
    jobs = {
        "reference:ik": _figures(),
        "student:ik": _figures(max_radial_error_m=0.0030),  # 1.8 mm over the reference
        "reference:impedance": _figures(),
        "student:impedance": _figures(door_opening_at_arc_end_rad=0.55 - 0.06),  # 3.4 deg
    }
    specs = [t for t in TESTS if t.key in ("ik_episode", "impedance_episode")]
    default = results_from_jobs(specs, jobs, 1.0)
    assert [t["score"] for t in default["tests"]] == [2.0, 2.0]
    strict = Assignment()
    strict.tests.ik_episode.radial_margin = 0.001
    strict.tests.ik_episode.points = 5.0
    strict.tests.impedance_episode.door_opening_margin_deg = 3.0
    results = results_from_jobs(specs, jobs, 1.0, strict)
    assert [(t["score"], t["max_score"]) for t in results["tests"]] == [(0.0, 5.0), (0.0, 2.0)]
    assert [t["status"] for t in results["tests"]] == ["failed", "failed"]
    assert "+ 1.00 mm" in results["tests"][0]["output"]
    assert "margin 3.00 deg" in results["tests"][1]["output"]


@pytest.mark.slow
def test_points_visibility_and_seed_reach_results_json(tmp_path, reference, capsys):
    """`doorlab pset grade --assignment` on the stubs (reference reused): every test's points
    and visibility, the top-level visibility, plain text, numbers; `--seed` is recorded."""
    text = (
        "visibility: after_due_date\n"
        "tests:\n"
        "  ik_unit: {visibility: hidden, points: 0}\n"
        "  ik_episode: {points: 3.5, visibility: after_published}\n"
    )
    settings = _write(tmp_path / "course.yaml", text)
    earlier = _write(
        tmp_path / "earlier.json", json.dumps({"extra_data": {"reference": reference}})
    )
    folder = init_folder(tmp_path / "stubs")
    argv = ["pset", "grade", str(folder), "--assignment", str(settings)]
    assert main([*argv, "--reference", str(earlier), "--seed", "123"]) == 0
    capsys.readouterr()
    results = json.loads((folder / "test_results.json").read_text())
    assert results["visibility"] == "after_due_date"
    assert results["output_format"] == results["test_output_format"] == "text"
    tests = {t["name"]: t for t in results["tests"]}
    ik_unit = tests[next(t.name for t in TESTS if t.key == "ik_unit")]
    assert (ik_unit["visibility"], ik_unit["max_score"]) == ("hidden", 0.0)
    assert (tests[IK_EPISODE]["visibility"], tests[IK_EPISODE]["max_score"]) == (
        "after_published",
        3.5,
    )
    assert results["extra_data"]["max_score"] == sum(t.max_score for t in TESTS) - 2 + 1.5
    assert all(t["status"] == "failed" and t["score"] == 0 for t in results["tests"])
    assert [t["number"] for t in results["tests"]] == [t.number for t in TESTS]
    assert results["extra_data"]["seed"]["grading"] == 123
    assert "grading seed 123" in results["output"]


def test_a_changed_margin_or_points_changes_the_zip_and_its_digest(tmp_path):
    def digest(assignment) -> tuple[str, bytes]:
        out = gradescope.write_autograder(tmp_path / "ag.zip", assignment=assignment, force=True)
        with zipfile.ZipFile(out) as archive:
            settings = json.loads(archive.read(gradescope.SETTINGS_NAME))
            return settings["digest"], archive.read(gradescope.ASSIGNMENT_NAME)

    base, base_text = digest(None)
    assert digest(Assignment()) == (base, base_text)  # no file: the defaults
    margin = Assignment()
    margin.tests.velocity_episode.orientation_margin = 0.02
    points = Assignment()
    points.tests.calc_p_Q_unit.points = 2.0
    digests = {base, digest(margin)[0], digest(points)[0], digest(Assignment(seed=1))[0]}
    assert len(digests) == 4
    assert parse_assignment(digest(margin)[1].decode()) == margin  # the zip grades with it


@pytest.mark.slow
def test_a_margin_from_the_file_reaches_the_episode_s_verdict(tmp_path, reference):
    """The key's IK episode passes with the default margin and fails with none: its
    feasible IK (any pose within the +-1 mm box) errs more than the reference's along the
    arc, which the default 2.83 mm allows (the message states the margin it used)."""
    folder = init_folder(tmp_path / "key", solutions=True)
    strict = Assignment()
    strict.tests.ik_episode.radial_margin = 0.0
    results = grade(folder, reference=reference, only=[IK_EPISODE], assignment=strict)
    (test,) = results["tests"]
    assert test["score"] == 0 and "+ 0.00 mm" in test["output"], test["output"]
    assert "FAILED max radial error" in test["output"]


# Reproducible grading ----------------------------------------------------------------------


def _wrong_key(folder: Path) -> Path:
    """The key with calc_p_Q absolute and the velocity plan's error sign flipped: unit tests
    whose outputs show the drawn inputs."""
    init_folder(folder, solutions=True)
    edits = [
        ("open_left_door.py", "return p_WQ - p_WC_handle", "return p_WQ"),
        (
            "manip_station_sim/robot_plans.py",
            "V_des = np.concatenate([50.0 * theta_n_W, 100.0 * err_xyz])",
            "V_des = np.concatenate([50.0 * theta_n_W, -100.0 * err_xyz])",
        ),
    ]
    for rel, old, new in edits:
        path = folder / rel
        path.write_text(path.read_text().replace(old, new))
    return folder


def _without_times(data):
    if isinstance(data, dict):
        return {
            k: _without_times(v)
            for k, v in data.items()
            if k not in ("execution_time", "seconds", "wall_time_s")
        }
    if isinstance(data, list):
        return [_without_times(v) for v in data]
    return data


@pytest.mark.slow
def test_the_same_submission_grades_the_same_and_a_seed_replays(tmp_path):
    """Graded twice: the same results but for times. The same files with a comment added
    draw other inputs, and `seed=` (--seed) replays the first grading's exactly."""
    course = Assignment(seed=20190501)
    folder = _wrong_key(tmp_path / "wrong")
    first = grade(folder, only=UNITS, assignment=course)
    second = grade(folder, only=UNITS, assignment=course)
    assert _without_times(first) == _without_times(second)
    digest = files_digest(folder, STUDENT_FILES)
    seed = first["extra_data"]["seed"]
    assert seed == {
        "grading": grading_seed(course.seed, digest),
        "source": "from the assignment's random seed and your files' SHA-256",
        "files_sha256": digest,
    }
    failed = {t["name"] for t in first["tests"] if t["score"] == 0}
    assert failed == {UNITS[1], UNITS[3]}  # calc_p_Q, CalcPositionCommand
    for t in first["tests"]:
        assert f"grading seed {seed['grading']}" in t["output"], t

    edited = _wrong_key(tmp_path / "edited")
    path = edited / "ik_utils.py"
    path.write_text(path.read_text() + "\n# a comment\n")
    other = grade(edited, only=UNITS[1:2], assignment=course)
    assert other["extra_data"]["seed"]["grading"] != seed["grading"]
    assert other["tests"][0]["output"] != first["tests"][1]["output"]  # other draws
    replayed = grade(edited, only=UNITS, assignment=course, seed=seed["grading"])
    assert replayed["extra_data"]["seed"]["source"] == "given with --seed"
    assert _without_times(replayed["tests"]) == _without_times(first["tests"])
