"""Tests of ``doorlab.report``: the experiment set, the page built from run folders, run_report.

The page is built once per session from three real short runs plus a hand-written ``ik_failed``
folder (``report_fixtures.short_report``); ``run_report`` runs two tiny experiments over two
worker processes, one of them invalid.
"""

from __future__ import annotations

import html
import json
import math
import re
from pathlib import Path

import pytest
from dask_local import plain_cluster
from report_fixtures import (
    FAILED_ERROR,
    FAILED_RUN,
    SHORT_RUNS,
    short_experiment,
    short_report,
    short_scenario,
)

from doorlab.config import Scenario, validate
from doorlab.errors import ConfigError, OutputError
from doorlab.report import (
    EXPERIMENTS,
    QUESTIONS,
    format_number,
    make_experiments,
    run_report,
)

NUM_SPAN = re.compile(
    r'<span class="num" data-run="([^"]+)" data-key="([^"]+)"(?: data-unit="([^"]*)")?>'
    r"([^<]*)</span>"
)
UNIT_SCALE = {"mm": 1000.0, "deg": 180.0 / math.pi, "": 1.0}
"""Display scale of each unit the page uses for metrics (others are shown in SI)."""


@pytest.fixture(scope="module")
def report() -> tuple[Path, str, dict[str, dict]]:
    """(report folder, index.html text, metrics.json of every run by name)."""
    folder = short_report()
    page = (folder / "index.html").read_text(encoding="utf-8")
    metrics = {
        p.name: json.loads((p / "metrics.json").read_text())
        for p in (folder / "runs").iterdir()
        if (p / "metrics.json").is_file()
    }
    return folder, page, metrics


def answer(page: str, qid: str) -> str:
    """The HTML of one question's generated answer."""
    match = re.search(
        rf'<div class="answer" id="answer-{qid}">(.*?)</div></section>', page, flags=re.S
    )
    assert match, f"no answer block for {qid}"
    return match.group(1)


def printed_tolerance(text: str) -> float:
    """Half a unit in the last printed digit of a number like '37.7' or '1230'."""
    if "." in text:
        return 0.5 * 10 ** -len(text.split(".")[1])
    digits = len(text.lstrip("-"))
    return 0.5 * 10 ** max(digits - 3, 0)


def test_experiments_are_the_problem_sets_set():
    """EXPERIMENTS holds the problem set's eight runs with the right controller, doors and knots,
    then diffik's and osc's, doors open and closed."""
    expected = {
        "ik_2_open": ("ik", "open", 2),
        "ik_5_open": ("ik", "open", 5),
        "ik_10_open": ("ik", "open", 10),
        "ik_10_closed": ("ik", "closed", 10),
        "velocity_open": ("velocity", "open", None),
        "velocity_closed": ("velocity", "closed", None),
        "impedance_open": ("impedance", "open", None),
        "impedance_closed": ("impedance", "closed", None),
        "diffik_open": ("diffik", "open", None),
        "diffik_closed": ("diffik", "closed", None),
        "osc_open": ("osc", "open", None),
        "osc_closed": ("osc", "closed", None),
    }
    assert [name for name, _ in EXPERIMENTS] == list(expected)
    for name, scenario in EXPERIMENTS:
        controller, doors, knots = expected[name]
        validate(scenario)
        assert (scenario.controller, scenario.doors) == (controller, doors)
        if knots is not None:
            assert scenario.ik.knots == knots


def test_make_experiments_keeps_the_base_physics():
    """Every experiment copies the base's physics and timeline; door_angles defer to doors."""
    base = Scenario()
    base.station.time_step = 0.001
    base.timeline.arc_duration = 7.0
    base.door_angles = [-0.3, 0.3]
    experiments = make_experiments(base)
    for _, scenario in experiments:
        assert scenario.station.time_step == 0.001
        assert scenario.timeline.arc_duration == 7.0
        assert scenario.door_angles is None
    assert base.door_angles == [-0.3, 0.3]  # the base is not modified
    assert len({id(s) for _, s in experiments}) == len(experiments)


def test_format_number_gives_three_significant_digits():
    """Numbers print with 3 significant digits, no exponent, trailing zeros kept."""
    assert format_number(37.416) == "37.4"
    assert format_number(1.1) == "1.10"
    assert format_number(0.0823456) == "0.0823"
    assert format_number(1234.5) == "1230"
    assert format_number(0.0) == "0"
    assert format_number(float("nan")) == "n/a"
    assert format_number(None) == "n/a"


@pytest.mark.slow
def test_page_embeds_every_image_and_fetches_nothing(report):
    """Every <img> is a base64 PNG data URI; no URL, script or external stylesheet."""
    _, page, _ = report
    images = re.findall(r"<img\b[^>]*>", page)
    assert len(images) >= 8
    for tag in images:
        assert '<img src="data:image/png;base64,' in tag
    assert "http://" not in page and "https://" not in page
    assert "<script" not in page.lower()
    assert '<link rel="stylesheet"' not in page


@pytest.mark.slow
def test_metrics_table_has_one_row_per_run_with_units(report):
    """The metrics table has one row per run folder and units in its headers."""
    folder, page, metrics = report
    table = re.search(r'<table id="metrics-table">(.*?)</table>', page, flags=re.S).group(1)
    rows = re.findall(r'<tr data-run="([^"]+)"', table)
    assert sorted(rows) == sorted(metrics) and len(rows) == len(SHORT_RUNS) + 1
    headers = re.findall(r"<th[^>]*>([^<]*)</th>", table)
    for unit_header in (
        "max radial error [mm]",
        "max orientation error [deg]",
        "peak external torque [N m]",
        "max joint speed [rad/s]",
        "sim time [s]",
    ):
        assert unit_header in headers
    summary = json.loads((folder / "summary.json").read_text())
    assert [r["name"] for r in summary["runs"]] == [SHORT_RUNS[0], FAILED_RUN, *SHORT_RUNS[1:]]


def test_failed_run_appears_with_status_and_error(report):
    """A folder whose metrics.json says ik_failed is listed as failed with its message."""
    _, page, _ = report
    row = re.search(rf'<tr data-run="{FAILED_RUN}" class="failed">(.*?)</tr>', page, flags=re.S)
    assert row, "the ik_failed run has no failed row in the metrics table"
    assert "ik_failed" in row.group(1)
    assert html.escape(FAILED_ERROR) in row.group(1)
    assert f"<code>{FAILED_RUN}</code> produced no logs" in answer(page, "t1q1")


def test_answers_print_the_metrics_of_the_folders(report):
    """Every metric quoted in an answer equals metrics.json to the printed precision."""
    _, page, metrics = report
    checked = 0
    for qid, _, _ in QUESTIONS:
        for run, key, unit, text in NUM_SPAN.findall(answer(page, qid)):
            value_text = text.removesuffix(f" {unit}").strip() if unit else text.strip()
            expected = metrics[run][key] * UNIT_SCALE.get(unit, 1.0)
            assert abs(float(value_text) - expected) <= printed_tolerance(value_text) * 1.001, (
                qid,
                run,
                key,
                text,
                expected,
            )
            checked += 1
    assert checked >= 15


def test_answers_exist_for_the_questions_with_data(report):
    """Questions whose runs exist get numbers; those without say which runs are missing."""
    _, page, metrics = report
    ik2 = metrics["ik_2_open"]
    t1q1 = answer(page, "t1q1")
    assert f"{format_number(ik2['max_radial_error_m'] * 1000)} mm" in t1q1
    t2q1 = answer(page, "t2q1")
    assert 'data-run="velocity_open" data-key="max_radial_error_m"' in t2q1
    assert 'data-run="ik_2_open" data-key="max_radial_error_m"' in t2q1
    velocity, ik = (metrics[n]["max_radial_error_m"] for n in ("velocity_open", "ik_2_open"))
    # The comparison follows the numbers' actual order, and a contradiction is said plainly.
    assert ("times smaller than" in t2q1) == (velocity < ik)
    assert ("contradicts the problem set" in t2q1) == (velocity >= ik)
    t2q2 = answer(page, "t2q2")
    assert 'data-run="velocity_closed" data-key="door_opening_arc_end_rad"' in t2q2
    for qid in ("t3q1", "t3q2"):
        assert "<code>impedance_open</code> was not run" in answer(page, qid)


def test_page_quotes_the_six_questions_and_links_the_runs(report):
    """The page quotes each seed question and links each run's folder and its replay."""
    _, page, _ = report
    for _, _, question in QUESTIONS:
        assert html.escape(question) in page
    for name in SHORT_RUNS:
        assert f'href="runs/{name}/"' in page
    assert f'href="runs/{SHORT_RUNS[-1]}/replay.html"' in page


@pytest.mark.slow
def test_run_report_reports_a_failed_experiment_and_keeps_the_others(tmp_path: Path):
    """jobs=2 with one invalid experiment: exit 1, an error row, the valid run still written."""
    broken = short_scenario()
    broken.controller = "teleport"  # rejected by validate() inside the worker
    experiments = [short_experiment("velocity_open"), ("broken", broken)]
    out = tmp_path / "report"
    code = run_report(
        out, jobs=2, experiments=experiments, progress=False, robustness=False, arm=False
    )
    assert code == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]
    good = json.loads((out / "runs" / "velocity_open" / "metrics.json").read_text())
    assert good["status"] in ("ok", "slipped", "speed_limit")
    assert (out / "runs" / "velocity_open" / "log.npz").is_file()
    bad = json.loads((out / "runs" / "broken" / "metrics.json").read_text())
    assert bad["status"] == "error" and "teleport" in bad["error"]
    page = (out / "index.html").read_text(encoding="utf-8")
    assert re.search(r'<tr data-run="broken" class="failed">', page)
    summary = json.loads((out / "summary.json").read_text())
    assert {r["name"]: r["status"] for r in summary["runs"]}["broken"] == "error"
    assert (out / "figures").is_dir()

    with pytest.raises(OutputError, match="already exists"):
        run_report(out, jobs=1, experiments=[], progress=False, robustness=False, arm=False)


def test_run_report_rejects_bad_arguments(tmp_path: Path):
    """jobs < 1 and duplicate experiment names raise ConfigError before anything is written."""
    with pytest.raises(ConfigError, match="jobs"):
        run_report(
            tmp_path / "a", jobs=0, experiments=[], progress=False, robustness=False, arm=False
        )
    twice = [short_experiment("velocity_open"), short_experiment("velocity_open")]
    with pytest.raises(ConfigError, match="unique"):
        run_report(
            tmp_path / "b", jobs=1, experiments=twice, progress=False, robustness=False, arm=False
        )
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_run_report_on_a_dask_cluster(tmp_path: Path):
    """run_report through a real Dask LocalCluster (one worker process on loopback): the worker
    ships the run folder back, so the report holds the same files as a local run writes."""
    pytest.importorskip("distributed")
    experiments = [short_experiment("ik_2_open")]
    out = tmp_path / "report"
    with plain_cluster(1) as cluster:
        address = cluster.scheduler_address
        code = run_report(
            out,
            jobs=1,
            experiments=experiments,
            progress=False,
            scheduler=address,
            robustness=False,
            arm=False,
        )
    folder = out / "runs" / "ik_2_open"
    metrics = json.loads((folder / "metrics.json").read_text())
    assert code == (0 if metrics["status"] == "ok" else 1)
    assert metrics["controller"] == "ik" and metrics["knots"] == 2
    names = {p.name for p in folder.iterdir()}
    assert {"metrics.json", "log.npz", "scenario.yaml", "replay.html"} <= names
    assert any(name.endswith(".png") for name in names)
    assert 'href="runs/ik_2_open/replay.html"' in (out / "index.html").read_text()
