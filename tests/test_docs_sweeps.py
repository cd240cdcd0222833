"""docs/guides/sweeps.md's commands, as written (tests/doc_commands.py), and its table."""

from __future__ import annotations

import importlib.util
import re
import sys

import pytest
from doc_commands import ROOT, Page

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
    # The page's table of the impedance sweep (written by make_figures.py) is this run's.
    text = (ROOT / "docs" / "guides" / "sweeps.md").read_text()
    region = re.search(r"<!-- measured: sweep_impedance/table -->\n(.*?)<!-- /", text, re.S)
    assert region and "|" in region.group(1), "sweeps.md: the impedance table is not on the page"
    table = _make_figures().impedance_table(tmp_path / "doorlab_sweep")
    assert same_table(region.group(1), table) == []


def _make_figures():
    """docs/tools/make_figures.py as a module (its tables are what the page shows)."""
    name = "doorlab_docs_make_figures"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, ROOT / "docs/tools/make_figures.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


def _cells(table: str) -> list[list[str]]:
    rows = [line.strip("|").split("|") for line in table.strip().splitlines()]
    return [[c.strip() for c in row] for row in rows if not set("".join(row)) <= set("-: ")]


def same_table(page: str, run: str) -> list[tuple[str, str]]:
    """The cells where a table on the page and one made from a run differ: numbers more than
    one unit of their last printed digit apart (the same Drake gives the same digits; another
    release may move a last one), or another text (a slip's *)."""
    number = re.compile(r"-?\d+(?:\.\d+)?")
    differ = []
    for row_page, row_run in zip(_cells(page), _cells(run), strict=True):
        for a, b in zip(row_page, row_run, strict=True):
            na, nb = number.findall(a), number.findall(b)
            if number.sub("#", a) != number.sub("#", b) or len(na) != len(nb):
                differ.append((a, b))
                continue
            for x, y in zip(na, nb, strict=True):
                unit = 10.0 ** -(len(x.split(".")[1]) if "." in x else 0)
                if abs(float(x) - float(y)) > unit + 1e-9:
                    differ.append((a, b))
    return differ
