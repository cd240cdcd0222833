"""Figures of docs/figures with their captions and the commands that made them."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path


def _figure_targets() -> dict:
    """docs/tools/make_figures.py's TARGETS (loaded from the folder above this package)."""
    path = Path(__file__).resolve().parents[1] / "make_figures.py"
    spec = importlib.util.spec_from_file_location("doorlab_docs_make_figures", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module.TARGETS


def figure_markdown(name: str, page: str = "index.md") -> str:
    """A figure of docs/figures (``TARGET/NAME``) with its caption and the command that made
    it, for the page at ``page`` (its path under docs/)."""
    targets = _figure_targets()
    target_name, _, figure = name.partition("/")
    if target_name not in targets or figure not in targets[target_name].figures:
        known = [f"{t}/{f}" for t, target in targets.items() for f in target.figures]
        raise ValueError(f"unknown figure {name!r}; valid: {', '.join(known)}")
    target = targets[target_name]
    _, caption = target.figures[figure]
    depth = len(Path(page).parent.parts)
    src = "../" * depth + f"figures/{target_name}/{figure}.png"
    command = target.command.format(out="DIR")
    return (
        f"<figure markdown>\n![{caption}]({src})\n"
        f"<figcaption>{caption}. Made by <code>{command}</code> "
        f"(<code>python docs/tools/make_figures.py {target_name}</code>).</figcaption>\n"
        "</figure>\n"
    )


def figure_text_markdown(name: str, page: str = "index.md") -> str:  # noqa: ARG001
    """A text a figure target kept (``TARGET/NAME``, e.g. ``run/summary``) as a code block."""
    target_name, _, text = name.partition("/")
    path = Path(__file__).resolve().parents[2] / "figures" / target_name / f"{text}.txt"
    if not path.is_file():
        raise ValueError(f"{path} is missing: python docs/tools/make_figures.py {target_name}")
    return f"```text\n{path.read_text().rstrip()}\n```\n"
