"""Tests of the report's robustness section: the grid of cases, the section built from small
run folders (``report_fixtures.robustness_report``: one reused short run, one short adaptive
run, one hand-written failure), the exit code and ``doorlab report --robustness``.

The short runs are structure fixtures: their doors need not open (the arc lasts 2 s), so the
tests check that the page prints what the folders hold, not the physics of the full runs.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest
from report_fixtures import FAILED_ERROR, ROBUST_YAW_DEG, robustness_report, short_scenario

from doorlab.config import Scenario
from doorlab.episode.controllers import REGISTRY
from doorlab.report import make_experiments, make_robustness_cases, run_report
from doorlab.studies.robustness import ACCEPTANCE_YAW_ERRORS_DEG


def _section(page: str) -> str:
    match = re.search(r'<section id="robustness">(.*?)</section>', page, flags=re.S)
    assert match, "no robustness section"
    return match.group(1)


def test_robustness_cases_cover_the_registry_and_reuse_identical_runs():
    """Every registry controller on every acceptance yaw error, doors closed; the problem set's
    closed-door runs are reused at yaw 0 and nothing else is run twice."""
    experiments = make_experiments()
    cases, new = make_robustness_cases(None, experiments)
    assert [(c.controller, round(math.degrees(c.yaw_error_rad), 9)) for c in cases] == [
        (name, y) for name in REGISTRY for y in ACCEPTANCE_YAW_ERRORS_DEG
    ]
    at_zero = {c.controller: c.run for c in cases if c.yaw_error_rad == 0.0}
    assert at_zero["ik"] == "ik_10_closed"
    assert at_zero["velocity"] == "velocity_closed"
    assert at_zero["impedance"] == "impedance_closed"
    seed = dict(experiments)
    reused = [c for c in cases if c.run in seed]
    assert len(new) == len(cases) - len(reused)
    names = [name for name, _ in new]
    assert len(set(names)) == len(names) and not set(names) & set(seed)
    by_name = dict(new)
    for case in cases:
        scenario = by_name.get(case.run, seed.get(case.run))
        assert scenario.controller == case.controller and scenario.doors == "closed"
        assert scenario.station.cupboard_yaw_error == pytest.approx(case.yaw_error_rad)


def test_robustness_cases_keep_the_base_physics():
    base = Scenario()
    base.station.time_step = 5e-4
    _, new = make_robustness_cases(base, ())
    assert all(s.station.time_step == 5e-4 for _, s in new)


@pytest.mark.slow
def test_section_prints_the_folders_metrics_and_embeds_its_figures():
    """One table row per case with the run's own numbers, both figures embedded and saved,
    a finding per controller, the failed run's status; the section's runs stay out of the
    seed's runs table."""
    folder, grid = robustness_report()
    page = (folder / "index.html").read_text(encoding="utf-8")
    section = _section(page)
    assert "TRUE" in section and "BELIEVED" in section and "exit code" in section
    rows = re.findall(r'<tr data-run="([^"]+)"[^>]*>(.*?)</tr>', section, flags=re.S)
    assert [name for name, _ in rows] == [case.run for case, _ in grid]
    for (case, record), (_, row) in zip(grid, rows, strict=True):
        cells = re.findall(r"<td[^>]*>(.*?)</td>", row, flags=re.S)
        assert case.controller in cells[1]
        assert float(cells[2]) == pytest.approx(math.degrees(case.yaw_error_rad), abs=0.05)
        metrics = json.loads((Path(record.run_dir) / "metrics.json").read_text())
        assert cells[3] == metrics["status"]
        if "door_opening_arc_end_rad" in metrics:
            shown = float(cells[4].split("/")[0])
            assert shown == pytest.approx(
                math.degrees(metrics["door_opening_arc_end_rad"]), abs=0.05
            )
            assert float(cells[6]) == pytest.approx(
                metrics["peak_external_torque_arc_Nm"], abs=0.005
            )
        else:
            assert cells[4].startswith("-")
    adaptive = json.loads((Path(grid[2][1].run_dir) / "metrics.json").read_text())
    if adaptive.get("hinge_estimate_error_m") is not None:
        assert f"{1e3 * adaptive['hinge_estimate_error_m']:.1f}" in rows[2][1]
    images = re.findall(r'<img src="data:image/png;base64,', section)
    assert len(images) == 2
    assert (folder / "figures" / "robustness.png").is_file()
    assert (folder / "figures" / "hinge_convergence.png").is_file()
    findings = re.findall(r"<li>(.*?)</li>", section, flags=re.S)
    assert [f.split(":")[0] for f in findings] == ["ik", "velocity", "adaptive"]
    assert "ik_failed" in findings[0] and f"{ROBUST_YAW_DEG:+.0f}" in findings[2]
    runs_table = re.search(r'<table id="runs-table">(.*?)</table>', page, flags=re.S).group(1)
    assert "robust_" not in runs_table
    assert "3 (2 runs of their own, 1 shared" in page
    summary = json.loads((folder / "summary.json").read_text())
    assert [r["run"] for r in summary["robustness"]] == [c.run for c, _ in grid]
    assert FAILED_ERROR not in section  # the table shows the status; the run folder the error


@pytest.mark.slow
def test_failing_robustness_runs_do_not_fail_the_report(tmp_path: Path, monkeypatch):
    """A robustness run that fails (here: rejected by validate() in the worker) shows in the
    section and leaves the exit code at 0; robustness=False writes no section."""
    from doorlab.report import RobustnessCase, runner

    broken = short_scenario()
    broken.controller = "teleport"
    case = RobustnessCase("robust_broken", "velocity", math.radians(5.0))
    monkeypatch.setattr(
        runner,
        "make_robustness_cases",
        lambda base, given, **_: ((case,), (("robust_broken", broken),)),
    )
    out = tmp_path / "with"
    assert run_report(out, jobs=1, experiments=[], progress=False, robustness=True) == 0
    section = _section((out / "index.html").read_text(encoding="utf-8"))
    assert re.search(r'<tr data-run="robust_broken" class="warn">.*?error', section, re.S)
    assert (
        json.loads((out / "runs" / "robust_broken" / "metrics.json").read_text())["status"]
        == "error"
    )

    out = tmp_path / "without"  # the default: no robustness section
    assert run_report(out, jobs=1, experiments=[], progress=False) == 0
    page = (out / "index.html").read_text(encoding="utf-8")
    assert 'id="robustness"' not in page
    assert "robustness" not in json.loads((out / "summary.json").read_text())


def test_cli_sections_reach_run_report(tmp_path: Path, monkeypatch, capsys):
    """``doorlab report`` runs neither the robustness nor the "On the arm" section unless asked:
    ``--robustness`` asks run_report for the robustness runs, ``--arm`` for the runs on the arm
    with the band of arm models, ``--arm --no-arm-band`` for the arm without the band (and
    ``--no-arm-band`` alone is one line, exit 2); --help names the flags."""
    import doorlab.report
    from doorlab.cli.parser import main

    calls, arms, bands = [], [], []

    def fake(out, **kwargs):
        calls.append(kwargs["robustness"])
        arms.append(kwargs["arm"])
        bands.append(kwargs["arm_band"])
        return 0

    monkeypatch.setattr(doorlab.report, "run_report", fake)
    assert main(["report", "--out", str(tmp_path / "a"), "--robustness"]) == 0
    assert main(["report", "--out", str(tmp_path / "b")]) == 0
    assert main(["report", "--out", str(tmp_path / "c"), "--arm"]) == 0
    assert main(["report", "--out", str(tmp_path / "d"), "--arm", "--no-arm-band"]) == 0
    assert main(["report", "--out", str(tmp_path / "e"), "--no-robustness", "--no-arm"]) == 0
    assert calls == [True, False, False, False, False]
    assert arms == [False, False, True, True, False]
    assert bands == [True, True, True, False, True]
    capsys.readouterr()
    assert main(["report", "--out", str(tmp_path / "f"), "--no-arm-band"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--arm" in err[0]
    assert main(["report", "--help"]) == 0
    help_text = capsys.readouterr().out
    assert "--robustness" in help_text and "--arm" in help_text
    assert "--no-arm-band" in help_text
