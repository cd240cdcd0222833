"""The pages' commands run as written (tests/doc_commands.py): README.md here, each guide in
a file of its own (tests/test_docs_*.py: each page's blocks in the page's order in a fresh copy
of the checkout, a file each so that the suite's workers run them side by side).

Besides exiting as the page says, a command gives what the page says it gives: the files it
names, the folders it writes. A block no test runs says which test does, or why not.
"""

from __future__ import annotations

import re
import urllib.request
from pathlib import Path

import doc_commands
import pytest
from doc_commands import Block, Outcome, Page

pytestmark = pytest.mark.slow


def test_every_page_is_covered_and_every_block_known():
    """Every page a reader is sent to is run here or in a file of its own, and each of its
    blocks is run, run by a named test, or marked with why it cannot run here."""
    tests = Path(__file__).parent
    for page in doc_commands.PAGES:
        name = "pages" if page == "README.md" else Path(page).stem.replace("-", "_")
        assert (tests / f"test_docs_{name}.py").is_file(), f"{page}: no test runs its commands"
        for block in doc_commands.blocks(page):
            if block.run_by is not None:
                named = re.findall(r"tests/[\w.]+\.py|\.ci/run", block.run_by)
                assert named, f"{page}:{block.line}: run by what? {block.run_by!r}"
                assert all((tests.parent / n).is_file() for n in named), block.run_by
            known = ("bash", "python", "yaml", "toml", "text", "")
            assert block.lang in known, (page, block.line, block.lang)


def test_readme(tmp_path):
    """The site's block: ``mkdocs serve`` answers on its address, ``mkdocs build --strict``
    writes site/index.html (the quick start is .ci/run's, as written)."""
    page = Page("README.md", tmp_path)
    served = []

    def check(block: Block, outcome: Outcome, work: Path) -> None:
        if "mkdocs serve" in block.text:
            with urllib.request.urlopen("http://127.0.0.1:8000/", timeout=10) as answer:
                served.append(answer.read().decode())
        if "mkdocs build" in block.text:
            assert (work / "site" / "index.html").is_file()

    outcomes = page.run_blocks(check)
    assert [o.how for o in outcomes][0].startswith("run by")
    assert "doorlab" in served[0]
