"""The report's comparison beyond the problem set (diffik and osc against the problem set's three)
and the answers as data (:mod:`doorlab.report.prose`) rendered by the templates.

The section is built once per module from short real runs (a 2 s arc): diffik open and closed,
osc and the impedance plan open, here, and the shared fixture's velocity runs
(``report_fixtures``). The numbers are checked against the run folders, in the page and in the
answer's data alike; the physics of the full runs is the report's (``doorlab report``) and
tests/test_controllers.py's.
"""

from __future__ import annotations

import functools
import json
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from report_fixtures import _root, short_experiment, short_run_folders

from doorlab.outputs.pages import Figures, format_number, render_macro
from doorlab.report.beyond import COLUMNS, SCALED_BELOW, comparison_context, run_name
from doorlab.report.prose import Num, Paragraph, code, number, para, strong, sub

UNIT_SCALE = {"mm": 1000.0, "deg": 180.0 / math.pi, "N m": 1.0, "": 1.0}
SPAN = re.compile(
    r'<span class="num" data-run="([^"]+)" data-key="([^"]+)"(?: data-unit="([^"]*)")?>'
    r"([^<]*)</span>"
)
OWN_RUNS = ("diffik_open", "diffik_closed", "osc_open", "impedance_open")
"""The short runs this module adds to the shared fixture's (velocity, open and closed)."""


def printed_tolerance(text: str) -> float:
    """Half a unit in the last printed digit (3 significant digits)."""
    if "." in text:
        return 0.5 * 10 ** -len(text.split(".")[1])
    return 0.5 * 10 ** max(len(text.lstrip("-")) - 3, 0)


@functools.cache
def beyond_report() -> Path:
    from doorlab.outputs.runs import run_to_folder
    from doorlab.report import RunRecord, build_page

    shared = short_run_folders()
    report_dir = _root() / "beyond"
    runs = report_dir / "runs"
    runs.mkdir(parents=True)
    for name in ("velocity_open", "velocity_closed"):
        shutil.copytree(shared[name], runs / name)
    for name in OWN_RUNS:
        _, scenario = short_experiment(name)
        run_to_folder(scenario, runs / name, replay=False, plots=False)
    order = ["velocity_open", "velocity_closed", *OWN_RUNS]
    build_page([RunRecord(n, runs / n) for n in order], report_dir, total_wall_time_s=1.0, jobs=1)
    return report_dir


@pytest.fixture(scope="module")
def report():
    folder = beyond_report()
    page = (folder / "index.html").read_text(encoding="utf-8")
    metrics = {
        p.name: json.loads((p / "metrics.json").read_text()) for p in (folder / "runs").iterdir()
    }
    match = re.search(r'<section id="beyond">(.*?)</section>', page, flags=re.S)
    assert match, "no comparison section"
    return folder, match.group(1), metrics


def _check(run: str, key: str, text: str, metrics: dict) -> None:
    value = float(text)
    unit = {"_m": "mm", "_rad": "deg", "_Nm": "N m"}
    scale = next((UNIT_SCALE[u] for s, u in unit.items() if key.endswith(s)), 1.0)
    expected = metrics[run][key] * scale
    assert abs(value - expected) <= printed_tolerance(text) * 1.001, (run, key, text, expected)


@pytest.mark.slow
def test_the_table_prints_each_runs_metrics(report):
    """A row per run of the comparison the report has (IK, velocity, impedance, diffik, osc;
    open, closed), in that order, each cell its folder's metric to the printed precision."""
    _, section, metrics = report
    table = re.search(r'<table id="beyond-table">(.*?)</table>', section, flags=re.S).group(1)
    rows = re.findall(r'<tr data-run="([^"]+)"', table)
    expected = [
        run_name(c, d)
        for c in ("ik", "velocity", "impedance", "diffik", "osc")
        for d in ("open", "closed")
        if run_name(c, d) in metrics
    ]
    assert rows == expected
    cells = SPAN.findall(table)
    assert len(cells) == len(rows) * len(COLUMNS)
    for run, key, _, text in cells:
        if text == "n/a":
            assert metrics[run].get(key) is None
        else:
            _check(run, key, text, metrics)


@pytest.mark.slow
def test_the_answer_states_the_folders_metrics(report):
    """Every number of the generated answer tied to a run equals its metrics.json; the
    comparisons' words follow the numbers' order."""
    _, section, metrics = report
    answer = re.search(r'<div class="answer" id="answer-beyond">(.*?)</div>', section, re.S)
    text = answer.group(1)
    spans = SPAN.findall(text)
    assert len(spans) >= 12
    for run, key, unit, shown in spans:
        _check(run, key, shown.removesuffix(f" {unit}") if unit else shown, metrics)
    osc, imp = (metrics[n]["max_radial_error_m"] for n in ("osc_open", "impedance_open"))
    word = "smaller" if osc < imp else "larger"
    assert re.search(rf"osc_open.*?times {word} than the impedance plan", text, re.S)
    assert "diffik against the velocity plan" in text and "osc against the impedance plan" in text


@pytest.mark.slow
def test_the_qp_sentence_follows_diffiks_log(report):
    """ "never bound" exactly when diffik's QP kept all of V_des at every tick of the arc (its plan
    log's scale), else the count of the ticks it scaled V_des down."""
    from doorlab.episode.result import EpisodeResult

    folder, section, _ = report
    result = EpisodeResult.load(folder / "runs" / "diffik_open" / "log.npz")
    t0, t1 = result.arc_window
    log = result.plan_log
    in_arc = (log["t"] >= t0) & (log["t"] <= t1)
    scale = log["scale"][in_arc]
    scaled = int(np.sum(scale[np.isfinite(scale)] < SCALED_BELOW))
    text = re.sub(r"<[^>]+>", "", section)
    if scaled == 0:
        assert "never bound along this arc" in text
        assert f"at none of its {int(np.sum(np.isfinite(scale)))} ticks" in text
    else:
        assert f"down at {scaled} of its" in text


@pytest.mark.slow
def test_the_answer_is_data_whose_facts_are_the_metrics(report):
    """The section's answer as data (no HTML): each fact tied to a run carries the value
    metrics.json has, in the unit shown; summary.json lists the table in SI units."""
    from doorlab.episode.metrics import Kinematics
    from doorlab.report import RunRecord
    from doorlab.report.context import AnswerPage
    from doorlab.report.folders import load_run

    folder, _, metrics = report
    loaded = [
        load_run(RunRecord(n, folder / "runs" / n), Kinematics())
        for n in ("velocity_open", "velocity_closed", *OWN_RUNS)
    ]
    page = AnswerPage(loaded, Figures(folder / "figures_again"))
    comparison = comparison_context(page, folder)
    facts = [f for f in comparison.answer.facts if f.run]
    assert facts and all(isinstance(p, Paragraph) for p in comparison.answer.paragraphs)
    for fact in facts:
        scale = {"mm": 1000.0, "deg": 180.0 / math.pi}.get(fact.unit, 1.0)
        assert fact.value == pytest.approx(metrics[fact.run][fact.key] * scale, rel=1e-12)
        assert fact.text == format_number(fact.value)
    summary = json.loads((folder / "summary.json").read_text())["beyond"]
    assert [r["run"] for r in summary["rows"]] == [row.run for row in comparison.rows]
    for row in summary["rows"]:
        for key, _ in COLUMNS:
            assert row[key] == metrics[row["run"]].get(key)
    paragraphs = comparison.answer.paragraphs
    assert summary["answer_markdown"] == [p.markdown for p in paragraphs]
    assert all(f.shown in p.markdown for p in paragraphs for f in p.facts)


@pytest.mark.slow
def test_the_section_embeds_its_figures(report):
    """Radial and orientation errors, doors open and closed; the door angle and the contact
    torques, doors closed: six figures, embedded and saved."""
    folder, section, _ = report
    assert section.count('src="data:image/png;base64,') == 6
    for name in (
        "beyond_open_radial_error",
        "beyond_closed_orientation_error",
        "beyond_closed_door_angle",
        "beyond_closed_external_torque_norm",
    ):
        assert (folder / "figures" / f"{name}.png").is_file()


def test_a_page_without_diffik_or_osc_has_no_section():
    """The problem set's runs alone (the shared fixture's short report): no comparison section."""
    from report_fixtures import short_report

    page = (short_report() / "index.html").read_text(encoding="utf-8")
    assert 'id="beyond"' not in page


def test_prose_renders_escaped_text_tagged_numbers_and_styles():
    """The template writes the tags; the data's text is escaped (a run's error message may hold
    anything); a fact's span carries its run, key and unit."""
    paragraph = para(
        "a < b & ",
        Num(1.5, "1.50", "mm", "velocity_open", "max_radial_error_m"),
        ", ",
        number(3.14159),
        " ",
        code("<run>"),
        " ",
        strong("bold"),
        " K",
        sub("v"),
        kind="contradiction",
    )
    html = render_macro("prose", [paragraph])
    assert html.startswith('<p class="contradiction">a &lt; b &amp; ')
    assert (
        '<span class="num" data-run="velocity_open" data-key="max_radial_error_m" '
        'data-unit="mm">1.50 mm</span>' in html
    )
    assert '<span class="num">3.14</span>' in html
    assert "<code>&lt;run&gt;</code> <b>bold</b> K<sub>v</sub></p>" in html
    assert paragraph.text == "a < b & 1.50 mm, 3.14 <run> bold Kv"
    assert [f.key for f in paragraph.facts] == ["max_radial_error_m", ""]
