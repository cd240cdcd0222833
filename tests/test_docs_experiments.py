"""docs/guides/experiments.md's commands, as written (tests/doc_commands.py)."""

from __future__ import annotations

import pytest
from doc_commands import Page

pytestmark = pytest.mark.slow


def test_experiments(tmp_path):
    """``doorlab run`` with the page's options writes its folders (the default's name, and
    ``--out ik5``); ``doorlab report --out my_report`` writes its index.html; the Python block
    runs and prints the metrics it names."""
    page = Page("docs/guides/experiments.md", tmp_path)
    outcomes = page.run_blocks()
    assert [o.how for o in outcomes] == ["ran"] * 3
    assert (tmp_path / "doorlab_out" / "impedance_open" / "metrics.json").is_file()
    assert (tmp_path / "ik5" / "metrics.json").is_file()
    assert (tmp_path / "my_report" / "index.html").is_file()
    printed = outcomes[2].outputs[0].split()
    assert len(printed) == 3 and printed[2] in ("True", "False"), printed
