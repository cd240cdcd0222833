"""The report's answers as data: the measured facts and the sentences they support.

An answer (:class:`Answer`) is its figures and its paragraphs; a paragraph (:class:`Paragraph`)
is a tuple of parts: plain text, a measured number (:class:`Num`: its value, how the page
prints it, and the run and ``metrics.json`` key it comes from) or a styled piece
(:class:`Styled`: code, bold, a sub- or superscript). Nothing here is HTML: the template
(``macros.html.j2``'s ``prose``) escapes the text and writes the tags, so a test can read the
facts from the data and the page alike.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import ClassVar, Union

from doorlab.outputs.pages import EmbeddedFigure, format_number

STYLES = ("code", "strong", "em", "sub", "sup")
"""The styles of a :class:`Styled` part (the template's tags: code, b, em, sub, sup)."""


@dataclass(frozen=True)
class Num:
    """A number on the page: a measured value, or one derived from measured values.

    Attributes:
        value: The value in the unit shown (None: not measured; printed "n/a").
        text: How the page prints it (:func:`doorlab.outputs.pages.format_number`).
        unit: The unit printed after it ("" for none).
        run: The run it was measured in ("" for a derived number).
        key: Its ``metrics.json`` key ("" for a derived number).
    """

    value: float | None
    text: str
    unit: str = ""
    run: str = ""
    key: str = ""
    style: ClassVar[str] = "num"

    @property
    def shown(self) -> str:
        """The text with its unit, as printed."""
        return f"{self.text} {self.unit}" if self.unit else self.text


@dataclass(frozen=True)
class Styled:
    """A piece of text in one of :data:`STYLES` (a run's name as code, a word in bold, the v of
    K_v as a subscript)."""

    text: str
    style: str


Part = Union[str, Num, Styled]  # noqa: UP007 (a runtime alias: isinstance-free, for readers)


@dataclass(frozen=True)
class Paragraph:
    """One paragraph of an answer: its parts in order, and what kind of statement it is.

    Attributes:
        parts: Text, numbers and styled pieces. kind: "" (a finding) or "contradiction" (the
            measurements contradict the problem set's hint; the page marks it).
    """

    parts: tuple[Part, ...]
    kind: str = ""

    @property
    def facts(self) -> tuple[Num, ...]:
        """The numbers this paragraph states."""
        return tuple(p for p in self.parts if isinstance(p, Num))

    @property
    def text(self) -> str:
        """The paragraph as plain text."""
        return "".join(p if isinstance(p, str) else getattr(p, "shown", p.text) for p in self.parts)

    @property
    def markdown(self) -> str:
        """The paragraph as Markdown (for pages that quote a report: docs/tools/make_figures.py)."""
        marks = {"code": "`{}`", "strong": "**{}**", "em": "*{}*"}
        marks |= {"sub": "<sub>{}</sub>", "sup": "<sup>{}</sup>"}
        out = []
        for p in self.parts:
            if isinstance(p, str):
                out.append(p.replace("*", "\\*").replace("_", "\\_"))
            elif isinstance(p, Num):
                out.append(p.shown)
            else:
                out.append(marks[p.style].format(p.text))
        return "".join(out)


@dataclass(frozen=True)
class Answer:
    """A question's answer: its figures (in page order) and its paragraphs."""

    figures: tuple[EmbeddedFigure, ...] = ()
    paragraphs: tuple[Paragraph, ...] = ()

    @property
    def facts(self) -> tuple[Num, ...]:
        """Every number the answer states."""
        return tuple(n for p in self.paragraphs for n in p.facts)


def _flatten(parts: Iterable) -> list[Part]:
    out: list[Part] = []
    for part in parts:
        if part is None or part == "":
            continue
        if isinstance(part, (str, Num, Styled)):
            out.append(part)
        else:
            out.extend(_flatten(part))
    return out


def para(*parts, kind: str = "") -> Paragraph:
    """A paragraph of ``parts`` (nested lists and tuples flattened; None and "" dropped)."""
    return Paragraph(tuple(_flatten(parts)), kind)


def joined(items: Iterable, separator: str = ", ") -> list[Part]:
    """``items`` (parts or lists of parts) with ``separator`` between them."""
    out: list[Part] = []
    for i, item in enumerate(items):
        if i:
            out.append(separator)
        out.extend(_flatten([item]))
    return out


def code(text: str) -> Styled:
    return Styled(str(text), "code")


def strong(text: str) -> Styled:
    return Styled(str(text), "strong")


def em(text: str) -> Styled:
    return Styled(str(text), "em")


def sub(text: str) -> Styled:
    return Styled(str(text), "sub")


def sup(text: str) -> Styled:
    return Styled(str(text), "sup")


def number(value: float | None, unit: str = "", digits: int | None = None) -> Num:
    """A derived number (a ratio, a spread, a model's value), printed with the page's digits."""
    text = format_number(value) if digits is None else format_number(value, digits)
    return Num(None if value is None else float(value), text, unit)


def count(n: int) -> Num:
    """A counted number (ticks, runs), printed whole."""
    return Num(float(n), str(int(n)))


K_V = ("K", sub("v"))
"""K_v, the translational gain."""
K_W = ("K", sub("ω"))
"""K_omega, the rotational gain."""
D_Q = ("D", sub("q"))
"""D_q, the inner loop's joint damping."""
V_DES = ("V", sub("des"))
"""V_des, the task velocity a velocity law asks for."""
K_P = ("K", sub("p"))
"""K_p, a stiffness per unit of task-space inertia."""
K_D = ("K", sub("d"))
"""K_d, a damping per unit of task-space inertia."""
