"""``doorlab report --pdf``: the report page printed by headless Chromium.

The PDF test prints a short-run report page (shared fixture), rasterizes its pages with
pdftoppm and checks there are pages with ink on them; skipped when Chromium or pdftoppm is
not installed. Without Chromium, ``--pdf`` fails before any simulation with a one-line error
naming the package.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from report_fixtures import single_run_report

from doorlab.cli.parser import main
from doorlab.runtime import pdf


@pytest.mark.slow
def test_report_page_prints_to_a_pdf_with_pages(tmp_path: Path):
    try:
        pdf.find_chromium()
    except Exception:
        pytest.skip("chromium not installed: apt-get install chromium")
    if shutil.which("pdftoppm") is None:
        pytest.skip("pdftoppm not installed: apt-get install poppler-utils")
    from matplotlib.image import imread

    out = pdf.print_pdf(single_run_report() / "index.html", tmp_path / "report.pdf")
    assert out.read_bytes().startswith(b"%PDF")
    subprocess.run(
        ["pdftoppm", "-png", "-r", "40", str(out), str(tmp_path / "page")], check=True, timeout=120
    )
    pages = sorted(tmp_path.glob("page-*.png"))
    assert len(pages) >= 2  # the page has several figures and tables: more than one sheet
    first = imread(pages[0])
    # Ink on the first page: a noticeable share of pixels is not white.
    assert np.mean(first[..., :3].mean(axis=2) < 0.9) > 0.01


def test_pdf_without_chromium_is_a_one_line_error_before_any_run(
    tmp_path: Path, monkeypatch, capsys
):
    monkeypatch.setattr(shutil, "which", lambda name: None)
    out = tmp_path / "report"
    assert main(["report", "--pdf", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "apt-get install chromium" in err
    assert not out.exists()
