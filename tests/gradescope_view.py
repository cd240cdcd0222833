"""A results.json as Gradescope shows it to a student, for the browser tests.

Gradescope's Autograder Specifications ("Output String Formatting") say a test's output is
shown as text in a ``<pre>`` unless its ``output_format`` says otherwise; ``"html"`` is
rendered after Gradescope sanitizes it ("we sanitize the output so you may not be able to use
all HTML elements"). The specification does not list what its sanitizer keeps; this stand-in
keeps what Rails' default sanitizer (Loofah's safe list; Gradescope is a Rails application)
keeps of what doorlab writes: ``pre``, ``p``, ``em`` and ``img`` with ``src``, ``alt`` and
``width``, ``data:`` URIs of images (bleach, with that list). Anything else (a script, an
event handler, a style) is dropped, so a page that still shows its figures here needs no more
than those elements. Students see the tests Gradescope shows (hidden ones never).
"""

from __future__ import annotations

from pathlib import Path

import bleach
import jinja2

ALLOWED_TAGS = {"pre", "p", "em", "img", "br", "code"}
ALLOWED_ATTRIBUTES = {"img": ["src", "alt", "width"]}
ALLOWED_PROTOCOLS = {"data"}

TEMPLATE = Path(__file__).with_name("gradescope_view.html.j2")
"""The page around the tests (Gradescope's layout, roughly: its total, its output, a box per
test)."""


def sanitize(html: str) -> str:
    """What the stand-in sanitizer keeps of an ``html`` output (see the module docstring)."""
    return bleach.clean(
        html,
        tags=ALLOWED_TAGS,
        attributes=ALLOWED_ATTRIBUTES,
        protocols=ALLOWED_PROTOCOLS,
        strip=True,
    )


def student_view(results: dict) -> str:
    """The page a student sees for ``results`` (hidden tests left out)."""
    tests = []
    for t in results.get("tests", []):
        if t.get("visibility") == "hidden":
            continue
        html = sanitize(t["output"]) if t.get("output_format") == "html" else None
        tests.append({**t, "html": html})
    page = jinja2.Template(TEMPLATE.read_text(), autoescape=True)
    return page.render(
        score=f"{results['score']:g}",
        max_score=f"{sum(t['max_score'] for t in results['tests']):g}",
        output=results.get("output", ""),
        tests=tests,
    )
