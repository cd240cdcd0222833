"""The MkDocs hook that writes the site's reference from the code (``hooks:`` in mkdocs.yml).

Pages ask for generated blocks with ``<!-- doorlab:NAME [ARG] -->`` markers; the blocks are
written by the package beside this file, :mod:`doorlab_reference` (one module per kind of
block; its docstring lists the markers). This file only plugs it into MkDocs.

Print one block without MkDocs: ``python docs/tools/reference.py cli`` (or any marker's name).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

# MkDocs puts this folder on sys.path while it loads a hook; a test that loads this file by
# path, or ``python docs/tools/reference.py``, may not.
if str(Path(__file__).resolve().parent) not in sys.path:
    sys.path.insert(0, str(Path(__file__).resolve().parent))

from doorlab_reference import *  # noqa: E402, F403 (the hook's module is the reference's API)
from doorlab_reference import GENERATORS, expand  # noqa: E402


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ARG001 (MkDocs' API)
    """MkDocs hook: expands the page's markers (an error stops the build, naming the page)."""
    from mkdocs.exceptions import PluginError

    try:
        return expand(markdown, page.file.src_uri)
    except ValueError as e:
        raise PluginError(f"doorlab reference, {page.file.src_uri}: {e}") from None


_ROLE_IN_HTML = re.compile(r":(?:mod|func|class|data|meth|attr|exc|obj):(?=<code\b)")


def on_page_content(html: str, page, config, files) -> str:  # noqa: ARG001 (MkDocs' API)
    """MkDocs hook: the API pages' Sphinx roles (``:func:`x```) are shown as plain code."""
    return _ROLE_IN_HTML.sub("", html)


if __name__ == "__main__":
    if len(sys.argv) < 2 or sys.argv[1] not in GENERATORS:
        sys.exit(f"usage: python {sys.argv[0]} {{{','.join(GENERATORS)}}} [GROUP]")
    print(GENERATORS[sys.argv[1]](*sys.argv[2:]))
