"""Getting started, as a reader follows it after the README's quick start.

Its install block is the README's quick start (.ci/run runs it exactly; tests/test_repository.py
compares them). "The first run" quotes what ``doorlab run`` prints (a measured region written by
``docs/tools/make_figures.py run``): the main job, run here as the README runs it, in a copy of
the checkout, prints the same figures. Times are the machine's and are left out; each figure
agrees within one unit of its last printed digit, or 1 % (the same Drake gives the same digits:
the simulation is deterministic; another release may move a last digit, docs/explanation/
fidelity.md).
"""

from __future__ import annotations

import re
import subprocess

import doc_commands
import pytest

pytestmark = pytest.mark.slow
NUMBER = re.compile(r"-?\d+(?:\.\d+)?")
MACHINE_LINES = ("simulated / wall time", "doorlab run:")
"""Lines of the summary that hold the machine's figures (times) or a path, not the run's."""


def _figures(summary: str) -> dict[str, list[str]]:
    """The summary's lines by their label, each with its numbers as printed."""
    out = {}
    for line in summary.splitlines():
        label = re.split(r"\s{2,}", line.strip(), maxsplit=1)[0]
        if not line.strip() or any(line.strip().startswith(m) for m in MACHINE_LINES):
            continue
        out[label] = NUMBER.findall(line[line.index(label) + len(label) :])
    return out


def _agree(page: str, run: str) -> bool:
    digits = len(page.split(".")[1]) if "." in page else 0
    return abs(float(page) - float(run)) <= max(10.0**-digits, 0.01 * abs(float(page)))


def test_the_first_run_prints_what_the_page_quotes(tmp_path):
    blocks = doc_commands.blocks("docs/getting-started.md")
    assert [b.run_by is not None for b in blocks if b.lang == "bash"] == [True]
    page_text = (doc_commands.ROOT / "docs" / "getting-started.md").read_text()
    region = re.search(r"<!-- measured: run/summary -->\n```text\n(.*?)```", page_text, re.S)
    assert region, "getting-started.md: the first run's summary is not on the page"
    quoted = _figures(region.group(1))
    work = tmp_path / "clone"
    doc_commands.copy_checkout(work, after_readme=False)  # the README's own run
    done = subprocess.run(
        [".venv/bin/doorlab", "run"], cwd=work, capture_output=True, text=True, timeout=900
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert (work / "doorlab_out" / "velocity_closed" / "metrics.json").is_file()
    printed = _figures(done.stdout)
    assert set(quoted) == set(printed), (sorted(quoted), sorted(printed))
    assert len(quoted) >= 10
    differ = {
        label: (quoted[label], printed[label])
        for label in quoted
        if len(quoted[label]) != len(printed[label])
        or not all(_agree(a, b) for a, b in zip(quoted[label], printed[label], strict=True))
    }
    assert differ == {}, differ
