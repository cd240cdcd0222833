"""What a page quotes from a run, written into the page by the run that measured it.

A page holds what ``docs/tools/make_figures.py`` made between two markers, in its Markdown
source (so a reader sees it on GitHub as on the site)::

    <!-- measured: TARGET/NAME -->
    ...written by make_figures.py...
    <!-- /measured -->

NAME is a figure of the target (``docs/figures/TARGET/NAME.png``: the image, its caption and
the command that made it) or a text the target kept (``docs/figures/TARGET/NAME.md``, Markdown
as is: a table, a sentence with a time; ``NAME.txt``: a block of the command's output).
:func:`fill` writes every region of a page from docs/figures; ``make_figures.py`` calls it
after each run, and tests/test_docs.py checks that no page differs from it (nothing in a
region is typed by hand, nothing is stale against the recorded outputs).
"""

from __future__ import annotations

import importlib.util
import os
import re
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parents[2]
ROOT = DOCS.parent
FIGURES = DOCS / "figures"
REGION = re.compile(
    r"(?P<open><!-- measured: (?P<name>[\w./-]+) -->\n)(?P<body>.*?)(?P<close><!-- /measured -->)",
    re.S,
)
"""A measured region of a page's Markdown."""


def _figure_targets() -> dict:
    """docs/tools/make_figures.py's TARGETS (loaded from the folder above this package)."""
    path = Path(__file__).resolve().parents[1] / "make_figures.py"
    name = "doorlab_docs_make_figures"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module  # dataclasses look their module up
        spec.loader.exec_module(module)
    return sys.modules[name].TARGETS


def region_markdown(name: str, page: str) -> str:
    """The Markdown of region ``TARGET/NAME`` for the page at ``page`` (its path from the
    repository's root, e.g. ``docs/guides/sweeps.md`` or ``README.md``)."""
    targets = _figure_targets()
    target_name, _, item = name.partition("/")
    if target_name not in targets:
        raise ValueError(f"unknown measured region {name!r}; targets: {', '.join(targets)}")
    target = targets[target_name]
    made = f"`python docs/tools/make_figures.py {target_name}`"
    if item in target.figures:
        _, caption = target.figures[item]
        figure = FIGURES / target_name / f"{item}.png"
        src = Path(os.path.relpath(figure, (ROOT / page).parent)).as_posix()
        command = target.command.format(out="DIR")
        return f"![{caption}]({src})\n\n*{caption}. Made by `{command}` ({made}).*\n"
    for suffix in (".md", ".txt"):
        path = FIGURES / target_name / f"{item}{suffix}"
        if path.is_file():
            text = path.read_text().rstrip()
            return f"{text}\n" if suffix == ".md" else f"```text\n{text}\n```\n"
    known = [*target.figures, *(target.text or {}), *(target.tables or {})]
    raise ValueError(f"{name}: no such figure or text (made: {', '.join(known)}); run {made}")


def fill(markdown: str, page: str, missing: list[str] | None = None) -> str:
    """``markdown`` with every measured region written from docs/figures. With ``missing``
    (a list), a region whose run is not in docs/figures is left as it is and named there;
    without, it stops with the run to make."""

    def replace(match: re.Match) -> str:
        try:
            body = region_markdown(match.group("name"), page)
        except ValueError as e:
            if missing is None:
                raise
            missing.append(f"{page}: {e}")
            return match.group(0)
        return f"{match.group('open')}{body}{match.group('close')}"

    return REGION.sub(replace, markdown)


def pages() -> list[Path]:
    """The pages that may hold measured regions: README.md and every page under docs/."""
    return [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]


def stale() -> list[str]:
    """The pages (paths from the root) whose regions differ from what docs/figures gives."""
    out = []
    for path in pages():
        text = path.read_text()
        rel = path.relative_to(ROOT).as_posix()
        if REGION.search(text) and fill(text, rel) != text:
            out.append(rel)
    return out


def write_pages() -> tuple[list[str], list[str]]:
    """Writes every page's regions from docs/figures: (the pages it changed, the regions
    whose runs are missing, left as they were)."""
    changed: list[str] = []
    missing: list[str] = []
    for path in pages():
        text = path.read_text()
        rel = path.relative_to(ROOT).as_posix()
        new = fill(text, rel, missing)
        if new != text:
            path.write_text(new)
            changed.append(rel)
    return changed, missing
