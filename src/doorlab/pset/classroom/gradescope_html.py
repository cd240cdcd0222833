"""The autograder's episode tests on Gradescope with the student's figures.

Gradescope shows a test's ``output`` as text, or renders it as HTML when the test's
``output_format`` is ``"html"`` (its Autograder Specifications, "Output String Formatting":
the HTML is sanitized, so only plain elements are used; https://gradescope-autograders.readthedocs.io/en/latest/specs/).
:func:`with_figures` gives each episode test whose episode ran (and that students may see:
not ``hidden``) an HTML output (Jinja2 template ``pset_gradescope_test.html.j2``): the
test's text, escaped in a ``<pre>`` (nothing the student's code printed is ever rendered as
HTML), then the figure of the feedback page (:mod:`doorlab.pset.classroom.feedback`: the
door's opening, Q's radial error and L7's orientation error along the arc, the student's
against the reference) as a PNG data URI. The specification names no size limit; each test's
HTML is kept under :data:`MAX_TEST_HTML_BYTES` (a figure is 45-60 kB of PNG, ~80 kB as
base64), else the figure is left out and the output says so. The text stays in the test's
``extra_data.text_output`` (what the autograder's own summary prints).
"""

from __future__ import annotations

import base64

from doorlab.pset.rules import verdicts

MAX_TEST_HTML_BYTES = 200_000
"""Largest HTML output of one test [bytes] (three figures: ~0.25 MB of results.json)."""


def _figure(results: dict, job: str) -> dict | None:
    from doorlab.pset.classroom.feedback import EPISODES, _figure_png, _series

    extra = results.get("extra_data") or {}
    yours = _series((extra.get("episodes") or {}).get(job))
    if yours is None or job not in EPISODES:
        return None
    reference = _series((extra.get("reference") or {}).get(job.replace("student:", "reference:")))
    title = EPISODES[job]
    png = _figure_png(title, yours, reference)
    caption = f"{title}: yours (red) against doorlab's reference (grey)" + (
        "" if reference is not None else " (the reference's series is not in this grading)"
    )
    return {"data": base64.b64encode(png).decode("ascii"), "caption": caption}


def with_figures(results: dict) -> dict:
    """``results`` (in place; returned) with each shown episode test's output as HTML with
    its figure (see the module docstring)."""
    from doorlab.outputs.pages import render

    jobs = {
        spec.name: next((j for j in spec.jobs if j.startswith("student:")), None)
        for spec in verdicts.TESTS
    }
    for test in results.get("tests") or []:
        job = jobs.get(test.get("name"))
        if job is None or test.get("visibility") == "hidden":
            continue
        figure = _figure(results, job)
        if figure is None:
            continue
        text = str(test.get("output") or "")
        html = render("pset_gradescope_test.html.j2", text=text, figure=figure)
        if len(html.encode()) > MAX_TEST_HTML_BYTES:
            note = f"(the figure of this episode is left out: over {MAX_TEST_HTML_BYTES} bytes)"
            html = render("pset_gradescope_test.html.j2", text=f"{text}\n{note}", figure=None)
        test.setdefault("extra_data", {})["text_output"] = text
        test["output"], test["output_format"] = html, "html"
    return results
