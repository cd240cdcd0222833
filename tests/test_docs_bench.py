"""docs/guides/bench.md's commands, as written (tests/doc_commands.py): the card of every
built-in, of a built-in beside a plug-in, over a distribution of one's own, and resumed."""

from __future__ import annotations

import json

import pytest
from doc_commands import Page

from doorlab.config import CONTROLLERS

pytestmark = pytest.mark.slow


def test_bench(tmp_path):
    page = Page("docs/guides/bench.md", tmp_path)
    outcomes = page.run_blocks()
    assert [o.how for o in outcomes] == ["ran"] * 3
    builtins = json.loads((tmp_path / "bench_builtins" / "bench.json").read_text())
    assert set(builtins["controllers"]) == set(CONTROLLERS)
    two = json.loads((tmp_path / "bench_two" / "bench.json").read_text())
    assert set(two["controllers"]) == {"velocity", "dls"}
    assert two["bench"]["seed"] == 7
    for card, episodes in ((builtins, 1), (two, 2)):  # bench_two resumed: 1 kept, 1 more
        for entry in card["controllers"].values():
            assert entry["episodes"] == episodes, entry
            low, high = entry["ci95"]
            assert 0.0 <= low <= entry["success_rate"] <= high <= 1.0, entry
    assert (tmp_path / "bench_two" / "index.html").is_file()
    assert (tmp_path / "bench_yaw" / "bench.json").is_file()
