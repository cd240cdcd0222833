"""Text from student code made safe to store and to print.

Everything a submission can put into words (what its code printed, an exception's message,
a traceback, a file name) reaches ``results.json`` and the instructor's terminal only through
:func:`clean_text`: terminal escape sequences (ANSI ``ESC [ ... m``, OSC titles, cursor moves),
control characters (NUL, carriage return, backspace, C1 controls), bidirectional overrides and
every other character that ends a line for :meth:`str.splitlines` but the newline (vertical
tab, form feed, the file, group and record separators, U+0085, the line and paragraph
separators U+2028 and U+2029) are removed, so no output can draw over the grader's own lines
(a fake ``Total score: 14 / 14``), start a line of its own or reorder them; lone surrogates
become U+FFFD, so the text is valid UTF-8 (JSON parsers and Gradescope reject lone
surrogates).
"""

from __future__ import annotations

import re
from typing import Any

ELLIPSIS = "\u2026"
"""What ends a text cut at its limit."""

_ESCAPES = re.compile(
    r"""
    \x1b\[[0-?]*[ -/]*[@-~]              # CSI: colours, cursor moves, erase (ESC [ ... final)
    | \x1b\][^\x07\x1b]*(?:\x07|\x1b\\)?  # OSC: window titles, hyperlinks (ends BEL or ST)
    | \x1b[PX^_][^\x1b]*(?:\x1b\\)?       # DCS, SOS, PM, APC strings
    | \x1b[ -/]*[0-~]?                   # any other escape (ESC c resets the terminal)
    | \x9b[0-?]*[ -/]*[@-~]              # the one-character (C1) CSI
    """,
    re.VERBOSE,
)
_CONTROLS = re.compile(
    "[\x00-\x08\x0b-\x1f\x7f-\x9f"  # C0 but tab and newline, DEL, C1
    "\u061c\u200e\u200f\u202a-\u202e\u2066-\u2069"  # bidirectional marks and overrides
    "\u2028\u2029"  # the line and paragraph separators (str.splitlines breaks on them)
    "\ud800-\udfff]"  # lone surrogates (a well-formed str holds none)
)


def _replace(match: re.Match) -> str:
    return "\ufffd" if "\ud800" <= match.group() <= "\udfff" else ""


def clean_text(text: str, limit: int | None = None) -> str:
    """``text`` without escape sequences, control characters and line separators but the
    newline (newlines and tabs stay; ``\\r\\n`` becomes ``\\n``): its lines are exactly
    ``text.split("\\n")``, and :meth:`str.splitlines` finds the same; lone surrogates
    replaced by U+FFFD.

    Args:
        text: Any text (a non-str is converted with ``str``; bytes are decoded as UTF-8
            with replacement).
        limit: At most this many characters are returned (cut ones end in an ellipsis);
            None: no limit.
    """
    if isinstance(text, (bytes, bytearray)):
        text = bytes(text).decode("utf-8", "replace")
    elif not isinstance(text, str):
        text = str(text)
    text = _ESCAPES.sub("", text.replace("\r\n", "\n"))
    text = _CONTROLS.sub(_replace, text)
    if limit is not None and len(text) > limit:
        text = text[: max(0, limit - 1)] + ELLIPSIS if limit > 0 else ""
    return text


def clean_json(value: Any) -> Any:
    """A JSON-ready value with every string in it (keys too) passed through
    :func:`clean_text`."""
    if isinstance(value, str):
        return clean_text(value)
    if isinstance(value, dict):
        return {clean_text(str(k)): clean_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [clean_json(v) for v in value]
    return value
