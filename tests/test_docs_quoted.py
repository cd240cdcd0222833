"""What the pages quote from a run is the run's: the blocks docs/tools/make_figures.py writes
(a report's tables and its generated comparison) hold the text of the files it wrote beside
the figures, and the blocks benchmarks/report_time.py writes (what the report and each of its
sections cost) hold what its results file says. A hand edit of a quoted number fails here."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _load(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_the_pages_hold_the_tables_make_figures_wrote():
    figures = _load(REPO / "docs" / "tools" / "make_figures.py", "doorlab_docs_make_figures_q")
    found = {}
    for page in sorted((REPO / "docs").rglob("*.md")):
        for key, text in figures.quoted_blocks(page.read_text()).items():
            found[key] = page
            written = REPO / "docs" / "figures" / f"{key}.txt"
            assert written.is_file(), f"{page}: {key} quoted, {written} missing"
            assert text == written.read_text().rstrip("\n"), f"{page}: {key} differs from {written}"
    assert {"report/runs", "report/beyond"} <= set(found)


def test_the_pages_hold_what_the_report_time_benchmark_measured():
    bench = _load(REPO / "benchmarks" / "report_time.py", "doorlab_bench_report_time_q")
    results = json.loads(bench.RESULTS.read_text())
    for page, name in bench.DOC_BLOCKS.items():
        quoted = bench.quoted((REPO / page).read_text(), name)
        assert quoted == bench.block(name, results), f"{page}: report-time:{name}"
    assert results["report"]["episodes"] >= 12  # the problem set's eight, diffik's and osc's
