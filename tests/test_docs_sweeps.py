"""docs/guides/sweeps.md's commands, as written (tests/doc_commands.py), and its table."""

from __future__ import annotations

import pytest
from doc_commands import Page

pytestmark = pytest.mark.slow


def test_sweeps(tmp_path):
    """The sweeps write their folders (doorlab_sweep/, kv/, cluster/), the SPEC the page
    shows loads, and the cluster's sweep, on a scheduler and a worker started as the page
    says, writes its table."""
    page = Page("docs/guides/sweeps.md", tmp_path, values={"HOST": "127.0.0.1", "N": "2"})
    outcomes = page.run_blocks()
    assert [o.how for o in outcomes] == ["ran"] * 3
    for folder in ("doorlab_sweep", "kv", "cluster"):
        assert (tmp_path / folder / "results.csv").is_file(), folder
