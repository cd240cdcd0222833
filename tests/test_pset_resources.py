"""Issue 43, without a grading: what a class shares that no view owns, and the sheet's guard.

The limits derived from the machine and ``--jobs`` (:mod:`doorlab.pset.isolation.memory`), the
room checks and the writes that ENOSPC cannot leave half-done, the intake that writes nothing,
the CSV guard. The attacks themselves (a class beside hidden memory, beside a disk filler)
are graded in ``test_pset_exhaustion.py``.
"""

from __future__ import annotations

import pytest

from doorlab.pset.classroom.roster import _cell, sheet_text


@pytest.mark.parametrize(
    "text",
    [
        "=1+1",
        " =1+1",
        "\u3000=1+1",  # an ideographic space first
        "\u00a0@SUM(A1)",
        "\uff1dcmd|' /C calc'!A0",  # full-width equals
        "\uff0b1",  # full-width plus
        "\uff0d1",  # full-width hyphen-minus
        "\uff20SUM(A1)",  # full-width commercial at
        "\ufe66HYPERLINK(1)",  # small equals
        "\u2212 1",  # the minus sign
        "  -2+3",
    ],
)
def test_the_csv_guard_catches_full_width_and_space_led_formulas(text):
    """A cell a spreadsheet could run as a formula is written with a leading quote, however
    its formula character is spelled or spaced (issue 43: U+FF1D and a space before = passed)."""
    assert _cell(text) == "'" + text
    assert "\n'" in sheet_text([{"submission": text}], [])


@pytest.mark.parametrize("text", ["Ada Lovelace", "O'Brien", "\uff21da", "1-2", "a=b", ""])
def test_the_csv_guard_leaves_plain_cells_alone(text):
    assert _cell(text) == text
